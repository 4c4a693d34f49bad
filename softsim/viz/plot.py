"""``softsim plot``: energies and displacements of a run against time, as a PNG (matplotlib, Agg).

Uses matplotlib's Agg canvas directly (no pyplot, no global backend change), so it works without a
display and inside other programs.
"""

import numpy as np

from ..errors import PLOT_EXTRA, MissingDependencyError
from .results import ResultsError, open_results



def _matplotlib():
    """``(Figure, FigureCanvasAgg)``, or ``MissingDependencyError`` naming the extra."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingDependencyError(f"softsim plot needs matplotlib: {PLOT_EXTRA}") from None
    return Figure, FigureCanvasAgg


def displacement_history(results, vertices=None):
    """``(label, (k,) [m])`` curves of displacement magnitude: one per vertex of ``vertices``, or
    the largest over all vertices when ``vertices`` is empty."""
    n = results.node_count
    for v in vertices or ():
        if not 0 <= v < n:
            raise ResultsError(f"--vertex {v}: out of range; the mesh has {n} vertices (0 to {n - 1})")
    magnitudes = [np.linalg.norm(results.field("displacement", i), axis=1) for i in range(results.frame_count)]
    magnitudes = np.array(magnitudes)                       # (k, n)
    if vertices:
        return [(f"vertex {v}", magnitudes[:, v]) for v in vertices]
    return [("max over vertices", magnitudes.max(axis=1))]


def total_energy_label(scene):
    """The legend of the energies' sum for a run of ``scene`` (its stored config, a dict).  The
    ground's penalty springs hold energy the file does not record: during a contact the sum dips
    by it (the bouncing cube: 32.5 -> 27 J at each bounce), which is no energy lost."""
    return "total (no contact energy)" if scene.get("ground") else "total"


def plot_history(path, output, vertices=None):
    """Write a PNG to ``output``: the energies (when the run recorded them) and the displacement of
    ``vertices`` (default: the largest displacement) against time.  Returns ``output``."""
    Figure, FigureCanvasAgg = _matplotlib()
    with open_results(path) as results:
        times = results.times
        energy = results.energy()
        curves = displacement_history(results, vertices)
        title = f"{results.path.name}: {results.scene.get('material', {}).get('model', '')} " \
                f"({results.attrs.get('status', '')})"
        total = total_energy_label(results.scene)
    panels = 2 if energy else 1
    figure = Figure(figsize=(7.0, 2.8 * panels + 0.4), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    if energy:
        ax = axes[0]
        for term, values in energy.items():
            ax.plot(times, values, label=term)
        ax.plot(times, sum(energy.values()), "k--", label=total)
        ax.set_ylabel("energy [J]")
        ax.legend(loc="best", fontsize="small")
        ax.grid(alpha=0.3)
    ax = axes[-1]
    for label, values in curves:
        ax.plot(times, values * 1e3, label=label)
    ax.set_ylabel("|displacement| [mm]")
    ax.set_xlabel("time [s]")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    figure.suptitle(title)
    try:
        figure.savefig(output, dpi=110)
    except (OSError, ValueError) as exc:
        raise ResultsError(f"-o '{output}': cannot write the plot ({str(exc).splitlines()[0]})") from None
    return output
