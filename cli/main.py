"""``softsim`` command group: logging verbosity, and the one place errors become exit codes."""

import logging
import sys

import click

from softsim import __version__
from softsim.errors import SoftsimError
from softsim.kernels.jit import on_first_compile

from . import export as export_command
from . import info as info_command
from . import mesh as mesh_command
from . import plot as plot_command
from . import render as render_command
from . import run as run_command
from . import stability as stability_command
from . import sweep as sweep_command
from . import verify as verify_command
from .launch import EXIT_INTERRUPTED


# Said as a command starts compiling kernels its Numba disk cache does not hold.
COMPILE_NOTICE = ("compiling kernels not yet in the cache, once: up to a few minutes this first time; "
                  "later runs load them from the cache")


class _EchoHandler(logging.Handler):
    """Library log records as one line each on stderr: ``warning: ...``; through tqdm where
    ``softsim run`` may show a progress bar (imported on a terminal), so that the line is not
    drawn onto the bar."""

    def emit(self, record):
        line = f"{record.levelname.lower()}: {record.getMessage()}"
        tqdm = sys.modules.get("tqdm")
        if tqdm is not None:
            tqdm.tqdm.write(line, file=sys.stderr)
        else:
            click.echo(line, err=True)


class _UsageLine(click.ClickException):
    """A usage error (a bad option or argument) as one line, with click's exit code for those."""

    exit_code = 2


# click 8.2 and later raise this for a command given no arguments, to show its help.
_NO_ARGS_IS_HELP = getattr(click.exceptions, "NoArgsIsHelpError", ())


def _one_line(exc, ctx):
    """A ``click.UsageError``, which click prints as usage, a hint and the error (three lines), as
    one line naming the help to read; the help itself where there was nothing to parse."""
    if isinstance(exc, _NO_ARGS_IS_HELP):
        return exc
    if exc.ctx is not None:
        command = exc.ctx.command_path
    elif ctx is not None:         # an option's missing value: click names no context
        command = " ".join(filter(None, (ctx.command_path, ctx.invoked_subcommand)))
    else:
        command = None
    see = f" (see '{command} --help')" if command else ""
    return _UsageLine(f"{exc.format_message()}{see}")


class SoftsimGroup(click.Group):
    """Turns library errors into one line on stderr and a non-zero exit code, never a traceback."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except SoftsimError as exc:
            raise click.ClickException(str(exc)) from None
        except click.UsageError as exc:
            raise _one_line(exc, ctx) from None
        except KeyboardInterrupt:
            click.echo("softsim: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        except (click.exceptions.Exit, click.ClickException):
            raise
        except Exception as exc:   # a bug: one line by default, the traceback with -vv
            if (ctx.meta.get("softsim.verbosity") or 0) > 1:
                raise
            first_line = (str(exc).strip().splitlines() or [""])[0]
            again = f"softsim -vv {ctx.invoked_subcommand} ..." if ctx.invoked_subcommand else "softsim -vv ..."
            raise click.ClickException(
                f"unexpected {type(exc).__name__}: {first_line} (run '{again}' for the traceback: -vv goes "
                f"before the command)") from None

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent, **extra)
        except click.UsageError as exc:        # the group's own options (softsim --bad)
            raise _one_line(exc, None) from None


@click.group(cls=SoftsimGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More messages (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="No warnings or notes: errors and the result only.")
@click.version_option(__version__, prog_name="softsim")
@click.pass_context
def cli(ctx, verbose, quiet):
    """softsim: explicit FEM simulation of elastic solids from YAML scene files.

    \b
    Examples:
      softsim run configs/cantilever.yaml -o cantilever.h5
      softsim run configs/bouncing_cube.yaml --set material.youngs_modulus=5e5
      softsim mesh configs/cantilever.yaml -o beam.vtu
    """
    ctx.meta["softsim.verbosity"] = verbose
    logger = logging.getLogger("softsim")
    logger.handlers[:] = [_EchoHandler()]
    logger.propagate = False
    logger.setLevel(logging.ERROR if quiet else logging.DEBUG if verbose > 1 else logging.INFO)
    ctx.with_resource(on_first_compile(lambda: logger.info(COMPILE_NOTICE)))


cli.add_command(run_command.run)
cli.add_command(mesh_command.mesh)
cli.add_command(stability_command.stability)
cli.add_command(info_command.info)
cli.add_command(plot_command.plot)
cli.add_command(export_command.export)
cli.add_command(render_command.render)
cli.add_command(sweep_command.sweep)
cli.add_command(verify_command.verify)


def main():
    cli(prog_name="softsim")


if __name__ == "__main__":
    main()
