"""``softsim stability``: run the stress catalogue for every material model, measure the stability
limit against the ``dt: auto`` step, and write a table (CSV) and a plot (PNG).

``stability_report(out_dir, quick)`` does everything and returns a ``StabilityReport``; nothing
here prints (progress goes to an optional callback).  It writes into ``out_dir``:

- ``scenes/<scene>-<model>.yaml``: each catalogue scene, to rerun with ``softsim run``;
- ``runs/<scene>-<model>.h5``: each run's output (a stopped run keeps its frames before the stop);
- ``meshes/``: the hand-made meshes the scenes and the measurement use;
- ``stability.csv``: one row per (scene, model), the columns of ``COLUMNS``;
- ``limits.csv``: one row per measured case (``limits.LimitMeasurement``);
- ``stability.png``: the measured limit against the ``auto`` step, per model (needs matplotlib,
  the ``plot`` extra; without it ``StabilityReport.plot_note`` says so and the rest is written).

Catalogue outcomes: ``finished``; ``stopped: <reason>`` when the run raised a ``SoftsimError``
(the guard's one-line message); ``refused: <reason>`` when ``prepare`` raised one before anything
was written (``dt_policy: refuse``).

Energy drift is ``(E_last - E_first) / max_frames(kinetic + elastic)`` with ``E`` the total energy
kinetic + elastic + gravity: the change of what should be conserved, relative to the energy that
moves around (independent of the gravity datum).  Damping, a penalty ground (its spring energy is
not in the output) and held regions that move (they do work) make it meaningless; ``drift_note``
says which.
"""

import csv
import logging
import time as _time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import PLOT_EXTRA, ConfigError, MissingDependencyError, SoftsimError
from ..io.files import writable_folder
from ..kernels import compile_ahead
from ..kernels.jit import compile_timer
from ..io.hdf5 import frames_written, read_resume_state
from .catalogue import MODELS, SCENE_NAMES, catalogue
from .limits import MESH_KINDS, LimitCase, limit_cases, limit_meshes, limit_scene, measure_limit, verdicts

COLUMNS = ("scene", "model", "outcome", "steps", "steps_planned", "dt_s", "max_abs_J_minus_1", "min_J",
           "min_J_last", "energy_drift", "drift_note", "wall_time_s", "warnings")
LIMIT_COLUMNS = ("model", "youngs_modulus", "poissons_ratio", "density", "mesh", "auto_dt_s", "exact_dt_s",
                 "measured_dt_s", "unstable_dt_s", "measured_over_auto", "exact_over_auto", "measured_over_exact",
                 "blowup_steps", "steps", "runs", "wall_time_s")

# The grid of the measured limits: (Young's moduli [Pa], Poisson ratios), quick and full.
QUICK_GRID = ((1e5, 2e11), (0.3, 0.499))
FULL_GRID = ((1e5, 1e7, 2e11), (0.3, 0.45, 0.49, 0.499))
QUICK_LIMIT_STEPS = 3000
FULL_LIMIT_STEPS = 5000


@dataclass(frozen=True)
class CatalogueRow:
    """One (scene, model) run of the catalogue; see ``COLUMNS`` and the module docstring.

    steps: steps done up to the last written frame; steps_planned: the run's plan; dt [s]; J:
    volume ratio of the tets over all written frames (min_J_last: in the last one); None where
    nothing was written.  warnings: what the library logged during the run.
    """

    scene: str
    model: str
    outcome: str
    steps: int
    steps_planned: int
    dt: float | None
    max_abs_J_minus_1: float | None
    min_J: float | None
    min_J_last: float | None
    energy_drift: float | None
    drift_note: str
    wall_time_s: float
    path: str | None
    warnings: tuple = field(default=())

    @property
    def status(self):
        """``finished``, ``stopped`` or ``refused``."""
        return self.outcome.split(":", 1)[0]

    def csv_values(self):
        return (self.scene, self.model, self.outcome, self.steps, self.steps_planned, _blank(self.dt),
                _blank(self.max_abs_J_minus_1), _blank(self.min_J), _blank(self.min_J_last),
                _blank(self.energy_drift), self.drift_note, f"{self.wall_time_s:.3f}", " | ".join(self.warnings))


