"""The verification cases: scenes with known answers, each run over ladders of element size and
time step for every material model that applies.

Each case is a function ``run(params, quick, models, mutate, progress) -> [VerifyRow]`` with its
parameters in a frozen dataclass (SI units); the analytic answer is derived from those parameters
(``references``), so a case reruns unchanged with other moduli, sizes or densities::

    from softsim.verify.cases import CASES, Cantilever
    rows = CASES["cantilever"].run(Cantilever(youngs_modulus=2e9), quick=True)

Errors are relative: ``|computed - reference| / |reference|`` (the patch test and the energy
case divide by the scale named in ``reference``).  Structured boxes (hex cells of 5 tets) give
ladders whose element size halves exactly; the patch test uses an unstructured gmsh mesh.
"""

import functools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..config.schema import FLOAT32_MODELS
from ..kernels.forces import elastic_forces
from ..materials.models import MODEL_IDS, ROTATION_INVARIANT, model_lame_parameters
from ..simulation import frame_energy
from . import references as ref
from .driver import Run, RunRecorded, face_mask, recording_step_calls, tet_deformation_gradients, unique_edges

MODELS = tuple(MODEL_IDS)
# Half-width [m] of the selection boxes around a face.
BOX = 1e-6
@dataclass(frozen=True)
class VerifyRow:
    """One run of a case, one measured quantity.

    ladder: what the rung refines (``element_size``, ``dt``, ``load`` or ``-`` for a single run);
    refinement: that parameter's value (element size [m], dt [s], sigma / E); element_size [m]
    (the mesh's target edge); dt [s]; steps taken; wall_time_s: time of the steps only [s];
    value / reference_value in the quantity's unit; error: relative error against ``reference``;
    order: observed order against the previous rung of the same ladder; order_self: order from
    successive differences of the values (no exact answer needed); reference_uncertainty: how far
    the reference itself may be from the true answer of the scene, relative (0 for exact ones).
    """

    case: str
    quantity: str
    model: str
    precision: str
    ladder: str
    refinement: float
    element_size: float
    tets: int
    dt: float
    steps: int
    wall_time_s: float
    value: float
    reference_value: float
    error: float
    reference: str
    order: float | None = None
    order_self: float | None = None
    note: str = ""
    reference_uncertainty: float = 0.0

    @property
    def variant(self):
        """The model, and the precision where it is not float64: ``stvk``, ``stvk float32``."""
        return self.model if self.precision == "float64" else f"{self.model} {self.precision}"


def _structured_box(size, element_size, material, **extra):
    data = {
        "mesh": {"shape": "box", "size": [float(s) for s in size], "origin": [0.0, 0.0, 0.0],
                 "element_size": float(element_size), "structured": True},
        "material": material,
        "gravity": [0.0, 0.0, 0.0],
    }
    data.update(extra)
    return data


def _material(model, p):
    return {"model": model, "youngs_modulus": p.youngs_modulus, "poissons_ratio": p.poissons_ratio,
            "density": p.density}


def _clamp(axes=("x", "y", "z")):
    return {"min": [-BOX, -1e9, -1e9], "max": [BOX, 1e9, 1e9], "axes": list(axes)}


def _row(case, quantity, run, ladder, refinement, value, reference_value, reference, note="", error=None,
         uncertainty=0.0):
    if error is None:
        error = abs(value - reference_value) / abs(reference_value)
    return VerifyRow(case=case, quantity=quantity, model=run.scene.material.model, precision=run.scene.precision,
                     ladder=ladder, refinement=float(refinement), element_size=float(run.scene.mesh.element_size),
                     tets=run.tet_count, dt=run.dt, steps=run.steps, wall_time_s=run.wall_time_s, value=float(value),
                     reference_value=float(reference_value), error=float(error), reference=reference, note=note,
                     reference_uncertainty=float(uncertainty))


def _report(progress, row):
    if progress is not None:
        progress(f"{row.case} / {row.variant}: {row.quantity} h={row.element_size:.4g} m dt={row.dt:.3g} s: "
                 f"error {row.error:.3g} ({row.reference}) in {row.wall_time_s:.2f} s")


