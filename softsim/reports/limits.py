"""The measured stability limit of symplectic Euler, against the ``dt: auto`` step.

For one small free body (no gravity, no ground, nothing held, no damping) on a given mesh, material
model, E and nu, ``measure_limit`` finds the largest step at which the time loop stays bounded, by
running it:

- the body starts in its rest shape with a small random smooth velocity field (a random strain
  rate, RMS speed ``PERTURBATION x`` the dilatational wave speed: strains about 1e-6, where every
  model is Hooke's law);
- a step counts as stable if, over ``steps`` steps (thousands), the total energy (kinetic +
  elastic; there is no gravity) stays finite and within ``ENERGY_FACTOR`` of the start.  Just above
  the limit the top mode grows by ``1 + 2 sqrt(omega dt - 2)`` per step (x1.3 at 1 % above): from
  the start's share, or from round-off, it passes the factor within tens to hundreds of steps, so
  a growth that ``steps`` steps would miss is one within well under 1 % of the limit;
- the bracket starts around symplectic Euler's theoretical limit ``2 / omega_max``
  (``stability.exact_stable_step``), or, independent of it, at [auto, 3 auto]; each end is
  confirmed by a run and widened until it is; then it is bisected (geometrically) until the
  unstable end is within ``tolerance`` of the stable one.

The ``auto`` step is what ``prepare`` gives the same scene with ``time.dt: auto`` before fitting it
to the frames (``Prepared.safe_dt``).  The report wants ``auto <= measured <= 2 auto``.
"""

import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MESH_KINDS = ("structured", "gmsh", "slivers")
# Densities that go with a Young's modulus (rubber ... steel) [kg/m^3]; any other E gets 1000.
DENSITY = {1e5: 1000.0, 1e6: 1100.0, 1e7: 1100.0, 1e9: 1500.0, 2e11: 7850.0}
ENERGY_FACTOR = 2.0
PERTURBATION = 1e-6
STEPS = 3000
TOLERANCE = 0.02
CHUNK = 50
SEED = 5
# The bracket around the theoretical limit the search starts from (each end is checked by a run),
# and the upper end of the wide one, in units of the auto step.
START_BRACKET = (0.992, 1.008)
WIDE_BRACKET = 3.0
CUBE_SIZE = 0.1
CELL = 0.025
GMSH_SIZE = 0.05


@dataclass(frozen=True)
class LimitCase:
    """One point of the stability plot: a material model, E [Pa], nu, and a mesh kind."""

    model: str
    youngs_modulus: float
    poissons_ratio: float
    mesh_kind: str

    @property
    def density(self):
        return DENSITY.get(self.youngs_modulus, 1000.0)

    @property
    def label(self):
        return f"{self.model} E={self.youngs_modulus:g} nu={self.poissons_ratio:g} {self.mesh_kind}"


@dataclass(frozen=True)
class LimitMeasurement:
    """The result of ``measure_limit``.

    auto_dt: the ``dt: auto`` step [s]; exact_dt: ``2 / omega_max`` at rest [s]; measured_dt: the
    largest step found stable [s]; unstable_dt: the smallest found unstable [s] (within
    ``tolerance`` above measured_dt); blowup_steps: steps the run at unstable_dt took to leave the
    bound (how fast growth just above the limit shows); steps: run length of a stable verdict;
    runs: runs made; wall_time_s.
    """

    case: LimitCase
    auto_dt: float
    exact_dt: float
    measured_dt: float
    unstable_dt: float
    blowup_steps: int
    steps: int
    runs: int
    wall_time_s: float

    @property
    def ratio(self):
        """measured / auto."""
        return self.measured_dt / self.auto_dt


def limit_meshes(mesh_dir, kinds=MESH_KINDS):
    """Write the small meshes of the measurement into ``mesh_dir``; ``{kind: path}``.

    structured: a 10 cm cube of 4 x 4 x 4 cells, 5 tets each (320 tets); gmsh: the same cube meshed
    by gmsh with edges of 2.5-5 cm (about 400 tets); slivers: the structured cube with its interior vertices moved at
    random by up to 0.45 of a cell.
    """
    from ..mesh.generate import gmsh_box, structured_box
    from .catalogue import sliver_box, write_mesh

    size = (CUBE_SIZE,) * 3
    builders = {
        "structured": lambda: structured_box(size, (0.0, 0.0, 0.0), CELL),
        "gmsh": lambda: gmsh_box(size, (0.0, 0.0, 0.0), GMSH_SIZE),
        "slivers": lambda: sliver_box(size, CELL),
    }
    mesh_dir = Path(mesh_dir)
    return {kind: write_mesh(mesh_dir / f"limit-{kind}.vtu", *builders[kind]()) for kind in kinds}


def limit_scene(case, mesh_file):
    """The validated scene of ``case`` on ``mesh_file``: a free body, no gravity, no damping, dt auto."""
    from ..config import parse_scene

    return parse_scene({
        "mesh": {"shape": "file", "file": str(mesh_file)},
        "material": {"model": case.model, "youngs_modulus": case.youngs_modulus,
                     "poissons_ratio": case.poissons_ratio, "density": case.density},
        "gravity": [0.0, 0.0, 0.0],
    })


