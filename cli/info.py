"""``softsim info``: summarise a run file (scene, mesh, status, frames, each field's range)."""

import json

import click

from softsim.viz.info import format_summary, summarize


@click.command()
@click.argument("results", type=click.Path(dir_okay=False, path_type=str))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object (for scripts).")
def info(results, as_json):
    """Summarise RESULTS (an HDF5 file written by softsim run): scene, mesh size, status, steps,
    dt, wall time, frames, simulated time reached, and the min / max of every stored field.

    \b
    Examples:
      softsim info cantilever.h5
      softsim info cantilever.h5 --json | jq .fields.von_mises.max
    """
    summary = summarize(results)
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        click.echo("\n".join(format_summary(summary)))