@dataclass(frozen=True)
class StabilityReport:
    """What ``stability_report`` produced.

    rows: ``CatalogueRow`` per (scene, model); limits: ``LimitMeasurement`` per case; verdicts:
    ``{model: (min, max, ok)}`` of measured / auto; paths of what was written (``plot_path`` None
    without matplotlib, ``plot_note`` then says which extra adds it); wall_time_s of the whole report.
    """

    out_dir: Path
    rows: list
    limits: list
    verdicts: dict
    csv_path: Path
    limits_csv_path: Path | None
    plot_path: Path | None
    plot_note: str | None
    wall_time_s: float

    def table(self):
        """The catalogue table, aligned, as text."""
        return format_table(self.rows)

    def limit_table(self):
        """measured / auto per mesh kind and nu (rows) and model (columns), min-max over E, as text."""
        return format_limit_table(self.limits)

    def verdict_lines(self):
        """One line per model: min / max of measured / auto and whether ``auto <= limit <= 2 auto``."""
        return verdict_lines(self.limits, self.verdicts)


def _blank(value):
    return "" if value is None else f"{value:.6g}"


# ---------------------------------------------------------------------------------------------
# Catalogue runs


@contextmanager
def _captured_warnings():
    """Collect (and keep off the console) what the ``softsim`` logger warns about, as strings."""
    logger = logging.getLogger("softsim")
    records = []

    class Capture(logging.Filter):
        def filter(self, record):
            if record.levelno >= logging.WARNING:
                records.append(record.getMessage())
                return False
            return True

    capture = Capture()
    logger.addFilter(capture)
    try:
        yield records
    finally:
        logger.removeFilter(capture)


def volume_ratios(points, tets, frames):
    """``J = det F`` (k, m) of every tet in every frame: frames (k, n, 3), rest points (n, 3) [m]."""
    X = points[tets]
    rest = np.linalg.det(X[:, 1:] - X[:, :1])
    x = frames[:, tets]                                          # (k, m, 4, 3)
    return np.linalg.det(x[:, :, 1:] - x[:, :, :1]) / rest


def run_metrics(path):
    """``(steps, dt, max |J - 1|, min J, min J of the last frame, energy drift)`` of an output file."""
    import h5py

    with h5py.File(path, "r") as f:
        state = read_resume_state(f)
        steps = int(state["step"]) if state is not None else 0      # None: stopped before frame 0
        dt = float(f.attrs["dt"])
        k = frames_written(f)
        J = volume_ratios(f["mesh/points"][:], f["mesh/tets"][:], f["frames/points"][:k])
        drift = None
        if "frames/energy" in f and k > 1:
            e = {term: f["frames/energy"][term][:k] for term in ("kinetic", "elastic", "gravity")}
            mechanical = e["kinetic"] + e["elastic"]
            total = mechanical + e["gravity"]
            scale = float(np.max(mechanical))
            drift = float((total[-1] - total[0]) / scale) if scale > 0.0 else 0.0
    if J.size == 0:
        return steps, dt, None, None, None, drift
    return steps, dt, float(np.abs(J - 1.0).max()), float(J.min()), float(J[-1].min()), drift


def _one_line(error):
    return " ".join(str(error).split())


def run_catalogue_scene(entry, model, out_dir):
    """Run catalogue scene ``entry`` with material ``model`` into ``out_dir/runs``; a ``CatalogueRow``.

    Its scene file goes to ``out_dir/scenes/<scene>-<model>.yaml`` first (``output.path`` there is
    ``<scene>-<model>.h5``, relative to where the user reruns it); a scene the schema refuses (an
    inverted start for a model that cannot recover from one) is written as given, and its row
    says ``refused``.
    """
    import yaml

    from ..config import parse_scene, scene_to_yaml
    from ..simulation import prepare, simulate

    out_dir = Path(out_dir)
    name = f"{entry.name}-{model}"
    data = entry.scene_data(model)
    data["output"] = {**data.get("output", {}), "path": f"{name}.h5"}
    (out_dir / "scenes").mkdir(parents=True, exist_ok=True)
    scene_file = out_dir / "scenes" / f"{name}.yaml"
    path = out_dir / "runs" / f"{name}.h5"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)                      # no stale file from an earlier report
    path.with_suffix(".xdmf").unlink(missing_ok=True)
    note = ", ".join(entry.drift_caveats)
    try:
        scene = parse_scene(data)
    except ConfigError as exc:
        scene_file.write_text(yaml.safe_dump(data, sort_keys=False))
        return CatalogueRow(entry.name, model, f"refused: {_one_line(exc)}", 0, 0, None, None, None, None,
                            None, note, 0.0, None, ())
    scene_file.write_text(scene_to_yaml(scene))
    scene = scene.model_copy(update={"output": scene.output.model_copy(update={"path": str(path)})})
    started = _time.perf_counter()
    with _captured_warnings() as warnings, compile_timer() as compiled:
        try:
            prepared = prepare(scene)
        except SoftsimError as exc:
            return CatalogueRow(entry.name, model, f"refused: {_one_line(exc)}", 0, 0, None, None, None, None,
                                None, note, _time.perf_counter() - started - compiled(), None, tuple(warnings))
        try:
            simulate(prepared, path)
            outcome = "finished"
        except SoftsimError as exc:
            outcome = f"stopped: {_one_line(exc)}"
        wall = _time.perf_counter() - started - compiled()      # the first run of a model compiles its step
    if not path.is_file():       # stopped before the file existed
        return CatalogueRow(entry.name, model, outcome, 0, prepared.plan.total_steps, prepared.plan.dt, None, None,
                            None, None, note, wall, None, tuple(warnings))
    steps, dt, strain, min_J, min_J_last, drift = run_metrics(path)
    return CatalogueRow(entry.name, model, outcome, steps, prepared.plan.total_steps, dt, strain, min_J, min_J_last,
                        drift, note, wall, str(path), tuple(warnings))


