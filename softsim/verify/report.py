"""``softsim verify``: run the verification cases and write what accuracy costs.

``verify_report(out_dir, quick, cases, models)`` runs the cases (``cases.CASES``) and writes into
``out_dir``:

- ``verify.csv``: one row per run and measured quantity (the columns of ``COLUMNS``);
- ``verify_<case>.png``: error against wall time, log-log, one line per model and ladder, the
  Pareto front (no other run is both faster and more accurate) marked; needs matplotlib (the
  ``plot`` extra: without it ``VerifyReport.plot_note`` says so and the rest is written);
- ``verify.md``: the plots, the fitted convergence orders, and for error budgets of 1 % and
  0.1 % the cheapest run that met each (where the reference itself is good enough to tell).

Wall times count the time steps only (``driver.Run``); they depend on the machine and its load,
which ``verify.md`` records.  Nothing here prints: progress goes to an optional callback.
"""

import csv
import math
import os
import platform
import re
import time as _time
from dataclasses import dataclass
from pathlib import Path

from ..config.schema import FLOAT32_MODELS, PRECISIONS
from ..errors import PLOT_EXTRA, ConfigError, MissingDependencyError
from ..io.files import writable_folder
from ..kernels import compile_ahead
from . import references as ref
from .cases import CASES, MODELS, VerifyRow

COLUMNS = ("case", "quantity", "model", "precision", "ladder", "refinement", "element_size_m", "tets", "dt_s",
           "steps", "wall_time_s", "value", "reference_value", "error", "reference", "reference_uncertainty",
           "order", "order_self", "note")
BUDGETS = (1e-2, 1e-3)
# Wall times this close (relative) count as equal when picking the cheapest run for a budget.
TIME_NOISE = 0.5
MODEL_COLOURS = {"linear": "tab:gray", "stvk": "tab:blue", "corotated": "tab:green", "neohookean": "tab:red"}
LADDER_STYLES = {"element_size": ("o", "-"), "dt": ("s", "--"), "load": ("^", ":"), "-": ("D", "none")}


@dataclass(frozen=True)
class VerifyReport:
    """What ``verify_report`` produced: the rows (``cases.VerifyRow``), the paths written
    (``plot_paths`` empty without matplotlib, ``plot_note`` then names the extra), the budget
    answers ``{case: [sentence, ...]}`` and the wall time of the whole report [s]."""

    out_dir: Path
    quick: bool
    rows: list
    csv_path: Path
    summary_path: Path
    plot_paths: dict
    plot_note: str | None
    budgets: dict
    wall_time_s: float

    def table(self):
        return format_table(self.rows)


def _blank(value, spec=".6g"):
    return "" if value is None else format(value, spec)