def with_orders(rows):
    """``rows`` with ``order`` and ``order_self`` filled in per ladder (same case, quantity, model and
    precision, ladder), rungs ordered from coarse to fine; other rows unchanged."""
    out = list(rows)
    groups = {}
    for i, row in enumerate(out):
        if row.ladder != "-":
            groups.setdefault((row.case, row.quantity, row.variant, row.ladder), []).append(i)
    for indices in groups.values():
        indices.sort(key=lambda i: -out[i].refinement)
        p = [out[i].refinement for i in indices]
        orders = ref.observed_orders(p, [out[i].error for i in indices])
        selfs = ref.self_convergence_orders(p, [out[i].value for i in indices])
        for i, order, order_self in zip(indices, orders, selfs):
            out[i] = replace(out[i], order=order, order_self=order_self)
    return out


# ---------------------------------------------------------------------------------------------
# 1. Cantilever under its own weight


@dataclass(frozen=True)
class Cantilever:
    """A square-section beam clamped (all axes) at x = 0, sagging under gravity, damped to rest.

    E is chosen so that the sag is about 0.15 % of the length: small-strain beam theory applies to
    every model.  Ladder: ``thickness / n`` for n in ``divisions``.
    """

    length: float = 1.0
    thickness: float = 0.1
    youngs_modulus: float = 1.0e9
    poissons_ratio: float = 0.3
    density: float = 1000.0
    gravity: float = 9.81
    divisions: tuple = (2, 3, 4, 6, 8)
    quick_divisions: tuple = (2, 3, 4)
    # Divisions run only for these models (the finest rung is the costly one).
    finest_models: tuple = ("stvk",)
    rest_tolerance: float = 2e-6     # stop when the tip moves less than this fraction per 1/omega_1