def _check_scene_names(scenes):
    """``ConfigError`` for a name in ``scenes`` (None: all) that is no catalogue scene's."""
    unknown = [name for name in scenes or () if name not in SCENE_NAMES]
    if unknown:
        raise ConfigError(f"unknown catalogue scene {', '.join(unknown)} (known: {', '.join(sorted(SCENE_NAMES))})")


def catalogue_run_calls(entries, models):
    """The calls of the guard's measure and of the step (``simulation.run_calls``) that the runs
    of ``entries`` x ``models`` make first, ``[(kernel, arguments), ...]``; scenes that the schema
    or the model refuses are left out (their rows say why)."""
    from ..config import parse_scene
    from ..simulation import run_calls, scene_model

    calls = []
    for entry in entries:
        for model in models:
            try:
                scene = parse_scene(entry.scene_data(model))
                calls += run_calls(scene, scene_model(scene))
            except SoftsimError:
                continue
    return calls


def run_catalogue(out_dir, quick=False, scenes=None, models=MODELS, progress=None):
    """Run every catalogue scene (or those named in ``scenes``) for every model in ``models``.

    Returns the ``CatalogueRow``s; ``progress(text)`` is called after each run.  Raises
    ``ConfigError`` for an unknown scene name.
    """
    out_dir = Path(out_dir)
    _check_scene_names(scenes)
    entries = catalogue(out_dir / "meshes", quick=quick)
    if scenes is not None:
        entries = [entry for entry in entries if entry.name in scenes]
    if compile_ahead.enabled():       # on both cores, before the first run
        compile_ahead.compile_shared(catalogue_run_calls(entries, models))
    rows = []
    total = len(entries) * len(models)
    for entry in entries:
        for model in models:
            row = run_catalogue_scene(entry, model, out_dir)
            rows.append(row)
            if progress is not None:
                progress(f"[{len(rows)}/{total}] {row.scene} / {row.model}: {row.status} ({row.wall_time_s:.1f} s)")
    return rows


