"""``softsim plot``: energies and displacements of a run against time (PNG, matplotlib)."""

from pathlib import Path

import click

from softsim.viz.plot import plot_history


@click.command()
@click.argument("results", type=click.Path(dir_okay=False, path_type=str))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Image file; the format follows the extension (default: RESULTS with .png).")
@click.option("--vertex", "vertices", type=int, multiple=True, metavar="N",
              help="Plot the displacement of vertex N (repeatable; default: the largest over all vertices).")
def plot(results, output, vertices):
    """Plot the energies (when recorded, output.fields: [energy]) and the displacement of chosen
    vertices, or the largest displacement, of RESULTS against time.

    \b
    Examples:
      softsim plot cantilever.h5 -o energy.png
      softsim plot cantilever.h5 --vertex 0 --vertex 120
    """
    if output is None:
        output = str(Path(results).with_suffix(".png"))
    click.echo(f"wrote {plot_history(results, output, list(vertices))}")