def perturbation_velocities(model, wave_speed, seed=SEED):
    """Random smooth velocities (n, 3) [m/s] in internal order: a random symmetric strain rate
    (a pure deformation, no rotation) about the centre of mass, RMS speed ``PERTURBATION x
    wave_speed``.

    Smooth on purpose: the highest modes, the ones that go unstable first, then start with almost
    no energy, so a bounded oscillation of theirs cannot push the total energy past
    ``ENERGY_FACTOR`` just below the limit (with white noise, structured meshes, whose spectrum is
    crowded near the top, tripped the factor at 0.96x the limit); above the limit they grow from
    round-off and cross it within a few hundred steps.
    """
    rng = np.random.default_rng(seed)
    mass = model.mass
    centre = (mass[:, None] * model.rest_points).sum(axis=0) / mass.sum()
    A = rng.standard_normal((3, 3))
    v = (model.rest_points - centre) @ (A + A.T).T
    v[mass == 0.0] = 0.0
    rms = math.sqrt(float((v * v).sum(axis=1).mean()))
    return v * (PERTURBATION * wave_speed / rms)


def stays_bounded(prepared, dt, v0, steps=STEPS):
    """``(stable, steps_run)``: whether ``steps`` symplectic-Euler steps of ``dt`` [s] from rest with
    velocities ``v0`` keep the energy finite and within ``ENERGY_FACTOR`` of the start."""
    from ..model import initial_state
    from ..simulation import frame_energy, step

    model = prepared.model
    state = initial_state(prepared.scene, model)
    state.v[...] = v0

    def energy():
        e = frame_energy(model, state)
        return e["kinetic"] + e["elastic"]

    start = energy()
    corner_forces = np.empty((model.tet_count, 4, 3))
    done = 0
    while done < steps:
        count = min(CHUNK, steps - done)
        step(model, state, dt, count, 0.0, corner_forces)
        done += count
        e = energy()
        if not (math.isfinite(e) and e <= ENERGY_FACTOR * start):
            return False, done
    return True, done


def measure_limit(case, mesh_file, steps=STEPS, tolerance=TOLERANCE, bracket="theory"):
    """``LimitMeasurement`` of ``case`` on ``mesh_file`` (see the module docstring).

    bracket: where the search starts.  ``"theory"``: ``START_BRACKET`` x the eigenvalue limit
    (already within ``tolerance``: two runs when theory is right); ``"wide"``: from the auto step to ``WIDE_BRACKET`` x it,
    independent of the eigenvalue computation (about eight runs).  Either way each end is
    confirmed by a run, and moved out (x0.8 down, x1.25 up) until it is.
    """
    from ..integrators.stability import exact_stable_step
    from ..simulation import prepare

    started = _time.perf_counter()
    prepared = prepare(limit_scene(case, mesh_file))
    auto = prepared.safe_dt
    exact = exact_stable_step(prepared.model)
    v0 = perturbation_velocities(prepared.model, prepared.wave_speed)
    runs = 0
    blowup = {}

    def stable(dt):
        nonlocal runs
        runs += 1
        ok, done = stays_bounded(prepared, dt, v0, steps)
        if not ok:
            blowup[dt] = done
        return ok

    if bracket == "theory":
        lo, hi = START_BRACKET[0] * exact, START_BRACKET[1] * exact
    elif bracket == "wide":
        lo, hi = auto, WIDE_BRACKET * auto
    else:
        raise ValueError(f"bracket must be 'theory' or 'wide', got {bracket!r}")
    hi_confirmed = False
    while not stable(lo):                 # the stable end, confirmed
        hi, hi_confirmed = lo, True
        lo *= 0.8
        if lo < 0.05 * auto:
            raise RuntimeError(f"{case.label}: no stable step found down to {lo:.3g} s")
    if not hi_confirmed:
        while stable(hi):                 # the unstable end, confirmed
            lo = hi
            hi *= 1.25
            if hi > 20.0 * auto:
                raise RuntimeError(f"{case.label}: still stable at {hi:.3g} s, 20x the auto step")
    while hi > lo * (1.0 + tolerance):
        mid = math.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return LimitMeasurement(case=case, auto_dt=auto, exact_dt=exact, measured_dt=lo, unstable_dt=hi,
                            blowup_steps=blowup[hi], steps=steps, runs=runs,
                            wall_time_s=_time.perf_counter() - started)


def limit_cases(models, youngs_moduli, poissons_ratios, mesh_kinds=MESH_KINDS):
    """Every combination, as ``LimitCase``s (model outermost)."""
    return [LimitCase(model, float(E), float(nu), kind)
            for model in models for kind in mesh_kinds for nu in poissons_ratios for E in youngs_moduli]


def verdicts(measurements):
    """``{model: (min ratio, max ratio, ok)}`` of measured / auto; ok: all within [1, 2]."""
    out = {}
    for m in measurements:
        out.setdefault(m.case.model, []).append(m.ratio)
    return {model: (min(r), max(r), min(r) >= 1.0 and max(r) <= 2.0) for model, r in out.items()}
