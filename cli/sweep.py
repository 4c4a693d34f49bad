"""``softsim sweep``: run every combination of a sweep file on Dask, one HDF5 file per run plus a summary."""

import contextlib
import logging
import signal
import sys
from pathlib import Path

import click

from softsim.sweep import expand_sweep, load_sweep, local_layout, plan_runs, plot_summary
from softsim.sweep.plot import require_matplotlib
from softsim.sweep.runner import local_client, remote_client, run_sweep, summary_columns

from .launch import EXIT_INTERRUPTED

log = logging.getLogger("softsim")

EXIT_RUNS_FAILED = 1


def _echo_failed_runs(result):
    for row in result.failed:
        click.echo(f"softsim: run {row['run']} ({row['name']}) {row['status']}: {row['status_reason']}", err=True)


def _runs(count):
    """``1 run``, ``6 runs``."""
    return f"{count} run{'s' if count != 1 else ''}"


def _progress_bar(total):
    """A tqdm bar of runs on a terminal's stderr, or None when stderr is not a TTY."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="run", file=sys.stderr, leave=False, dynamic_ncols=True)


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """While inside, SIGTERM cancels the sweep like Ctrl-C does."""
    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:          # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _column(name, columns, option):
    """The summary column ``name`` names: itself, or the swept key it is the last part of."""
    if name in columns:
        return name
    matches = [column for column in columns if column.rsplit(".", 1)[-1] == name]
    if len(matches) == 1:
        return matches[0]
    raise click.BadParameter(f"{name!r} is not a column of the summary (columns: {', '.join(columns)})",
                             param_hint=option)


@click.command()
@click.argument("sweep_file", metavar="SWEEP", type=click.Path(dir_okay=False, path_type=str))
@click.option("-o", "--output-dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="Folder for the run files and summary.csv (default: the sweep file's name, here).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local workers (default: one per core, at most one per run); cores / workers Numba threads each.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on an existing Dask cluster, e.g. tcp://host:8786, instead of a local one.")
@click.option("--shared-dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="A folder the workers and this machine see at the same path: workers write the run "
                   "files there directly (it is the output folder). Without it, each run's file comes "
                   "back through Dask and is written here.")
@click.option("--force", is_flag=True, help="Rerun every run, also those whose file is complete.")
@click.option("--dry-run", is_flag=True, help="List the runs and their output files; run nothing.")
@click.option("--plot", "plot_spec", metavar="X:Y[:LINES]", default=None,
              help="After the runs, plot summary column Y against X, one line per value of LINES, "
                   "into OUTPUT_DIR/summary.png (needs the plot extra).")
def sweep(sweep_file, output_dir, workers, scheduler, shared_dir, force, dry_run, plot_spec):
    """Run every combination of SWEEP (a sweep file) on Dask: one HDF5 file per run and summary.csv.

    Every combination is validated as a full scene before any run starts. Runs whose file is
    already complete (for the same scene) are skipped, failed ones are retried; a failed run does
    not stop the others. Exit code 1 if any run failed, 130 on Ctrl-C.

    \b
    Examples:
      softsim sweep configs/cantilever_sweep.yaml --dry-run
      softsim sweep configs/cantilever_sweep.yaml -o sweep_out --workers 2
      softsim sweep configs/cantilever_sweep.yaml -o sweep_out --plot youngs_modulus:tip_displacement:poissons_ratio
      softsim sweep big.yaml --scheduler tcp://head:8786 -o results
    """
    if shared_dir is not None:
        if output_dir is not None and Path(output_dir).absolute() != Path(shared_dir).absolute():
            raise click.UsageError("--shared-dir is the output folder; give -o or --shared-dir, not two folders")
        output_dir = shared_dir
    if scheduler is not None and workers is not None:
        raise click.UsageError("--workers sizes a local cluster; an existing cluster (--scheduler) has its own")
    output_dir = Path(output_dir if output_dir is not None else Path(sweep_file).stem)
    plot_columns = plot_spec.split(":") if plot_spec else None
    if plot_columns is not None and len(plot_columns) not in (2, 3):
        raise click.BadParameter("must look like X:Y or X:Y:LINES", param_hint="--plot")

    runs = expand_sweep(load_sweep(sweep_file), output_dir)
    if plot_columns is not None:            # checked before any run: a typo must not cost a whole sweep
        columns = summary_columns(runs)
        plot_columns = [_column(name, columns, "--plot") for name in plot_columns]
        require_matplotlib()
    if dry_run:
        to_run, _ = plan_runs(runs, force) if output_dir.is_dir() else (runs, [])
        running = {run.index for run in to_run}
        for run in runs:
            action = "run" if run.index in running else "skip (complete)"
            click.echo(f"{run.index + 1:>4}  {run.path}  {action}")
        click.echo(f"{_runs(len(runs))}, {len(to_run)} to run, {len(runs) - len(to_run)} complete")
        return
    output_dir.mkdir(parents=True, exist_ok=True)
    to_run, _ = plan_runs(runs, force)      # a file in the way is refused before any worker starts
    skipped = f" ({len(runs) - len(to_run)} already complete)" if len(to_run) < len(runs) else ""
    if not to_run:
        client_context, numba_threads = contextlib.nullcontext(None), None
        where = None
    elif scheduler is not None:
        client_context, numba_threads = remote_client(scheduler), None
        where = f"the cluster at {scheduler}"
    else:
        workers, numba_threads = local_layout(max(1, len(to_run)), workers)
        client_context = local_client(workers, numba_threads)
        where = f"{workers} local workers x {numba_threads} Numba threads"

    bar = None

    def progress(done, failed, running, total):
        nonlocal bar
        if bar is None:
            bar = _progress_bar(total)
            if bar is None:
                return
        bar.set_postfix_str(f"done {done - failed}, failed {failed}, running {running}", refresh=False)
        bar.update(done - bar.n)

    result = None
    try:
        with _sigterm_as_interrupt(), client_context as client:
            if where is not None:       # said once connected: a cluster that does not answer is an error first
                log.info("sweep: %d runs%s on %s", len(to_run), skipped, where)
            result = run_sweep(runs, output_dir, client, shared_dir=shared_dir is not None, force=force,
                               numba_threads=numba_threads, progress=progress)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        if result is None:
            click.echo(f"softsim: sweep cancelled; runs finished so far are in {output_dir / 'summary.csv'}",
                       err=True)
        else:   # while the local workers were stopping: every run had ended and the summary is written
            _echo_failed_runs(result)
            click.echo(f"softsim: interrupted after the sweep's {_runs(len(result.rows))} ended "
                       f"({result.counts['complete']} complete, {len(result.failed)} failed); "
                       f"summary in {result.summary_paths[0]}", err=True)
        sys.exit(EXIT_INTERRUPTED)
    if bar is not None:
        bar.close()

    if plot_columns is not None:
        x, y, lines = (plot_columns + [None])[:3]
        image = plot_summary(result.summary_paths[0], output_dir / "summary.png", x, y, lines,
                             title=Path(sweep_file).name)
        log.info("plot: %s", image)
    counts = result.counts
    click.echo(f"{output_dir}: {_runs(len(result.rows))}, {counts['complete']} complete "
               f"({result.skipped} skipped, already complete), {len(result.failed)} failed; "
               f"summary in {result.summary_paths[0]}")
    _echo_failed_runs(result)
    if result.failed:
        sys.exit(EXIT_RUNS_FAILED)