def write_csv(rows, path):
    """Write the catalogue rows to ``path`` (header ``COLUMNS``)."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow(row.csv_values())
    return Path(path)


def _fmt(value, spec):
    return "-" if value is None else format(value, spec)


def format_table(rows):
    """The catalogue rows as an aligned text table (the outcome, with its reason, last)."""
    header = ("scene", "model", "steps", "dt [s]", "max|J-1|", "min J", "min J end", "drift", "drift note",
              "wall [s]", "outcome")
    body = []
    for r in rows:
        steps = f"{r.steps}/{r.steps_planned}" if r.steps != r.steps_planned else str(r.steps)
        body.append((r.scene, r.model, steps, _fmt(r.dt, ".3g"), _fmt(r.max_abs_J_minus_1, ".3g"),
                     _fmt(r.min_J, ".3g"), _fmt(r.min_J_last, ".3g"), _fmt(r.energy_drift, "+.2e"),
                     r.drift_note or "-", f"{r.wall_time_s:.2f}", r.outcome))
    numeric = {2, 3, 4, 5, 6, 7, 9}
    widths = [max(len(str(line[i])) for line in [header] + body) for i in range(len(header) - 1)]

    def render(line):
        cells = [str(c).rjust(w) if i in numeric else str(c).ljust(w) for i, (c, w) in enumerate(zip(line, widths))]
        return "  ".join(cells + [str(line[-1])])

    lines = [render(header), "  ".join("-" * w for w in widths) + "  " + "-" * len(header[-1])]
    lines += [render(line) for line in body]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Measured limits


def limit_step_calls(cases, meshes):
    """The calls of the step (``simulation.step_calls``) that the measurements of ``cases`` on
    ``meshes`` (``{kind: path}``) make, ``[(kernel, arguments), ...]``."""
    from ..simulation import scene_model, step_calls

    calls = []
    for case in cases:
        scene = limit_scene(case, meshes[case.mesh_kind])
        calls += step_calls(scene, scene_model(scene))
    return calls


def measure_limits(out_dir, cases, steps=QUICK_LIMIT_STEPS, bracket="theory", progress=None):
    """``LimitMeasurement`` of each ``LimitCase`` in ``cases``; meshes go to ``out_dir/meshes``.

    bracket: ``"theory"`` or ``"wide"``, where the search starts (``limits.measure_limit``).
    """
    kinds = tuple(kind for kind in MESH_KINDS if any(case.mesh_kind == kind for case in cases))
    meshes = limit_meshes(Path(out_dir) / "meshes", kinds)
    if compile_ahead.enabled():       # on both cores, before the first measurement
        compile_ahead.compile_shared(limit_step_calls(cases, meshes))
    out = []
    for case in cases:
        with _captured_warnings():
            measurement = measure_limit(case, meshes[case.mesh_kind], steps=steps, bracket=bracket)
        out.append(measurement)
        if progress is not None:
            progress(f"[{len(out)}/{len(cases)}] limit {case.label}: measured / auto {measurement.ratio:.3f} "
                     f"({measurement.wall_time_s:.1f} s)")
    return out


def write_limits_csv(measurements, path):
    """Write the measured limits to ``path`` (header ``LIMIT_COLUMNS``)."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(LIMIT_COLUMNS)
        for m in measurements:
            c = m.case
            writer.writerow((c.model, f"{c.youngs_modulus:g}", f"{c.poissons_ratio:g}", f"{c.density:g}", c.mesh_kind,
                             f"{m.auto_dt:.6g}", f"{m.exact_dt:.6g}", f"{m.measured_dt:.6g}", f"{m.unstable_dt:.6g}",
                             f"{m.ratio:.4f}", f"{m.exact_dt / m.auto_dt:.4f}", f"{m.measured_dt / m.exact_dt:.4f}",
                             m.blowup_steps, m.steps, m.runs, f"{m.wall_time_s:.3f}"))
    return Path(path)


def format_limit_table(measurements):
    """measured / auto, rows (mesh kind, nu), columns models, each cell min-max over E."""
    if not measurements:
        return ""
    models = [m for m in MODELS if any(x.case.model == m for x in measurements)]
    keys = sorted({(x.case.mesh_kind, x.case.poissons_ratio) for x in measurements},
                  key=lambda k: (MESH_KINDS.index(k[0]) if k[0] in MESH_KINDS else 99, k[1]))
    header = ["mesh", "nu"] + models
    body = []
    for kind, nu in keys:
        cells = [kind, f"{nu:g}"]
        for model in models:
            ratios = [x.ratio for x in measurements if (x.case.mesh_kind, x.case.poissons_ratio, x.case.model)
                      == (kind, nu, model)]
            if not ratios:
                cells.append("-")
            elif max(ratios) - min(ratios) < 0.005:
                cells.append(f"{min(ratios):.2f}")
            else:
                cells.append(f"{min(ratios):.2f}-{max(ratios):.2f}")
        body.append(cells)
    widths = [max(len(line[i]) for line in [header] + body) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
             for line in [header] + body]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def verdict_lines(measurements, model_verdicts):
    """One line per model, then one on how fast growth showed above the limit."""
    lines = []
    for model in [m for m in MODELS if m in model_verdicts]:
        low, high, ok = model_verdicts[model]
        mine = [x for x in measurements if x.case.model == model]
        if ok:
            verdict = "ok: auto is safe and within 2x of the limit"
        else:
            problems = []
            unsafe = [x for x in mine if x.ratio < 1.0]
            wasteful = [x for x in mine if x.ratio > 2.0]
            if unsafe:
                worst = min(unsafe, key=lambda x: x.ratio)
                problems.append(f"UNSAFE in {len(unsafe)} case(s): limit below auto "
                                f"(worst {worst.ratio:.2f}: {worst.case.mesh_kind}, nu={worst.case.poissons_ratio:g})")
            if wasteful:
                worst = max(wasteful, key=lambda x: x.ratio)
                problems.append(f"WASTEFUL in {len(wasteful)} case(s): limit above 2x auto "
                                f"(worst {worst.ratio:.2f}: {worst.case.mesh_kind}, nu={worst.case.poissons_ratio:g})")
            verdict = "; ".join(problems)
        exact = [x.measured_dt / x.exact_dt for x in mine]
        lines.append(f"{model}: measured / auto {low:.2f}-{high:.2f} over {len(mine)} cases "
                     f"(measured / exact eigenvalue limit {min(exact):.3f}-{max(exact):.3f}): {verdict}")
    if measurements:
        slowest = max(measurements, key=lambda x: x.blowup_steps)
        lines.append(f"growth above the limit showed within {slowest.blowup_steps} steps at most "
                     f"(at {slowest.unstable_dt / slowest.measured_dt - 1:.1%} above the measured limit, "
                     f"{slowest.case.label}); a stable verdict took {slowest.steps} steps")
    return lines


