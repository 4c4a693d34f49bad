"""``softsim render``: a picture (.png) or animation (.gif, .mp4) of a run, off screen (PyVista)."""

import click

from softsim.viz.render import VIEWS, render as render_file


def _size(ctx, param, value):
    try:
        width, height = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"'{value}': expected WIDTHxHEIGHT, e.g. 800x600", param_hint="--size") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise click.BadParameter(f"'{value}': each side must be 16 to 8192 pixels", param_hint="--size")
    return width, height


@click.command()
@click.argument("results", type=click.Path(dir_okay=False, path_type=str))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="out.png (one frame), out.gif or out.mp4 (an animation).")
@click.option("--field", default=None, metavar="NAME",
              help="Colour by this field: a scalar (von_mises, pressure, J, speed), a vector's magnitude "
                   "(displacement) or a component (displacement_z, stress_xx). Default: von_mises if stored, "
                   "else displacement.")
@click.option("--frame", type=int, default=None, metavar="N", help="The frame of a .png (default: the last; -1 counts "
              "from the end).")
@click.option("--frames", default=None, metavar="START:STOP[:STEP]",
              help="Frames of an animation, Python slice syntax (default: all), e.g. ::2.")
@click.option("--size", default="800x600", show_default=True, callback=_size, metavar="WxH", help="Picture size in pixels.")
@click.option("--fps", type=click.FloatRange(min=0.1, max=100), default=None,
              help="Animation frames per second, 0.1 to 100 (a .gif at most 50); default: real time, "
                   "kept within 1 to 50.")
@click.option("--view", type=click.Choice(list(VIEWS)), default="oblique", show_default=True,
              help="Camera direction: oblique (front right, above), iso, or along an axis (xz: front, xy: top, yz: side).")
@click.option("--cmap", default="viridis", show_default=True, help="Matplotlib colour map name.")
@click.option("--no-edges", is_flag=True, help="Do not draw the element edges.")
def render(results, output, field, frame, frames, size, fps, view, cmap, no_edges):
    """Render the deformed surface of RESULTS (an HDF5 file written by softsim run), coloured by a
    field with a colour bar and the time, from a fixed camera that frames the whole motion.
    No display needed.

    \b
    Examples:
      softsim render cantilever.h5 -o cantilever.png --field von_mises
      softsim render bouncing_cube.h5 -o cube.gif --frames ::2 --size 480x360
      softsim render twisted_bar.h5 -o bar.mp4 --field speed --view xz
    """
    written = render_file(results, output, field=field, frame=frame, frames=frames, size=size, fps=fps, view=view,
                          cmap=cmap, show_edges=not no_edges)
    click.echo(f"wrote {written}")