def run_cantilever(p=Cantilever(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Tip deflection against Timoshenko beam theory, or against the Richardson limit of the ladder
    where the error is below a few times the 3D clamp's own difference from beam theory."""
    case = "cantilever"
    L, t = p.length, p.thickness
    w_bending, w_timoshenko = ref.cantilever_tip_deflection(L, t, t, p.youngs_modulus, p.poissons_ratio, p.density,
                                                             p.gravity)
    omega = ref.cantilever_frequency(L, t, p.youngs_modulus, p.density)
    divisions = p.quick_divisions if quick else p.divisions
    rows = []
    for model in models:
        runs = []
        mine = divisions if quick or model in p.finest_models else divisions[:-1]
        for n in mine:
            scene = _structured_box((L, t, t), t / n, _material(model, p), gravity=[0.0, 0.0, -p.gravity],
                                    damping=2.0 * omega, fixed=[_clamp()])
            run = Run(scene, mutate=mutate, precision=precision)
            X = run.model.rest_points
            tip = face_mask(X, 0, L, 1e-9 * L)

            def deflection():
                return float(-(run.state.x[tip, 2] - X[tip, 2]).mean())

            w, converged = run.relax(deflection, 1.0 / omega, p.rest_tolerance, max_time=80.0 / omega,
                                     min_time=5.0 / omega)
            speed = float(np.abs(run.state.v).max()) / (omega * abs(w)) if w != 0.0 else math.inf
            note = f"at rest: max|v| = {speed:.1e} omega_1 w" if converged else \
                f"NOT at rest after {run.time * omega:.0f}/omega_1 (max|v| = {speed:.1e} omega_1 w)"
            runs.append((n, run, w, note))
        h = [t / n for n, *_ in runs]
        w_values = [w for _, _, w, _ in runs]
        if len(runs) >= 3:
            limit, k, spread = ref.richardson_limit(h, w_values)
        else:
            limit, k, spread = None, None, None
        # How far Timoshenko's beam may be from this 3D beam (its clamp, its end), as the ladder
        # tells: the limit's distance from it, or the limit's own spread where that is larger.
        floor = max(abs(limit - w_timoshenko), spread) / w_timoshenko if limit is not None else 0.0
        for (n, run, w, note), hn in zip(runs, h):
            error_theory = abs(w - w_timoshenko) / w_timoshenko
            # The limit replaces beam theory near the floor, if the ladder knows the 3D answer better
            # than beam theory does (its spread below its distance from Timoshenko).
            trusted = limit is not None and len(runs) >= 3 and spread < abs(limit - w_timoshenko)
            use_theory = not trusted or error_theory > 5.0 * floor
            if use_theory:
                row = _row(case, "tip deflection", run, "element_size", hn, w, w_timoshenko, "timoshenko", note,
                           uncertainty=floor)
            else:
                row = _row(case, "tip deflection", run, "element_size", hn, w, limit,
                           f"richardson (k={k:.2f})", note, uncertainty=spread / abs(limit))
            rows.append(replace(row, note=f"{note}; vs Timoshenko {error_theory:.2e}, vs Euler-Bernoulli "
                                          f"{abs(w - w_bending) / w_bending:.2e}"
                                          + (f"; limit/Timoshenko = {limit / w_timoshenko:.4f} "
                                             f"(+-{spread / w_timoshenko:.1e})" if limit is not None else "")))
            _report(progress, rows[-1])
    return rows


# ---------------------------------------------------------------------------------------------
# 2. Axial vibration of a fixed-free bar


@dataclass(frozen=True)
class AxialVibration:
    """A bar clamped at x = 0 with nu = 0, so that the continuous 3D bar is exactly the 1D one (no
    lateral strain; the tets' shear couples the vertices of a cross-section, an O(h^2) effect),
    released from its first mode shape ``u = a sin(pi X / 2L)`` with a strain amplitude of
    ``strain`` (small: the nonlinear models add nothing measurable).

    The period is fitted (sinusoid, least squares) to the mean axial displacement of the free end
    over ``periods`` periods.  Ladders: element size ``length / n`` at ``dt: auto``, and
    ``dt_factors x auto`` on the ``length / dt_divisions`` mesh.
    """

    length: float = 1.0
    width: float = 0.1
    youngs_modulus: float = 1.0e7
    density: float = 1000.0
    strain: float = 1.0e-6
    periods: float = 3.0
    samples_per_period: int = 64
    divisions: tuple = (10, 20, 40, 80)
    quick_divisions: tuple = (10, 20, 40)
    dt_divisions: int = 20
    dt_factors: tuple = (1.0, 0.5, 0.25, 0.125)
    quick_dt_factors: tuple = (1.0, 0.5, 0.25)


def fit_period(times, values, guess):
    """Period [s] of the sinusoid ``a cos(w t) + b sin(w t) + c`` fitted to ``values`` (least squares
    over w, a, b, c; w by golden-section search within 10 % of ``2 pi / guess``)."""
    t = np.asarray(times, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)

    def residual(w):
        A = np.stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)], axis=1)
        coefficients, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sum((A @ coefficients - y) ** 2))

    w0 = 2.0 * math.pi / guess
    lo, hi = 0.9 * w0, 1.1 * w0
    golden = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - golden * (hi - lo), lo + golden * (hi - lo)
    fa, fb = residual(a), residual(b)
    for _ in range(80):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - golden * (hi - lo)
            fa = residual(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + golden * (hi - lo)
            fb = residual(b)
    return 2.0 * math.pi / (0.5 * (lo + hi))


def run_axial_vibration(p=AxialVibration(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Period of the free end against ``4 L / sqrt(E / rho)``."""
    case = "axial-vibration"
    L = p.length
    period = ref.fixed_free_bar_period(L, p.youngs_modulus, p.density)
    material = {"youngs_modulus": p.youngs_modulus, "poissons_ratio": 0.0, "density": p.density}
    divisions = p.quick_divisions if quick else p.divisions
    factors = p.quick_dt_factors if quick else p.dt_factors
    rows = []
    for model in models:
        @functools.cache                 # the dt ladder's first rung may be a rung of the mesh ladder
        def measure(n, factor):
            scene = _structured_box((L, p.width, p.width), L / n, {"model": model, **material}, fixed=[_clamp()])
            run = Run(scene, dt_factor=factor, mutate=mutate, precision=precision)
            X = run.model.rest_points
            u = p.strain * (2.0 * L / math.pi) * np.sin(0.5 * math.pi * X[:, 0] / L)
            run.restart_from(X + np.stack([u, np.zeros_like(u), np.zeros_like(u)], axis=1))
            end = face_mask(X, 0, L, 1e-9 * L)
            chunk = run.steps_for(period / p.samples_per_period)
            times, values = [0.0], [float((run.state.x[end, 0] - X[end, 0]).mean())]
            while run.time < p.periods * period:
                run.advance(chunk)
                times.append(run.time)
                values.append(float((run.state.x[end, 0] - X[end, 0]).mean()))
            return run, fit_period(times, values, period)

        for n in divisions:
            run, value = measure(n, 1.0)
            rows.append(_row(case, "period", run, "element_size", L / n, value, period, "4L/sqrt(E/rho)",
                             "nu = 0: the continuous 3D bar is the 1D bar"))
            _report(progress, rows[-1])
        for factor in factors:
            run, value = measure(p.dt_divisions, factor)
            rows.append(_row(case, "period", run, "dt", run.dt, value, period, "4L/sqrt(E/rho)",
                             f"dt = {factor:g} x auto on the L/{p.dt_divisions} mesh"))
            _report(progress, rows[-1])
    return rows


# ---------------------------------------------------------------------------------------------
# 3. Bar under end traction on rollers


@dataclass(frozen=True)
class Traction:
    """A bar on rollers (x = 0 face: x held; y = 0 face: y held; z = 0 face: z held, which removes
    the rigid modes and leaves lateral contraction free) under a nominal traction ``sigma`` on
    x = L, damped to rest.  The homogeneous stretch is the exact discrete answer of linear tets;
    what is left is the models' finite strain, O(sigma / E).  nu = 0.4 makes lambda = 4 mu, so a
    swap of the Lame parameters shows.  Ladders: ``load_ratios`` (sigma / E) on the ``element_size``
    mesh, and ``element_sizes`` at ``size_load_ratio``.
    """

    length: float = 1.0
    width: float = 0.2
    youngs_modulus: float = 1.0e6
    poissons_ratio: float = 0.4
    density: float = 1000.0
    element_size: float = 0.1
    load_ratios: tuple = (1e-2, 1e-3, 1e-4)
    quick_load_ratios: tuple = (1e-2, 1e-3)
    element_sizes: tuple = (0.1, 0.05)
    quick_element_sizes: tuple = (0.1, 0.05)
    size_load_ratio: float = 1e-3
    rest_tolerance: float = 1e-9


def run_traction(p=Traction(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Elongation ``sigma L / E`` and lateral contraction ``nu sigma w / E`` (small strain), and both
    against the exact homogeneous stretch of each material law (``references.uniaxial_stretches``)."""
    case = "traction"
    L, W = p.length, p.width
    c = ref.bar_wave_speed(p.youngs_modulus, p.density)
    omega = 0.5 * math.pi * c / L
    loads = p.quick_load_ratios if quick else p.load_ratios
    sizes = p.quick_element_sizes if quick else p.element_sizes
    rows = []
    for model in models:
        @functools.cache                 # the two ladders share their crossing rung
        def measure(h, load):
            sigma = load * p.youngs_modulus
            scene = _structured_box(
                (L, W, W), h, _material(model, p), damping=2.0 * omega,
                fixed=[_clamp(("x",)),
                       {"min": [-1e9, -BOX, -1e9], "max": [1e9, BOX, 1e9], "axes": ["y"]},
                       {"min": [-1e9, -1e9, -BOX], "max": [1e9, 1e9, BOX], "axes": ["z"]}],
                tractions=[{"min": [L - BOX, -1e9, -1e9], "max": [L + BOX, 1e9, 1e9], "traction": [sigma, 0, 0]}])
            run = Run(scene, mutate=mutate, precision=precision)
            X = run.model.rest_points
            end = face_mask(X, 0, L, 1e-9 * L)
            side = face_mask(X, 1, W, 1e-9 * W)

            def elongation():
                return float((run.state.x[end, 0] - X[end, 0]).mean())

            value, converged = run.relax(elongation, 1.0 / omega, p.rest_tolerance, max_time=100.0 / omega,
                                         min_time=5.0 / omega)
            contraction = float(-(run.state.x[side, 1] - X[side, 1]).mean())
            note = "at rest" if converged else f"NOT at rest after {run.time * omega:.0f}/omega_1"
            return run, value, contraction, note, sigma

        def add(ladder, refinement, h, load):
            run, elongation, contraction, note, sigma = measure(h, load)
            d_ref, c_ref = ref.uniaxial_small_strain(L, W, p.youngs_modulus, p.poissons_ratio, sigma)
            extra = "; finite strain O(sigma/E) remains" if run.scene.material.model != "linear" else ""
            finite = 0.0 if run.scene.material.model == "linear" else load     # small-strain theory's own error
            rows.append(_row(case, "elongation", run, ladder, refinement, elongation, d_ref, "sigma L / E",
                             f"{note}; sigma/E = {load:g}{extra}", uncertainty=finite))
            _report(progress, rows[-1])
            rows.append(_row(case, "contraction", run, ladder, refinement, contraction, c_ref, "nu sigma w / E",
                             f"{note}; sigma/E = {load:g}{extra}", uncertainty=finite))
            # Against the law's own exact homogeneous stretch: what is left is the relaxation only.
            model = run.scene.material.model
            lam, mu = model_lame_parameters(model, p.youngs_modulus, p.poissons_ratio)
            a, b = ref.uniaxial_stretches(model, lam, mu, sigma)
            exact = f"{note}; sigma/E = {load:g}; F = diag({a:.10g}, {b:.10g}, {b:.10g})"
            rows.append(_row(case, "elongation, exact stretch", run, ladder, refinement, elongation, (a - 1.0) * L,
                             "the law's homogeneous stretch", exact))
            rows.append(_row(case, "contraction, exact stretch", run, ladder, refinement, contraction, (1.0 - b) * W,
                             "the law's homogeneous stretch", exact))

        for load in loads:
            add("load", load, p.element_size, load)
        for h in sizes:
            add("element_size", h, h, p.size_load_ratio)
    return rows


# ---------------------------------------------------------------------------------------------
# 4. Free fall and rigid spin


@dataclass(frozen=True)
class RigidMotion:
    """A free cube: falling from rest under gravity for ``fall_time`` (centroid against g t^2 / 2;
    symplectic Euler's positions lead by g t dt / 2, so the relative error is dt / t), and spinning
    without gravity about a generic axis at the rate where the centrifugal strain is
    ``spin_strain`` for one turn (edge lengths and angular momentum about the centroid).
    """

    size: float = 0.1
    youngs_modulus: float = 1.0e6
    poissons_ratio: float = 0.3
    density: float = 1000.0
    gravity: float = 9.81
    fall_element_size: float = 0.05
    fall_time: float = 0.1
    dt_factors: tuple = (1.0, 0.5, 0.25, 0.125)
    quick_dt_factors: tuple = (1.0, 0.5, 0.25)
    spin_element_size: float = 0.025
    spin_strain: float = 1e-4
    spin_axis: tuple = (0.36, 0.48, 0.8)
    turns: float = 1.0
    samples_per_turn: int = 64


def run_rigid_motion(p=RigidMotion(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Centroid drop, then edge lengths and angular momentum of a spinning cube."""
    case = "rigid-motion"
    a = p.size
    rows = []
    radius = 0.5 * math.sqrt(3.0) * a
    omega = math.sqrt(p.spin_strain * p.youngs_modulus / (p.density * radius ** 2))
    axis = np.asarray(p.spin_axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    turn = 2.0 * math.pi / omega
    factors = p.quick_dt_factors if quick else p.dt_factors
    for model in models:
        for factor in factors:
            scene = _structured_box((a, a, a), p.fall_element_size, _material(model, p),
                                    gravity=[0.0, 0.0, -p.gravity])
            run = Run(scene, dt_factor=factor, mutate=mutate, precision=precision)
            mass = run.model.mass

            def centroid_z():
                return float((mass * run.state.x[:, 2]).sum() / mass.sum())

            z0 = centroid_z()
            run.advance(run.steps_for(p.fall_time))
            drop = z0 - centroid_z()
            expected = ref.free_fall_drop(p.gravity, run.time)
            # value: the drop over g t^2 / 2 (t differs a little between rungs: whole steps)
            rows.append(_row(case, "centroid drop", run, "dt", run.dt, drop / expected, 1.0, "g t^2 / 2",
                             f"value: drop / (g t^2 / 2); symplectic Euler: dt / t = {run.dt / run.time:.3g}"))
            _report(progress, rows[-1])

        scene = _structured_box((a, a, a), p.spin_element_size, _material(model, p),
                                angular_velocity=[float(v) for v in omega * axis])
        run = Run(scene, mutate=mutate, precision=precision)
        mass = run.model.mass[:, None]
        edges = unique_edges(run.model.tets)
        rest_length = np.linalg.norm(run.state.x[edges[:, 1]] - run.state.x[edges[:, 0]], axis=1)

        def angular_momentum():
            x, v = run.state.x, run.state.v
            c = (mass * x).sum(axis=0) / mass.sum()
            return (mass * np.cross(x - c, v)).sum(axis=0)

        L0 = angular_momentum()
        stretch = drift = 0.0
        chunk = run.steps_for(turn / p.samples_per_turn)
        while run.time < p.turns * turn:
            run.advance(chunk)
            x = run.state.x
            length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
            stretch = max(stretch, float(np.abs(length / rest_length - 1.0).max()))
            drift = max(drift, float(np.linalg.norm(angular_momentum() - L0) / np.linalg.norm(L0)))
        strain = ref.centrifugal_strain(p.youngs_modulus, p.density, omega, radius)
        if model in ROTATION_INVARIANT:
            note = f"centrifugal strain rho omega^2 R^2 / E = {strain:.1e} is physical, not an error"
        else:
            growth = math.sqrt(1.0 + (omega * run.time) ** 2) - 1.0
            note = (f"small strain sees a rotation's velocity as strain-free: points fly off along tangents, "
                    f"edges grow by sqrt(1 + (omega t)^2) - 1 = {growth:.3g}")
        rows.append(_row(case, "edge length", run, "-", run.dt, stretch, 0.0, "rigid: max|l/l0 - 1|", note,
                         error=stretch))
        _report(progress, rows[-1])
        rows.append(_row(case, "angular momentum", run, "-", run.dt, drift, 0.0, "max|L - L0| / |L0|",
                         f"{p.turns:g} turn(s) at omega = {omega:.3g} rad/s", error=drift))
        _report(progress, rows[-1])
    return rows


# ---------------------------------------------------------------------------------------------
# 5. Patch test


@dataclass(frozen=True)
class Patch:
    """An unstructured gmsh cube whose six faces are held on the affine field ``x = A X + b``.

    Two checks of the kernels: (1) with every vertex on the field, the elastic force on each
    interior vertex must vanish to round-off (relative to the reaction forces on the boundary);
    (2) released from the rest positions inside, damped (``2 omega_1``) to rest, every tet's ``F``
    must equal ``A`` to round-off.  Blind to the material constants (any homogeneous material is
    in equilibrium under uniform F); it catches assembly, geometry and rest-state errors.
    """

    size: float = 0.1
    youngs_modulus: float = 1.0e6
    poissons_ratio: float = 0.3
    density: float = 1000.0
    gradient: tuple = ((0.05, 0.02, -0.01), (0.01, -0.03, 0.02), (-0.02, 0.01, 0.04))
    translation: tuple = (0.01, -0.02, 0.005)
    element_sizes: tuple = (0.04, 0.025)
    quick_element_sizes: tuple = (0.04,)
    target: float = 1e-11     # stop relaxing below this max |F - A| / max |A - I|


def run_patch(p=Patch(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Interior force residual at ``A X + b``, then ``max |F - A|`` after relaxation."""
    case = "patch"
    a = p.size
    G = np.asarray(p.gradient, dtype=np.float64)
    A = np.eye(3) + G
    faces = []
    for k in range(3):
        for value in (0.0, a):
            lo, hi = [-1e9] * 3, [1e9] * 3
            lo[k], hi[k] = value - BOX, value + BOX
            faces.append({"min": lo, "max": hi})
    c_s = math.sqrt(p.youngs_modulus / (2.0 * (1.0 + p.poissons_ratio)) / p.density)
    omega = math.pi * math.sqrt(3.0) * c_s / a      # slowest mode of the clamped cube, roughly
    sizes = p.quick_element_sizes if quick else p.element_sizes
    rows = []
    for model in models:
        for h in sizes:
            scene = {
                "mesh": {"shape": "box", "size": [a, a, a], "origin": [0.0, 0.0, 0.0], "element_size": h},
                "material": _material(model, p), "gravity": [0.0, 0.0, 0.0], "damping": 2.0 * omega,
                "fixed": faces,
                "initial_deformation": {"matrix": A.tolist(), "translation": list(p.translation)},
            }
            run = Run(scene, mutate=mutate, precision=precision)
            m = run.model
            free = ~m.held.any(axis=1)
            if precision == "float64":       # this row evaluates the float64 per-tet forces
                arguments = (run.state.x, m.tets, m.Dm_inv, m.rest_volume, m.material_id, m.lam, m.mu,
                             m.csr_offsets, m.csr_slots)
                elastic_forces(*arguments)   # compiles (or loads) it: the timed call compiles nothing
                started = time.perf_counter()
                f = elastic_forces(*arguments)
                evaluation = time.perf_counter() - started
                scale = float(np.abs(f[~free]).max())
                residual = float(np.abs(f[free]).max()) / scale
                row = _row(case, "interior force at AX+b", run, "element_size", h, residual, 0.0,
                           "max|f interior| / max|f boundary|",
                           f"{int(free.sum())} interior of {m.node_count} vertices; wall time: one force evaluation",
                           error=residual)
                rows.append(replace(row, wall_time_s=evaluation))
                _report(progress, rows[-1])

            run.restart_from(m.rest_points)

            def uniformity():
                F = tet_deformation_gradients(m.rest_points, run.state.x, m.tets)
                return float(np.abs(F - A).max()) / float(np.abs(G).max())

            chunk = run.steps_for(1.0 / omega)
            history = [uniformity()]
            while run.time < 150.0 / omega and history[-1] > p.target:
                run.advance(chunk)
                history.append(uniformity())
                if len(history) > 6 and history[-1] > 0.9 * history[-6]:
                    break       # no longer decreasing: round-off reached
            rows.append(_row(case, "max |F - A|", run, "element_size", h, history[-1], 0.0,
                             "max|F - A| / max|A - I|", f"released from rest inside, {run.time * omega:.0f}/omega_1",
                             error=history[-1]))
            _report(progress, rows[-1])
    return rows


# ---------------------------------------------------------------------------------------------
# 6. Energy behaviour


@dataclass(frozen=True)
class Energy:
    """A short cantilever released straight under gravity, undamped, over ``periods`` periods of
    its first mode; total energy (kinetic + elastic + gravity) sampled ``samples_per_period`` times
    a period.  ``energy error``: max |E - E0| over the run; ``energy drift``: the linear trend of E
    over the run; both relative to the largest kinetic + elastic energy.  Ladder: dt.
    """

    length: float = 0.4
    thickness: float = 0.1
    youngs_modulus: float = 1.0e7
    poissons_ratio: float = 0.3
    density: float = 1000.0
    gravity: float = 9.81
    element_size: float = 0.05
    periods: float = 40.0
    quick_periods: float = 10.0
    samples_per_period: int = 32
    dt_factors: tuple = (1.0, 0.5, 0.25, 0.125)
    quick_dt_factors: tuple = (1.0, 0.5, 0.25)


def run_energy(p=Energy(), quick=False, models=MODELS, mutate=None, progress=None, precision="float64"):
    """Energy error and drift of symplectic Euler against dt."""
    case = "energy"
    L, t = p.length, p.thickness
    omega = ref.cantilever_frequency(L, t, p.youngs_modulus, p.density)
    period = 2.0 * math.pi / omega
    periods = p.quick_periods if quick else p.periods
    factors = p.quick_dt_factors if quick else p.dt_factors
    rows = []
    for model in models:
        for factor in factors:
            scene = _structured_box((L, t, t), p.element_size, _material(model, p), gravity=[0.0, 0.0, -p.gravity],
                                    fixed=[_clamp()])
            run = Run(scene, dt_factor=factor, mutate=mutate, precision=precision)
            m = run.reference_model

            def energies():
                e = frame_energy(m, run.state)
                moving = e["kinetic"] + e["elastic"]
                return moving, moving + e["gravity"]

            chunk = run.steps_for(period / p.samples_per_period)
            times, totals, scale = [0.0], [energies()[1]], 0.0
            while run.time < periods * period:
                run.advance(chunk)
                moving, total = energies()
                times.append(run.time)
                totals.append(total)
                scale = max(scale, moving)
            totals = np.asarray(totals)
            error = float(np.abs(totals - totals[0]).max()) / scale
            slope = float(np.polyfit(np.asarray(times), totals, 1)[0])
            drift = abs(slope) * run.time / scale
            note = f"{periods:g} periods of 2 pi / omega_1 = {period:.3g} s; dt = {factor:g} x auto"
            rows.append(_row(case, "energy error", run, "dt", run.dt, error, 0.0, "max|E - E0| / max(KE + elastic)",
                             note, error=error))
            _report(progress, rows[-1])
            rows.append(_row(case, "energy drift", run, "dt", run.dt, drift, 0.0,
                             "|trend of E| x duration / max(KE + elastic)", note, error=drift))
    return rows


# ---------------------------------------------------------------------------------------------
# Registry


@dataclass(frozen=True)
class Case:
    """A verification case: its name, title, default parameters, runner and the quantity that
    the error budget question is asked about (and whose plot comes first)."""

    name: str
    title: str
    params: object
    run: object
    primary: str
    models: tuple = field(default=MODELS)

    def __call__(self, quick=False, models=None, mutate=None, progress=None, params=None, precisions=("float64",)):
        """Rows of every model of ``models`` (default all) in every precision of ``precisions``
        (float32 for the models that have it)."""
        rows = []
        for precision, chosen in self._variants(models, precisions):
            rows += self.run(params or self.params, quick=quick, models=chosen, mutate=mutate, progress=progress,
                             precision=precision)
        return with_orders(rows)

    def step_calls(self, quick=False, models=None, mutate=None, params=None, precisions=("float64",)):
        """The calls of the compiled step (``[(kernel, arguments), ...]``) that ``self(...)`` with
        these arguments makes, recorded from the first run of each model and precision
        (``driver.recording_step_calls``; nothing is stepped): a case's runs of one model differ
        in mesh and time step, not in the features that make the step compile apart (damping,
        tractions)."""
        with recording_step_calls() as calls:
            for precision, chosen in self._variants(models, precisions):
                for model in chosen:
                    try:
                        self.run(params or self.params, quick=quick, models=(model,), mutate=mutate,
                                 precision=precision)
                    except RunRecorded:
                        pass
        return calls

    def _variants(self, models, precisions):
        """``(precision, models)`` for each of ``precisions`` in which any of ``models`` (default
        all) runs: this case's models, and in float32 those that have it."""
        for precision in precisions:
            chosen = tuple(m for m in (models or MODELS)
                           if m in self.models and (precision == "float64" or m in FLOAT32_MODELS))
            if chosen:
                yield precision, chosen


CASES = {
    case.name: case for case in (
        Case("cantilever", "Cantilever under its own weight: static tip deflection", Cantilever(), run_cantilever,
             "tip deflection"),
        Case("axial-vibration", "Axial vibration of a fixed-free bar: period of the free end", AxialVibration(),
             run_axial_vibration, "period"),
        Case("traction", "Bar under end traction on rollers: elongation and contraction", Traction(), run_traction,
             "elongation"),
        Case("rigid-motion", "Free fall and rigid spin", RigidMotion(), run_rigid_motion, "centroid drop"),
        Case("patch", "Patch test on an unstructured mesh: uniform F", Patch(), run_patch, "max |F - A|"),
        Case("energy", "Energy of an undamped oscillating beam (symplectic Euler)", Energy(), run_energy,
             "energy error"),
    )
}