# ---------------------------------------------------------------------------------------------
# Plot


def _matplotlib():
    """``(Figure, FigureCanvasAgg)``, or ``MissingDependencyError`` naming the extra."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingDependencyError(f"the stability plot needs matplotlib: {PLOT_EXTRA}") from None
    return Figure, FigureCanvasAgg


MESH_COLOURS = {"structured": "tab:blue", "gmsh": "tab:green", "slivers": "tab:red"}
NU_MARKERS = {0.3: "o", 0.45: "s", 0.49: "^", 0.499: "D"}
# the eigenvalue limit: an open black circle around the measured marker (they nearly coincide)
EXACT_STYLE = dict(marker="o", ms=13, mfc="none", mec="k", mew=0.8, ls="none")


def plot_limits(measurements, path):
    """Write the stability plot (PNG) of ``measurements`` to ``path``; raises ``MissingDependencyError``
    without matplotlib.  Uses the Agg canvas directly (no pyplot, no global backend change)."""
    Figure, FigureCanvasAgg = _matplotlib()
    from matplotlib.lines import Line2D

    models = [m for m in MODELS if any(x.case.model == m for x in measurements)]
    figure = Figure(figsize=(4.2 * len(models), 8.2), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(2, len(models), squeeze=False)
    autos = np.array([x.auto_dt for x in measurements])
    lo, hi = autos.min() / 2.0, autos.max() * 2.0
    line = np.array([lo, hi])
    for j, model in enumerate(models):
        mine = [x for x in measurements if x.case.model == model]
        top, bottom = axes[0, j], axes[1, j]
        top.fill_between(line, line, 2 * line, color="0.92", zorder=0)
        top.plot(line, line, "k-", lw=1, label="y = x (auto)")
        top.plot(line, 2 * line, "k--", lw=1, label="y = 2x")
        bottom.axhspan(1.0, 2.0, color="0.92", zorder=0)
        bottom.axhline(1.0, color="k", lw=1)
        bottom.axhline(2.0, color="k", lw=1, ls="--")
        for x in mine:
            style = dict(color=MESH_COLOURS.get(x.case.mesh_kind, "k"),
                         marker=NU_MARKERS.get(x.case.poissons_ratio, "P"), ms=7, ls="none", alpha=0.85)
            top.plot([x.auto_dt], [x.measured_dt], **style)
            top.plot([x.auto_dt], [x.exact_dt], **EXACT_STYLE)
            bottom.plot([x.auto_dt], [x.ratio], **style)
            bottom.plot([x.auto_dt], [x.exact_dt / x.auto_dt], **EXACT_STYLE)
        ratios = [x.ratio for x in mine]
        top.set_title(f"{model}: measured / auto {min(ratios):.2f}-{max(ratios):.2f}")
        for ax in (top, bottom):
            ax.set_xscale("log")
            ax.set_xlim(lo, hi)
            ax.grid(True, which="major", alpha=0.3)
            ax.set_xlabel("dt: auto [s]")
        top.set_yscale("log")
        top.set_ylim(lo, 2 * hi)
        top.set_ylabel("largest stable dt [s]")
        bottom.set_ylim(0.0, max(3.0, max(ratios) * 1.1))
        bottom.set_ylabel("measured / auto")
    handles = [Line2D([], [], color=c, marker="o", ls="none", label=f"mesh: {k}") for k, c in MESH_COLOURS.items()
               if any(x.case.mesh_kind == k for x in measurements)]
    handles += [Line2D([], [], color="0.3", marker=m, ls="none", label=f"nu = {nu:g}") for nu, m in NU_MARKERS.items()
                if any(x.case.poissons_ratio == nu for x in measurements)]
    handles += [Line2D([], [], label="exact 2/omega_max (Lanczos)", **EXACT_STYLE),
                Line2D([], [], color="k", lw=1, label="y = auto"), Line2D([], [], color="k", lw=1, ls="--",
                                                                          label="y = 2 auto")]
    figure.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 6), frameon=False)
    spread = max(x.unstable_dt / x.measured_dt for x in measurements) - 1
    figure.suptitle("Symplectic Euler: measured largest stable dt (energy bounded over "
                    f"{measurements[0].steps} steps; a stable and an unstable run within {spread:.1%} of each "
                    f"other, most in {max(x.runs for x in measurements)} runs) against the dt: auto step")
    figure.savefig(path, dpi=110)
    return Path(path)


# ---------------------------------------------------------------------------------------------
# Everything


def default_limit_cases(quick, models=MODELS):
    """The measurement grid: every model x mesh kind x nu x E of ``QUICK_GRID`` / ``FULL_GRID``."""
    youngs, poissons = QUICK_GRID if quick else FULL_GRID
    return limit_cases(models, youngs, poissons)


def stability_report(out_dir, quick=False, scenes=None, models=MODELS, cases=None, limit_steps=None,
                     plot=True, progress=None):
    """Run the catalogue and the limit measurement into ``out_dir``; a ``StabilityReport``.

    scenes: catalogue scene names (default all); models: material models (default all four);
    cases: the ``LimitCase``s to measure (default ``default_limit_cases(quick, models)``; an empty
    list skips the measurement and the plot); limit_steps: run length of a stable verdict (default
    3000, 5000 in full mode); the search starts around the eigenvalue limit in quick mode and at
    [auto, 3 auto], independent of it, in full mode; plot: write the PNG when matplotlib is there; progress: callable
    taking one line of text after each run.
    """
    started = _time.perf_counter()
    out_dir = Path(out_dir)
    models = tuple(models)
    unknown = [m for m in models if m not in MODELS]
    if unknown:
        raise ConfigError(f"unknown material model {', '.join(unknown)} (known: {', '.join(MODELS)})")
    _check_scene_names(scenes)
    writable_folder(out_dir)
    rows = run_catalogue(out_dir, quick=quick, scenes=scenes, models=models, progress=progress)
    csv_path = write_csv(rows, out_dir / "stability.csv")
    if cases is None:
        cases = default_limit_cases(quick, models)
    steps = limit_steps or (QUICK_LIMIT_STEPS if quick else FULL_LIMIT_STEPS)
    bracket = "theory" if quick else "wide"
    limits = measure_limits(out_dir, list(cases), steps=steps, bracket=bracket, progress=progress) if cases else []
    limits_csv = write_limits_csv(limits, out_dir / "limits.csv") if limits else None
    plot_path = plot_note = None
    if limits and plot:
        try:
            plot_path = plot_limits(limits, out_dir / "stability.png")
        except MissingDependencyError:
            plot_note = f"no plot: matplotlib is not installed ({PLOT_EXTRA} adds it)"
    return StabilityReport(out_dir=out_dir, rows=rows, limits=limits, verdicts=verdicts(limits) if limits else {},
                           csv_path=csv_path, limits_csv_path=limits_csv, plot_path=plot_path, plot_note=plot_note,
                           wall_time_s=_time.perf_counter() - started)


__all__ = ["COLUMNS", "LIMIT_COLUMNS", "CatalogueRow", "LimitCase", "StabilityReport", "default_limit_cases",
           "format_table", "measure_limits", "plot_limits", "run_catalogue", "run_catalogue_scene", "run_metrics",
           "stability_report", "volume_ratios", "write_csv", "write_limits_csv"]
