"""``softsim verify``: verification cases with known answers, error against run time, a table
(CSV + terminal), one plot per case and a markdown summary."""

import click

from softsim.config.schema import PRECISIONS
from softsim.verify.cases import CASES, MODELS
from softsim.verify.report import replot_report, verify_report


@click.command()
@click.option("--quick", is_flag=True, help="Short ladders (about a minute on 2 cores; the first run compiles for a few more).")
@click.option("--case", "cases", multiple=True, type=click.Choice(list(CASES)),
              help="Only this case (repeatable; default: all).")
@click.option("--model", "models", multiple=True, type=click.Choice(MODELS),
              help="Only this material model (repeatable; default: every model that applies).")
@click.option("--precision", "precisions", multiple=True, type=click.Choice(PRECISIONS),
              help="Only this precision of the step (repeatable; default: both, float32 for the models that have it).")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=str), default="verify",
              show_default=True, help="Folder for verify.csv, verify_<case>.png and verify.md.")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="Numba threads for the runs (default: Numba's setting, all cores).")
@click.option("--replot", is_flag=True,
              help="Run nothing: redraw the plots and verify.md from OUTPUT/verify.csv (e.g. after installing "
                   "the plot extra).")
def verify(quick, cases, models, precisions, out_dir, threads, replot):
    """Run verification cases with analytic answers over ladders of element size and time step,
    for every material model, and write the error against wall time: verify.csv, one plot per
    case and verify.md (the cheapest run for an error budget of 1 % and 0.1 %).

    \b
    Examples:
      softsim verify --quick -o verify-quick
      softsim verify --case cantilever --model stvk --precision float32
      softsim verify --replot -o verify
    """
    if replot:
        chosen = [name for name, given in (("--case", cases), ("--model", models), ("--precision", precisions),
                                           ("--threads", threads)) if given]
        if chosen:
            raise click.UsageError(f"--replot runs nothing, so {', '.join(chosen)} would not apply; redraw the "
                                   f"whole table, or run again with them")
        report = replot_report(out_dir, quick=quick)
    else:
        report = verify_report(out_dir, quick=quick, cases=cases or None, models=models or MODELS, threads=threads,
                               precisions=precisions or PRECISIONS,
                               progress=lambda line: click.echo(line, err=True))
    click.echo(report.table())
    for name, lines in report.budgets.items():
        if lines:
            click.echo(f"\n{name}: cheapest run for an error budget on the {CASES[name].primary}")
            for line in lines:
                click.echo(f"  {line}")
    written = [report.csv_path, *report.plot_paths.values(), report.summary_path]
    took = f"redrawn; the runs took {report.wall_time_s:.0f} s" if replot else f"{report.wall_time_s:.0f} s"
    click.echo("\nwrote " + ", ".join(str(p) for p in written) + f" ({took})")
    if report.plot_note:
        click.echo(report.plot_note)
