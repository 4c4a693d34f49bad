"""``softsim stability``: the stress catalogue for every model, the measured stability limit
against ``dt: auto``, a table (CSV + terminal) and a plot (PNG)."""

import click

from softsim.reports.catalogue import MODELS
from softsim.reports.stability import stability_report


@click.command()
@click.option("--quick", is_flag=True, help="Short runs and a small grid of measured limits (about a minute).")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=str), default="stability",
              show_default=True, help="Folder for the table, plot, scenes and run files.")
@click.option("--scene", "scenes", multiple=True, metavar="NAME",
              help="Only this catalogue scene (repeatable; default: all).")
@click.option("--model", "models", multiple=True, type=click.Choice(MODELS),
              help="Only this material model (repeatable; default: all four).")
def stability(quick, out_dir, scenes, models):
    """Run the stress catalogue with every material model, measure the largest stable dt
    against the dt: auto step, and write stability.csv, limits.csv and stability.png to OUTPUT.

    \b
    Examples:
      softsim stability --quick -o stability-quick
      softsim stability --scene crushed-cube --model neohookean
    """
    report = stability_report(out_dir, quick=quick, scenes=scenes or None, models=models or MODELS,
                              progress=lambda line: click.echo(line, err=True))
    click.echo(report.table())
    if report.limits:
        click.echo("\nmeasured largest stable dt / dt: auto (min-max over E):")
        click.echo(report.limit_table())
        click.echo("")
        for line in report.verdict_lines():
            click.echo(line)
    warned = sum(1 for row in report.rows if row.warnings)
    if warned:
        click.echo(f"{warned} runs logged warnings (the warnings column of {report.csv_path})")
    written = [report.csv_path, report.limits_csv_path, report.plot_path]
    click.echo("wrote " + ", ".join(str(p) for p in written if p is not None)
               + f" ({report.wall_time_s:.0f} s)")
    if report.plot_note:
        click.echo(report.plot_note)
