"""``softsim render``: pictures and animations of a run's deformed surface (PyVista, off screen).

The surface (the tets' boundary faces) moves with ``frames/points`` and is coloured by a field: a
per-tet field on the surface faces of its tet, a per-vertex field on the points.  Vectors show
their magnitude, tensors one component (``stress_xz``).  The camera is fixed for the whole
animation and frames the bounds over every rendered frame; the colour range is fixed too.  No X
server is needed: VTK's wheel renders through EGL or OSMesa when there is no display.
"""

import contextlib
import logging
import os
from pathlib import Path

import numpy as np

from ..errors import PLOT_EXTRA, MissingDependencyError
from ..io.fields import FIELDS
from .results import ResultsError, open_results

log = logging.getLogger("softsim")

FORMATS = (".png", ".gif", ".mp4")
# GIF frame delays count hundredths of a second, and players slow delays under 0.02 s down.
GIF_MAX_FPS = 50.0
# Direction from the focal point to the camera, and the view-up vector.
VIEWS = {
    "oblique": ((0.55, -1.0, 0.5), (0.0, 0.0, 1.0)),
    "iso": ((1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),
    "xz": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "xy": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "yz": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
}
AXES = "xyz"
BACKGROUND = "white"
# Outward-wound faces of a positively oriented tet (the face opposite corner 0, 1, 2, 3).
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def _pyvista():
    """The pyvista module, or ``MissingDependencyError`` naming the extra."""
    try:
        import pyvista
    except ImportError:
        raise MissingDependencyError(f"softsim render needs pyvista: {PLOT_EXTRA}") from None
    return pyvista


@contextlib.contextmanager
def _quiet_vtk_window_probe():
    """Without a display VTK first tries X and logs a warning before it falls back to EGL / OSMesa;
    keep that expected warning off stderr while the window is created."""
    try:
        from vtkmodules.vtkCommonCore import vtkLogger
    except ImportError:
        yield
        return
    if os.environ.get("DISPLAY"):
        yield
        return
    previous = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    try:
        yield
    finally:
        vtkLogger.SetStderrVerbosity(previous)


def boundary_faces(tets):
    """``(faces (b, 3), parent (b,))``: the outward-wound faces no other tet shares and their tet."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    parent = np.repeat(np.arange(len(tets)), 4)
    keys = np.sort(faces, axis=1)
    _, first, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
    single = np.sort(first[counts == 1])
    return faces[single], parent[single]


def field_choices(results):
    """Names ``--field`` accepts for ``results``: scalars, vectors (magnitude), vector and tensor
    components (``displacement_z``, ``stress_xz``)."""
    names = []
    for name in results.available_fields():
        if name not in FIELDS:          # energy/<term>: one number per frame
            continue
        shape = FIELDS[name].shape
        if shape in ((), (3,)):
            names.append(name)
        if shape == (3,):
            names += [f"{name}_{a}" for a in AXES]
        if shape == (3, 3):
            names += [f"{name}_{a}{b}" for a in AXES for b in AXES]
    return names


def default_field(results):
    """``von_mises`` when stored, else ``displacement`` (magnitude)."""
    return "von_mises" if "von_mises" in results.fields else "displacement"


def _parse_field(results, field):
    """``(name, component, label, unit)``; component None (scalar), 'mag', or index tuple."""
    choices = field_choices(results)
    if field not in choices:
        raise ResultsError(f"--field = '{field}': not available in {results.path}; choose from "
                           f"{', '.join(choices)}")
    if field in FIELDS:
        spec = FIELDS[field]
        if spec.shape == (3,):
            return field, "mag", f"|{field}|", spec.unit
        return field, None, field, spec.unit
    name, _, suffix = field.rpartition("_")
    spec = FIELDS[name]
    index = tuple(AXES.index(c) for c in suffix)
    return name, index, field, spec.unit


def _field_values(results, parsed, i):
    name, component, _, _ = parsed
    values = results.field(name, i)
    if component is None:
        return values
    if component == "mag":
        return np.linalg.norm(values, axis=1)
    return values[(slice(None), *component)]


class Renderer:
    """An off-screen PyVista scene of one run: the moving surface, a colour bar, the time, a ground.

    ``image(i)`` renders frame ``i`` and returns it as (height, width, 3) uint8.
    """

    def __init__(self, results, frames, field=None, size=(800, 600), view="oblique", cmap="viridis",
                 show_edges=True, shadows=True):
        pv = _pyvista()
        if view not in VIEWS:
            raise ResultsError(f"--view = '{view}': must be one of {', '.join(VIEWS)}")
        _check_cmap(cmap)
        self.results = results
        self.frames = list(frames)
        self.field = field or default_field(results)
        self.parsed = _parse_field(results, self.field)
        self.location = FIELDS[self.parsed[0]].location
        faces, self.parent = boundary_faces(results.tets)
        cells = np.column_stack([np.full(len(faces), 3), faces]).ravel()
        self.surface = pv.PolyData(results.frame_points(self.frames[0]).copy(), cells)

        # Fixed colour range and camera bounds over every frame rendered.
        lo, hi, bounds_lo, bounds_hi = np.inf, -np.inf, np.full(3, np.inf), np.full(3, -np.inf)
        for i in self.frames:
            values = self._values(i)
            lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
            points = results.frame_points(i)
            bounds_lo, bounds_hi = np.minimum(bounds_lo, points.min(0)), np.maximum(bounds_hi, points.max(0))
        if not hi > lo:          # a uniform field: a small range around it (never below 0 if it is not)
            pad = abs(hi) * 0.01 if hi != 0.0 else 1.0
            lo, hi = (max(lo - pad, 0.0) if lo >= 0.0 else lo - pad), hi + pad
        self.clim = (lo, hi)
        self.shadow = None
        self._store(self.frames[0])

        with _quiet_vtk_window_probe():
            self.plotter = pv.Plotter(off_screen=True, window_size=list(size))
        p = self.plotter
        p.set_background(BACKGROUND)
        label, unit = self.parsed[2], self.parsed[3]
        self.font_size = max(7, int(round(size[1] / 42)))   # text scales with the picture
        p.add_mesh(self.surface, scalars="value", preference="cell" if self.location == "tet" else "point",
                   clim=self.clim, cmap=cmap, show_edges=show_edges, edge_color=(0.15, 0.15, 0.15), line_width=0.5,
                   smooth_shading=False, ambient=0.2, diffuse=0.8, specular=0.2, specular_power=15,
                   scalar_bar_args=dict(title=f"{label} [{unit}]\n", vertical=True, position_x=0.8, position_y=0.08,
                                        width=0.07, height=0.8, fmt="%.3g", color="black",
                                        title_font_size=self.font_size + 1, label_font_size=self.font_size,
                                        n_labels=5))
        ground = results.scene.get("ground")
        extent = bounds_hi - bounds_lo
        if ground is not None:
            height = float(ground.get("height", 0.0))
            centre = 0.5 * (bounds_lo + bounds_hi)
            margin = max(extent.max(), 1e-3)
            plane = pv.Plane(center=(centre[0], centre[1], height), direction=(0, 0, 1),
                             i_size=extent[0] + 2 * margin, j_size=extent[1] + 2 * margin)
            p.add_mesh(plane, color=(0.82, 0.82, 0.8), ambient=0.3, diffuse=0.7, specular=0.0)
            if shadows:   # the surface flattened onto the ground, as under a light from straight above
                self.shadow_height = height + 1e-3 * max(extent.max(), 1e-3)
                self.shadow = self.surface.copy()
                self._store_shadow()
                p.add_mesh(self.shadow, color=(0.3, 0.3, 0.32), opacity=0.45, lighting=False)
            bounds_lo[2] = min(bounds_lo[2], height)
        direction, up = VIEWS[view]
        centre = 0.5 * (bounds_lo + bounds_hi)
        p.camera_position = [tuple(centre + np.asarray(direction)), tuple(centre), up]
        p.reset_camera(bounds=(bounds_lo[0], bounds_hi[0], bounds_lo[1], bounds_hi[1], bounds_lo[2], bounds_hi[2]))
        _fit_camera(p, bounds_lo, bounds_hi, size)
        if hasattr(p, "enable_anti_aliasing"):
            p.enable_anti_aliasing("ssaa")

    def _values(self, i):
        values = _field_values(self.results, self.parsed, i)
        return values[self.parent] if self.location == "tet" else values

    def _store(self, i):
        values = self._values(i)
        if self.location == "tet":
            self.surface.cell_data["value"] = values
        else:
            self.surface.point_data["value"] = values
        self.surface.points = self.results.frame_points(i)
        if self.shadow is not None:
            self._store_shadow()

    def _store_shadow(self):
        flat = np.array(self.surface.points)
        flat[:, 2] = self.shadow_height
        self.shadow.points = flat

    def show(self, i):
        """Move the surface, its colours and the time stamp to frame ``i``."""
        self._store(i)
        self.plotter.add_text(f"t = {self.results.times[i]:.3f} s", position=(0.03, 0.92), viewport=True,
                              font_size=self.font_size, color="black", name="time")
        self.plotter.render()

    def image(self, i):
        """Frame ``i`` as an (height, width, 3) uint8 array."""
        self.show(i)
        return np.asarray(self.plotter.screenshot(None, return_img=True))[..., :3].copy()

    def close(self):
        self.plotter.close()


# The part of the picture [fractions of width and height] the motion's bounding box fills: clear of
# the time stamp (top left) and the colour bar (right).
FIT_REGION = (0.05, 0.74, 0.06, 0.86)


def _fit_camera(plotter, lo, hi, size):
    """Zoom and shift the projection so that the box [lo, hi] fills ``FIT_REGION`` of the picture."""
    renderer, camera = plotter.renderer, plotter.camera
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    width, height = size
    x0, x1, y0, y1 = FIT_REGION
    for _ in range(4):
        pixels = []
        for corner in corners:
            renderer.SetWorldPoint(*corner, 1.0)
            renderer.WorldToDisplay()
            pixels.append(renderer.GetDisplayPoint()[:2])
        pixels = np.array(pixels)
        span = np.maximum(pixels.max(0) - pixels.min(0), 1e-6)
        camera.Zoom(min((x1 - x0) * width / span[0], (y1 - y0) * height / span[1]))
        pixels_centre = 0.5 * (pixels.max(0) + pixels.min(0))
        wanted = np.array([0.5 * (x0 + x1) * width, 0.5 * (y0 + y1) * height])
        cx, cy = camera.GetWindowCenter()
        # The window centre moves the picture against it by half the view per unit.
        camera.SetWindowCenter(cx - 2.0 * (wanted[0] - pixels_centre[0]) / width,
                               cy - 2.0 * (wanted[1] - pixels_centre[1]) / height)


def render(path, output, field=None, frame=None, frames=None, size=(800, 600), fps=None, view="oblique",
           cmap="viridis", show_edges=True):
    """Render run file ``path`` to ``output``: ``.png`` (one frame: ``frame``, default the last),
    ``.gif`` or ``.mp4`` (the frames ``frames``, slice text like ``0:100:2``, default all).

    field: see ``field_choices`` (default ``von_mises`` if stored, else displacement magnitude);
    size: (width, height) pixels (an .mp4's rounded down to multiples of 16); fps: animation frame
    rate (a .gif's at most ``GIF_MAX_FPS``; default real time, within 1 to 50).
    Returns ``output``.
    """
    output = Path(output)
    suffix = output.suffix.lower()
    if suffix not in FORMATS:
        raise ResultsError(f"-o '{output}': the format follows the extension; use one of {', '.join(FORMATS)}")
    if not output.resolve().parent.is_dir():
        raise ResultsError(f"-o '{output}': folder {output.resolve().parent} does not exist")
    if suffix == ".png" and frames is not None:
        raise ResultsError("--frames selects the frames of an animation; for a .png use --frame N")
    if suffix != ".png" and frame is not None:
        raise ResultsError("--frame picks the frame of a .png; for an animation use --frames START:STOP:STEP")
    if suffix == ".gif" and fps is not None and fps > GIF_MAX_FPS:
        raise ResultsError(f"--fps = {fps:g}: a .gif plays at most {GIF_MAX_FPS:g} frames per second (its frame "
                           f"delays count hundredths of a second, and players slow shorter ones down); use "
                           f"--fps {GIF_MAX_FPS:g} or less, or an .mp4")
    with open_results(path) as results:
        indices = [results.check_frame(-1 if frame is None else frame)] if suffix == ".png" \
            else results.select_frames(frames)
        if suffix == ".mp4":   # video codecs want sides that are multiples of 16
            fitted = tuple(max(16, 16 * (int(side) // 16)) for side in size)
            if fitted != tuple(size):
                log.info("the .mp4 is %dx%d pixels, not %dx%d: video codecs take sides that are multiples of 16",
                         *fitted, *size)
            size = fitted
        renderer = Renderer(results, indices, field, size, view, cmap, show_edges)
        try:
            if suffix == ".png":
                renderer.show(indices[0])
                renderer.plotter.screenshot(str(output))
                return output
            if fps is None:
                spacing = float(np.median(np.diff(results.times[indices]))) if len(indices) > 1 else 1.0
                fps = min(50.0, max(1.0, 1.0 / spacing if spacing > 0 else 10.0))
            if suffix == ".gif":
                renderer.plotter.open_gif(str(output), fps=fps, palettesize=128, subrectangles=True)
            else:
                _check_ffmpeg()
                renderer.plotter.open_movie(str(output), framerate=max(1, int(round(fps))), quality=7)
            for i in indices:
                renderer.show(i)
                renderer.plotter.write_frame()
        finally:
            renderer.close()
    return output


def _check_cmap(cmap):
    try:
        import matplotlib
    except ImportError:
        raise MissingDependencyError(f"softsim render's colour maps need matplotlib: {PLOT_EXTRA}") from None
    if cmap not in matplotlib.colormaps:
        raise ResultsError(f"--cmap = '{cmap}': not a matplotlib colour map (e.g. viridis, plasma, coolwarm, turbo)")


def _check_ffmpeg():
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise MissingDependencyError(f"writing .mp4 needs imageio-ffmpeg: {PLOT_EXTRA}") from None