def write_csv(rows, path):
    """Write ``rows`` to ``path`` (header ``COLUMNS``)."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        for r in rows:
            writer.writerow((r.case, r.quantity, r.model, r.precision, r.ladder, f"{r.refinement:.6g}",
                             f"{r.element_size:.6g}", r.tets, f"{r.dt:.6g}", r.steps, f"{r.wall_time_s:.6g}",
                             f"{r.value:.10g}", f"{r.reference_value:.10g}", f"{r.error:.4e}", r.reference,
                             f"{r.reference_uncertainty:.2e}", _blank(r.order, ".3f"), _blank(r.order_self, ".3f"),
                             r.note))
    return Path(path)


def format_table(rows):
    """The rows as an aligned text table (the note left out; it is in the CSV)."""
    header = ("case", "quantity", "model", "precision", "ladder", "tets", "dt [s]", "steps", "wall [s]", "error",
              "order", "reference")
    body = [(r.case, r.quantity, r.model, r.precision, r.ladder, str(r.tets), f"{r.dt:.3g}", str(r.steps),
             f"{r.wall_time_s:.2f}", f"{r.error:.2e}", _blank(r.order, ".2f") or "-", r.reference) for r in rows]
    numeric = {5, 6, 7, 8, 9, 10}
    widths = [max(len(line[i]) for line in [header] + body) for i in range(len(header) - 1)]

    def render(line):
        cells = [c.rjust(w) if i in numeric else c.ljust(w) for i, (c, w) in enumerate(zip(line, widths))]
        return "  ".join(cells + [line[-1]])

    lines = [render(header), "  ".join("-" * w for w in widths) + "  " + "-" * len(header[-1])]
    return "\n".join(lines + [render(line) for line in body])


# ---------------------------------------------------------------------------------------------
# Analysis


def pareto_front(times, errors):
    """Indices of the points no other point beats in both time and error, ordered by time."""
    order = sorted(range(len(times)), key=lambda i: (times[i], errors[i]))
    front, best = [], math.inf
    for i in order:
        if errors[i] < best:
            front.append(i)
            best = errors[i]
    return front


def ladders(rows):
    """``{(case, quantity, variant, ladder): [rows coarse -> fine]}`` of the rows with a ladder
    (variant: ``VerifyRow.variant``, the model and a precision other than float64)."""
    groups = {}
    for r in rows:
        if r.ladder != "-":
            groups.setdefault((r.case, r.quantity, r.variant, r.ladder), []).append(r)
    return {k: sorted(v, key=lambda r: -r.refinement) for k, v in groups.items()}


def fitted_orders(rows):
    """``{(case, quantity, variant, ladder): (order over all rungs, order over the last two)}``."""
    out = {}
    for key, group in ladders(rows).items():
        p = [r.refinement for r in group]
        e = [r.error for r in group]
        out[key] = (ref.fitted_order(p, e), group[-1].order)
    return out


def _describe(r):
    return (f"{r.variant}, element size {r.element_size:.3g} m ({r.tets} tets), dt {r.dt:.3g} s, {r.steps} steps: "
            f"{r.wall_time_s:.3g} s (error {r.error:.2e} against {r.reference})")


def budget_answers(rows, case_name, quantity, budgets=BUDGETS):
    """Plain sentences: for each budget, the cheapest run of ``quantity`` whose error met it, where
    the reference's own uncertainty is at most half the budget.  Wall times within ``TIME_NOISE``
    of the fastest count as equal (timings on a shared machine move that much): of those, the run
    with the least work (tets x steps) is the answer, so that the pick does not follow timer noise."""
    mine = [r for r in rows if r.case == case_name and r.quantity == quantity]
    lines = []
    if not mine:
        return lines
    for budget in budgets:
        trusted = [r for r in mine if r.reference_uncertainty <= 0.5 * budget]
        met = [r for r in trusted if r.error <= budget]
        label = f"{budget * 100:g} %"
        if met:
            fastest = min(r.wall_time_s for r in met)
            best = min((r for r in met if r.wall_time_s <= (1.0 + TIME_NOISE) * fastest),
                       key=lambda r: (r.tets * max(r.steps, 1), r.wall_time_s))
            lines.append(f"{label}: {_describe(best)}")
        elif any(r.error <= budget for r in mine):
            best = min(r.reference_uncertainty for r in mine)
            lines.append(f"{label}: cannot be told: the reference is itself only good to {best:.1e} relative")
        else:
            best = min(mine, key=lambda r: r.error)
            lines.append(f"{label}: not reached; the most accurate run was {_describe(best)}"
                         + _extrapolated_cost(mine, best, budget))
    return lines


def _extrapolated_cost(rows, best, budget):
    """``; extrapolating ...`` for an element-size ladder: the element size that the fitted order
    of the last three rungs predicts for ``budget``, and its cost with tets ~ h^-3 and steps ~ h^-1
    (dt: auto); empty where there is no such ladder or no convergence."""
    if best.ladder != "element_size":
        return ""
    group = sorted((r for r in rows if r.variant == best.variant and r.ladder == "element_size"),
                   key=lambda r: -r.refinement)[-3:]
    order = ref.fitted_order([r.refinement for r in group], [r.error for r in group])
    if order is None or order < 0.3 or len(group) < 2:
        return ""
    h = best.element_size * (budget / best.error) ** (1.0 / order)
    scale = (best.element_size / h) ** 4
    return (f"; extrapolating its order {order:.2f}: element size ~{h:.2g} m, ~{best.tets * scale ** 0.75:.2g} tets, "
            f"~{best.wall_time_s * scale:.2g} s")


# ---------------------------------------------------------------------------------------------
# Plots


def _matplotlib():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingDependencyError(f"the verification plots need matplotlib: {PLOT_EXTRA}") from None
    return Figure, FigureCanvasAgg


# Errors below this are drawn at it (exact zeros cannot sit on a log axis).
PLOT_FLOOR = 1e-17


def plot_case(case, rows, path):
    """Error against wall time for one case (one panel per quantity), PNG at ``path``."""
    Figure, FigureCanvasAgg = _matplotlib()
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogFormatterSciNotation, LogLocator, NullFormatter

    quantities = []
    for r in rows:
        if r.quantity not in quantities:
            quantities.append(r.quantity)
    if case.primary in quantities:
        quantities.remove(case.primary)
        quantities.insert(0, case.primary)
    columns = min(2, len(quantities))
    lines = math.ceil(len(quantities) / columns)
    figure = Figure(figsize=(7.6 * columns, 4.8 * lines), layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.subplots(lines, columns, squeeze=False).ravel()
    for unused in grid[len(quantities):]:
        unused.set_visible(False)
    axes = grid[:len(quantities)]
    for ax, quantity in zip(axes, quantities):
        mine = [r for r in rows if r.quantity == quantity]
        groups = {}
        for r in mine:
            groups.setdefault((r.variant, r.ladder), []).append(r)
        for (variant, ladder), group in groups.items():
            group.sort(key=lambda r: -r.refinement)
            marker, line = LADDER_STYLES.get(ladder, ("o", "-"))
            label = variant if ladder == "-" else f"{variant}, {ladder.replace('_', ' ')} ladder"
            single = group[0].precision == "float32"      # float32: open markers
            ax.plot([r.wall_time_s for r in group], [max(r.error, PLOT_FLOOR) for r in group], marker=marker,
                    ls=line, color=MODEL_COLOURS.get(group[0].model, "k"), ms=5, lw=1.2, alpha=0.85, label=label,
                    mfc="none" if single else None)
        times = [r.wall_time_s for r in mine]
        errors = [max(r.error, PLOT_FLOOR) for r in mine]
        front = pareto_front(times, errors)
        ax.plot([times[i] for i in front], [errors[i] for i in front], color="k", lw=0.8, ls=(0, (2, 2)),
                drawstyle="steps-post", zorder=1)
        ax.plot([times[i] for i in front], [errors[i] for i in front], ls="none", marker="o", ms=11, mfc="none",
                mec="k", mew=1.0, label="Pareto front", zorder=3)
        shown = set()
        for i in front:
            r = mine[i]
            text = {"element_size": f"{r.tets} tets", "dt": f"dt {r.dt:.2g} s",
                    "load": f"sigma/E {r.refinement:g}"}.get(r.ladder, "")
            if not text or text in shown:
                continue
            shown.add(text)
            ax.annotate(text, (times[i], errors[i]), xytext=(6, -10), textcoords="offset points", fontsize=6,
                        color="0.25")
        ax.set_xscale("log")
        ax.set_yscale("log")
        decades = math.log10(max(times) / min(times)) if min(times) > 0.0 else 9.0
        if decades < 0.7:                 # under a decade: three labels at the ends and between, not crowded
            ticks = [min(times), math.sqrt(min(times) * max(times)), max(times)] if decades > 0 else [min(times)]
            ax.xaxis.set_major_locator(FixedLocator(ticks))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:.2g}"))
        elif decades < 2.5:               # short ranges: label 1, 2, 5 x 10^k, not only the powers of ten
            ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(LogFormatterSciNotation(labelOnlyBase=False))
        ax.xaxis.set_minor_formatter(NullFormatter())
        low, high = min(errors), max(errors)
        if high < 30.0 * low:             # at least three decades: round-off noise must not look like a trend
            centre = math.sqrt(low * high)
            ax.set_ylim(centre / 30.0, centre * 30.0)
        bottom, top = ax.get_ylim()
        for budget in BUDGETS:
            if bottom < budget < top:     # a budget line and its label only where they fall inside the axes
                ax.axhline(budget, color="0.6", lw=0.8, ls=":")
                ax.annotate(f"{budget * 100:g} %", (1.0, budget), xycoords=("axes fraction", "data"), ha="right",
                            va="bottom", fontsize=8, color="0.4")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_xlabel("wall time of the time steps [s]")
        references = sorted({r.reference for r in mine})
        ax.set_ylabel(f"error: {quantity} (relative)")
        ax.set_title(f"{quantity}\n(against {'; '.join(references)})", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    figure.suptitle(case.title, fontsize=11)
    figure.savefig(path, dpi=110)
    return Path(path)


# ---------------------------------------------------------------------------------------------
# Summary


def _machine_line(threads, loads):
    return (f"{platform.node() or 'this machine'}: {os.cpu_count()} CPU cores, {threads} Numba threads, "
            f"load average {loads[0]:.1f} at the start and {loads[1]:.1f} at the end")


def _order_lines(rows, case_name):
    lines = []
    for (case, quantity, model, ladder), (order, last) in fitted_orders(rows).items():
        if case != case_name:
            continue
        group = ladders(rows)[(case, quantity, model, ladder)]     # model: the variant
        errors = ", ".join(f"{r.error:.2e}" for r in group)
        self_order = group[-1].order_self
        parts = [f"fitted {order:.2f}" if order is not None else "fitted -",
                 f"last pair {last:.2f}" if last is not None else "last pair -"]
        if self_order is not None:
            parts.append(f"from successive differences {self_order:.2f}")
        lines.append(f"| {quantity} | {model} | {ladder.replace('_', ' ')} | {errors} | {'; '.join(parts)} |")
    if not lines:
        return []
    return ["| quantity | model | ladder | errors, coarse to fine | order |", "|---|---|---|---|---|"] + lines


CASE_NOTES = {
    "cantilever": (
        "Linear tetrahedra lock in bending: their constant strain cannot represent the linear bending "
        "strain across the thickness, so coarse meshes are far too stiff and the tip deflection converges "
        "from below at a pre-asymptotic rate (O(h^2) is the asymptotic rate of smooth problems in "
        "displacement). The clamped 3D beam's tip deflection differs from Timoshenko's beam by up to about "
        "1 % (the clamp's Poisson constraint and end effects; the rows' note in verify.csv gives this run's "
        "limit/Timoshenko), so errors near that floor are measured against the "
        "Richardson-extrapolated limit of the element-size ladder instead, where the ladder knows the 3D "
        "answer better than beam theory does (the limit's spread below its distance from Timoshenko); "
        "the reference column says which was used, and reference_uncertainty in verify.csv how good it is. "
        "dt does not change a static answer, only what it costs (dt: auto throughout)."),
    "axial-vibration": (
        "nu = 0 makes the continuous 3D bar exactly the 1D bar (no lateral strain). Lumped-mass linear "
        "elements lengthen the period by O(h^2) (the 1D dispersion (kh)^2/24, plus the shear coupling of "
        "a cross-section's vertices in the 5-tet cells); symplectic Euler shortens it by O((omega dt)^2); "
        "with dt: auto, dt shrinks with h, so both are O(h^2). For this lowest mode dt never dominates: the stable dt "
        "is set by the highest mode, omega_1 dt ~ h / L, and the dt ladder only moves the error by a "
        "fraction (see the order from successive differences: 2)."),
    "traction": (
        "A homogeneous stretch is exact for linear tetrahedra, so the linear model (and corotated, whose "
        "stress is linear in a stretch without rotation) match sigma L / E to the tolerance of the "
        "damped relaxation at every element size; stvk and neohookean differ by their finite strain, "
        "O(sigma / E) (order 1 in the load ladder), which is the small-strain reference's own error, not "
        "the solver's. Against each law's own exact homogeneous stretch (F = diag(a, b, b) with P11 = sigma, "
        "P22 = 0, solved in NumPy independently of the kernels) every model is exact to the relaxation "
        "tolerance: anything more would be a bug."),
    "rigid-motion": (
        "Free fall: symplectic Euler's positions lead the exact parabola by g t dt / 2, an error of "
        "exactly dt / t, first order in dt and independent of the mesh and model: here dt alone "
        "dominates. Spin: rotation-invariant models keep every edge within the centrifugal strain "
        "rho omega^2 R^2 / E and conserve angular momentum to round-off (symplectic Euler conserves it "
        "exactly for rotation-invariant forces). The small-strain linear model sees an infinitesimal "
        "rotation as zero strain, so a spinning body's velocities meet no resistance: every point "
        "flies off along its tangent and the body grows as sqrt(1 + (omega t)^2)."),
    "patch": (
        "An affine displacement imposed on the boundary of an unstructured gmsh mesh: the interior "
        "forces at the exact field vanish to round-off, and relaxing from rest positions inside ends at "
        "uniform F = A to round-off, for every model. The patch test is blind to the material constants "
        "(any homogeneous material is in equilibrium under uniform F); the other cases catch those."),
    "energy": (
        "Symplectic Euler does not conserve energy exactly but keeps it bounded: the measured total "
        "energy oscillates with an amplitude O(dt) (positions and velocities are half a step apart) "
        "and shows no secular drift over many periods."),
}


def write_summary(path, rows, quick, budgets, plot_paths, plot_note, machine, wall_time_s, case_names):
    """Write ``verify.md``."""
    lines = [
        "# softsim verify: error against run time",
        "",
        f"{'Quick' if quick else 'Full'} run, {len(rows)} rows, {wall_time_s:.0f} s in all. Table: `verify.csv`. "
        f"Wall times count the time steps only (not meshing, JIT compilation or measurements), on "
        f"{machine}; other work on the machine inflates them.",
        "",
        "Errors are relative: |computed - reference| / |reference|; `order` is the slope of log error "
        "against log h (element size), log dt or log (sigma / E) over the rungs of one ladder. Linear "
        "tetrahedra are expected to converge as O(h^2) in displacement for smooth problems.",
        "",
    ]
    if plot_note:
        lines += [plot_note, ""]
    for name in case_names:
        case = CASES[name]
        mine = [r for r in rows if r.case == name]
        if not mine:
            continue
        lines += [f"## {case.title}", ""]
        if name in plot_paths:
            lines += [f"![{name}]({Path(plot_paths[name]).name})", ""]
        lines += [CASE_NOTES.get(name, ""), ""]
        orders = _order_lines(rows, name)
        if orders:
            lines += orders + [""]
        finest = {}
        for r in mine:
            if r.ladder != "-" and r.quantity == case.primary:
                best = finest.get(r.variant)
                if best is None or (r.element_size, r.dt) < (best.element_size, best.dt):
                    finest[r.variant] = r
        if finest:
            lines += ["| model | finest run of the " + case.primary + " | error | note |", "|---|---|---|---|"]
            lines += [f"| {r.variant} | {r.tets} tets, dt {r.dt:.3g} s, {r.steps} steps, {r.wall_time_s:.3g} s | "
                      f"{r.error:.2e} | {r.note} |" for r in finest.values()]
            lines.append("")
        singles = [r for r in mine if r.ladder == "-"]
        if singles:
            lines += ["| quantity | model | error | reference | note |", "|---|---|---|---|---|"]
            lines += [f"| {r.quantity} | {r.variant} | {r.error:.2e} | {r.reference} | {r.note} |" for r in singles]
            lines.append("")
        if budgets.get(name):
            lines += [f"Cheapest run for an error budget on the {case.primary}:", ""]
            lines += [f"- {line}" for line in budgets[name]] + [""]
    Path(path).write_text("\n".join(lines))
    return Path(path)


# ---------------------------------------------------------------------------------------------
# Everything


def verify_report(out_dir, quick=False, cases=None, models=MODELS, plot=True, progress=None, mutate=None,
                  threads=None, precisions=PRECISIONS):
    """Run the verification cases into ``out_dir``; a ``VerifyReport``.

    cases: case names (default all of ``CASES``); models: material models (default all four);
    precisions: of the step (default float64 and float32, which runs the models that have it);
    plot: write the PNGs when matplotlib is there; progress: callable taking one line of text
    after each run; mutate: ``Model -> Model`` applied to every prepared model (tests); threads:
    Numba threads for the run (default: Numba's setting).
    """
    started = _time.perf_counter()
    names = list(cases) if cases else list(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise ConfigError(f"unknown verification case {', '.join(unknown)} (known: {', '.join(CASES)})")
    models = tuple(models)
    bad = [m for m in models if m not in MODELS]
    if bad:
        raise ConfigError(f"unknown material model {', '.join(bad)} (known: {', '.join(MODELS)})")
    bad = [p for p in precisions if p not in PRECISIONS]
    if bad or not precisions:
        raise ConfigError(f"precision {', '.join(bad) or '(none)'}: must be one or more of {', '.join(PRECISIONS)}")
    if set(precisions) == {"float32"} and not set(models) & set(FLOAT32_MODELS):
        raise ConfigError(f"--precision float32: {', '.join(models)} steps in float64 only; float32 is available "
                          f"for {', '.join(FLOAT32_MODELS)}")
    import numba

    if threads is not None and not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
        raise ConfigError(f"threads = {threads}: must be between 1 and {numba.config.NUMBA_NUM_THREADS}")
    writable_folder(out_dir)            # before the runs, not after them
    previous = numba.get_num_threads()
    numba.set_num_threads(threads or previous)
    try:
        load_start = _load()
        compile_steps_ahead(names, quick, models, tuple(precisions), mutate)
        rows = []
        for name in names:
            rows += CASES[name](quick=quick, models=models, mutate=mutate, progress=progress,
                                precisions=tuple(precisions))
        machine = _machine_line(numba.get_num_threads(), (load_start, _load()))
    finally:
        numba.set_num_threads(previous)      # the caller's setting again
    return write_report(out_dir, rows, quick, plot=plot, machine=machine, started=started)


def compile_steps_ahead(names, quick, models, precisions, mutate):
    """Compile the step specialisations that the cases ``names`` will run, on two cores, before any
    of them times a step (``compile_ahead.compile_shared``; ``Case.step_calls``): their runs then
    load them from the disk cache.  Does nothing where no helper process may start (one core,
    ``SOFTSIM_COMPILE_AHEAD=0``): each step then compiles before its case's first run."""
    if not compile_ahead.enabled():
        return 0
    calls = []
    for name in names:
        calls += CASES[name].step_calls(quick=quick, models=models, mutate=mutate, precisions=precisions)
    return compile_ahead.compile_shared(calls)


def _load():
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def write_report(out_dir, rows, quick, plot=True, machine="this machine", started=None, wall_time_s=None):
    """Write ``verify.csv``, the plots and ``verify.md`` of ``rows`` into ``out_dir``; a ``VerifyReport``.

    Also re-renders a report from its table: ``write_report(dir, read_csv(dir / "verify.csv"), quick)``.
    machine: the line saying where the wall times were measured; started: ``perf_counter()`` at the
    start of the runs (for the total time; None: 0).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [name for name in CASES if any(r.case == name for r in rows)]
    csv_path = write_csv(rows, out_dir / "verify.csv")
    # from the table's values (wall times to 6 digits): a report re-rendered from it says the same
    table = read_csv(csv_path)
    budgets = {name: budget_answers(table, name, CASES[name].primary) for name in names}
    plot_paths, plot_note = {}, None
    if plot:
        try:
            for name in names:
                plot_paths[name] = plot_case(CASES[name], [r for r in rows if r.case == name],
                                             out_dir / f"verify_{name}.png")
        except MissingDependencyError:
            plot_paths = {}
            plot_note = f"No plots: matplotlib is not installed ({PLOT_EXTRA} adds them)."
    if wall_time_s is not None:
        wall = wall_time_s
    else:
        wall = _time.perf_counter() - started if started is not None else sum(r.wall_time_s for r in rows)
    summary = write_summary(out_dir / "verify.md", rows, quick, budgets, plot_paths, plot_note, machine, wall, names)
    return VerifyReport(out_dir=out_dir, quick=quick, rows=rows, csv_path=csv_path, summary_path=summary,
                        plot_paths=plot_paths, plot_note=plot_note, budgets=budgets, wall_time_s=wall)


def replot_report(out_dir, quick=False):
    """Redraw the plots and ``verify.md`` of the report in ``out_dir`` from its ``verify.csv``
    (nothing runs); the machine line of the old ``verify.md`` is kept.  ``ConfigError`` without a table."""
    out_dir = Path(out_dir)
    table = out_dir / "verify.csv"
    if not table.is_file():
        raise ConfigError(f"--replot: no verify.csv in '{out_dir}'; run softsim verify -o {out_dir} first")
    machine, wall = "the machine of the original run", None
    summary = out_dir / "verify.md"
    if summary.is_file():
        for line in summary.read_text().splitlines():
            if "Wall times count" in line and ", on " in line:
                machine = line.split(", on ", 1)[1].split("; other work")[0]
                quick = line.startswith("Quick")
                found = re.search(r"([0-9.]+) s in all", line)
                wall = float(found.group(1)) if found else None
                break
    return write_report(out_dir, read_csv(table), quick, machine=machine, wall_time_s=wall)


def read_csv(path):
    """The ``VerifyRow``s of a ``verify.csv``; ``ConfigError`` naming the line of one that is not a row."""
    def number(text):
        return float(text) if text != "" else None

    rows = []
    with open(path, newline="") as stream:
        reader = csv.DictReader(stream)
        missing = [column for column in COLUMNS if column not in (reader.fieldnames or ())]
        if missing:
            raise ConfigError(f"'{path}': not a table softsim verify wrote (no column {', '.join(missing)})")
        for d in reader:
            if None in d.values() or None in d:
                raise ConfigError(f"'{path}' line {reader.line_num}: not {len(COLUMNS)} columns")
            try:
                row = _row_of(d, number)
            except ValueError as exc:
                raise ConfigError(f"'{path}' line {reader.line_num}: {exc}") from None
            if not (math.isfinite(row.wall_time_s) and row.wall_time_s >= 0.0):
                raise ConfigError(f"'{path}' line {reader.line_num}: wall_time_s = {row.wall_time_s}: must be a "
                                  f"time of at least 0 s")
            rows.append(row)
    return rows


def _row_of(d, number):
    """A ``VerifyRow`` from a ``verify.csv`` row ``d`` (a dict of text)."""
    return VerifyRow(
        case=d["case"], quantity=d["quantity"], model=d["model"], precision=d["precision"],
        ladder=d["ladder"], refinement=float(d["refinement"]), element_size=float(d["element_size_m"]),
        tets=int(d["tets"]), dt=float(d["dt_s"]), steps=int(d["steps"]), wall_time_s=float(d["wall_time_s"]),
        value=float(d["value"]), reference_value=float(d["reference_value"]), error=float(d["error"]),
        reference=d["reference"], order=number(d["order"]), order_self=number(d["order_self"]),
        note=d["note"], reference_uncertainty=float(d["reference_uncertainty"]))


__all__ = ["BUDGETS", "COLUMNS", "VerifyReport", "budget_answers", "fitted_orders", "format_table", "pareto_front",
           "plot_case", "read_csv", "replot_report", "verify_report", "write_csv", "write_report", "write_summary"]
