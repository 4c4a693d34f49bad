"""``softsim export``: a run's frames as VTU files (one per frame) or one XDMF time series."""

import click

from softsim.viz.export import FORMATS, export as export_frames


@click.command()
@click.argument("results", type=click.Path(dir_okay=False, path_type=str))
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="vtu", show_default=True,
              help="vtu: one file per frame with the moved points and a .pvd index; xdmf: the rest mesh with "
                   "displacement as point data (ParaView: Warp By Vector), one .xdmf + .h5.")
@click.option("--frames", default=None, metavar="START:STOP[:STEP]",
              help="Frames to export, Python slice syntax (default: all), e.g. 0:100:10 or -1.")
@click.option("-o", "--output", type=click.Path(path_type=str), default=None,
              help="vtu: a folder (default RESULTS_vtu/) or, for one frame, a .vtu file; "
                   "xdmf: the .xdmf file (default RESULTS_export.xdmf).")
@click.option("--overwrite", is_flag=True, help="Replace existing files.")
def export(results, fmt, frames, output, overwrite):
    """Export the frames of RESULTS (an HDF5 file written by softsim run) as files meshio and
    ParaView read, with every stored field.

    \b
    Examples:
      softsim export cantilever.h5 --format vtu --frames 0:50:10 -o cantilever_vtu
      softsim export cantilever.h5 --format vtu --frames -1 -o last.vtu
      softsim export cantilever.h5 --format xdmf -o warp.xdmf
    """
    written = export_frames(results, fmt, output, frames, overwrite)
    files = f"{len(written)} file{'s' if len(written) != 1 else ''}"
    click.echo(f"wrote {files}: {written[0]}" + (f" ... {written[-1]}" if len(written) > 1 else ""))
