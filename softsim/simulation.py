"""Orchestration of one run: scene -> mesh -> model -> time loop -> HDF5.

``prepare`` does everything that can fail on bad input (meshing, checks, time plan) before any
file is written; ``simulate`` runs the prepared scene frame by frame.  Kernels do the numbers;
this module only decides what to call and in which order.
"""

import logging
import math
import time as _time
import weakref
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .config import scene_to_yaml
from .integrators.symplectic_euler import (PartSchedule, PrefetchChoice, advance, advance_driver, step_arguments,
                                           step_threads, work_buffer)
from .errors import ConfigError, SimulationError
from .integrators.guard import RECHECK_CHANGE, RECHECK_STEPS, FrameGuard, element_measure_call, ground_spring_energy
from .integrators.stability import exact_stable_step, nodal_frequency_bound
from .integrators.timestep import (AUTO_EIGEN_ITERATIONS, AUTO_EIGEN_MIN_STEPS, AUTO_EIGEN_SAFETY, AUTO_SAFETY,
                                   dilatational_wave_speed, plan_time)
from .io.hdf5 import (RunWriter, attributes_of, check_writable, frames_written, free_bytes, read_resume_state,
                      refuse_if_being_written, require_resume_names)
from .kernels.energy import elastic_energy, gravity_energy, kinetic_energy
from .kernels.fields import tet_fields
from .kernels import compile_ahead
from .kernels.jit import compile_timer, threading_layer
from .mesh import build_mesh, mesh_file_sha256
from .model import State, build_model, initial_state

log = logging.getLogger("softsim")

# dt: exact uses this fraction of the eigenvalue limit 2 / sqrt(lambda_max(M^-1 K)) at rest.
EXACT_SAFETY = 0.9
# float32's spacing relative to a value (half an ulp); float32 runs warn when a step damps
# velocities by less than FLOAT32_DAMPING_FLOOR of themselves (the damping rate then off by > 1 %).
FLOAT32_SPACING = float(np.finfo(np.float32).eps) / 2.0
FLOAT32_DAMPING_FLOOR = 100.0 * FLOAT32_SPACING


@dataclass(frozen=True)
class Prepared:
    """A scene ready to run: its model, time plan, and stable steps.

    dt_estimate: a rigorous lower bound of the stable step at rest [s]; safe_dt: the step
    ``dt: auto`` would use before fitting it to the frames (``auto_step``), or under ``dt: exact``
    ``EXACT_SAFETY`` x the limit [s]; substeps: how many sub-steps the
    policy split a given dt into; wave_speed: dilatational wave speed [m/s].
    """

    scene: object
    model: object
    plan: object
    dt_estimate: float
    safe_dt: float
    substeps: int
    wave_speed: float

    @property
    def mesh(self):
        return self.model.mesh


@dataclass(frozen=True)
class RunSummary:
    """What a finished run reports: planned steps, dt [s], wall time [s] (compiling included),
    tet-steps per second (counting sub-steps; over the wall time less the compiling), frames and
    the output path."""

    steps: int
    dt: float
    wall_time_s: float
    tet_steps_per_s: float
    frames: int
    path: str
    status: str = "complete"      # or "interrupted" (stopped on request after a whole frame)
    time: float = 0.0             # simulated time reached [s]
    compile_time_s: float = 0.0   # of the wall time, Numba compiling kernels its disk cache did not hold
    step: int = 0                 # the planned step reached (``steps`` when complete)


def stable_dt_estimate(model):
    """A lower bound [s] of symplectic Euler's stable step at rest: ``2 / sqrt(nodal bound)``.

    The nodal bound ``max_i sum_{e at i} lambda_max(K_e) / m_i`` (plus the ground's springs) is
    above the largest eigenvalue of ``M^-1 K``, so this step is never above the true limit; we
    measured the true limit at 1.17-1.93x it on structured, gmsh and sliver meshes
    (``benchmarks/stable_step_factor.py``).  The older altitude / wave-speed estimate overshot the
    limit on structured meshes (0.91x) and undershot it 10x with slivers.
    """
    bound = nodal_frequency_bound(model)
    return 2.0 / math.sqrt(bound) if bound > 0.0 else math.inf


def auto_step(model, duration, dt_estimate):
    """The ``dt: auto`` step [s] before it is fitted to the frames (see ``integrators.timestep``).

    ``max(AUTO_SAFETY x dt_estimate, AUTO_EIGEN_SAFETY x 2 / omega_max)`` with the eigenvalue
    limit at rest from Lanczos, computed only when a run of ``duration`` [s] takes at least
    ``AUTO_EIGEN_MIN_STEPS`` steps at the nodal-bound step (else that step alone).  Between 0.6
    and 0.8x the limit at rest; deterministic (fixed-seed Lanczos), so a resumed run plans the same.
    """
    nodal = AUTO_SAFETY * dt_estimate
    if not math.isfinite(nodal) or duration / nodal < AUTO_EIGEN_MIN_STEPS:
        return nodal
    return max(nodal, AUTO_EIGEN_SAFETY * exact_stable_step(model, iterations=AUTO_EIGEN_ITERATIONS))


def safe_step_basis(time):
    """What ``Prepared.safe_dt`` is for the scene's ``time`` settings, in words for messages."""
    if time.dt == "exact":
        return f"{EXACT_SAFETY:g} x the stability limit"
    return "dt: auto's, below the stability limit"


def choose_dt(scene, model, dt_estimate):
    """``(dt_target, safe_dt, substeps)`` [s, s, count] from ``time.dt`` and ``time.dt_policy``.

    ``auto``: ``auto_step`` (the larger of ``AUTO_SAFETY x`` the nodal-bound step and, for runs long
    enough, ``AUTO_EIGEN_SAFETY x`` the eigenvalue limit); ``exact``: ``EXACT_SAFETY x`` the limit
    from the largest eigenvalue of M^-1 K.  A given dt above the safe (auto) step is split into the
    fewest equal sub-steps below it (``substep``), refused (``refuse``), or used as given (``allow``).
    """
    safe = auto_step(model, scene.time.duration, dt_estimate)
    if scene.time.dt == "auto":
        return safe, safe, 1
    if scene.time.dt == "exact":
        exact = EXACT_SAFETY * exact_stable_step(model)
        return exact, exact, 1
    dt = float(scene.time.dt)
    if dt <= safe * (1.0 + 1e-9) or scene.time.dt_policy == "allow":
        if dt > safe:
            log.warning("time.dt = %.4g s is above the safe step %.4g s (%s); dt_policy: allow uses it as given",
                        dt, safe, safe_step_basis(scene.time))
        return dt, safe, 1
    if scene.time.dt_policy == "refuse":
        raise ConfigError(f"time.dt = {dt:g}: above the safe step {safe:.4g} s of this mesh and material "
                          f"({safe_step_basis(scene.time)}; dt_policy: refuse); use a dt <= {safe:.4g}, "
                          f"dt: auto, or dt_policy: substep")
    substeps = math.ceil(dt / safe - 1e-9)
    return dt / substeps, safe, substeps


def prepare(scene, mesh=None, resuming=False, compile_in_helper=False):
    """Mesh the scene (unless ``mesh``, a ``TetMesh`` already built from ``scene.mesh``, is given),
    build its model and time plan; raises ``SoftsimError`` on bad input.  resuming: the run goes on
    from a stored frame, so what the initial state would do (start in the ground) is not warned of.
    compile_in_helper: start compiling the step and the guard in a helper process, where the disk
    cache lacks them (``compile_run_ahead``), once the model is built."""
    model = scene_model(scene, mesh)
    if compile_in_helper:
        compile_run_ahead(scene, model)
    if model.has_ground and not resuming:
        warn_of_start_in_ground(scene, model)
    material = scene.material
    wave_speed = dilatational_wave_speed(material.youngs_modulus, material.poissons_ratio, material.density)
    dt_estimate = stable_dt_estimate(model)
    dt, safe_dt, substeps = choose_dt(scene, model, dt_estimate)
    loss = scene.damping * dt
    if scene.precision == "float32" and 0.0 < loss < FLOAT32_DAMPING_FLOOR:
        log.warning("precision: float32 with damping %g: a step damps velocities by %.2g of themselves, and "
                    "float32 resolves about %.0e, so the damping rate may be off by up to %.0f %%; use float64",
                    scene.damping, loss, FLOAT32_SPACING, 100 * FLOAT32_SPACING / loss)
    if scene.time.dt in ("auto", "exact"):
        plan = plan_time(scene.time.duration, scene.output.frame_interval, max_dt=dt)
    else:
        step_text = (f"time.dt = {scene.time.dt:g} s, split into {substeps} sub-steps of {dt:.4g} s,"
                     if substeps > 1 else None)
        plan = plan_time(scene.time.duration, scene.output.frame_interval, dt=dt, step_text=step_text)
    return Prepared(scene=scene, model=model, plan=plan, dt_estimate=dt_estimate, safe_dt=safe_dt,
                    substeps=substeps, wave_speed=wave_speed)


def scene_model(scene, mesh=None):
    """The ``Model`` of ``scene``, meshed unless ``mesh`` (a ``TetMesh`` built from ``scene.mesh``)
    is given: what ``prepare`` builds before it estimates the stable step and plans the steps."""
    return build_model(scene, build_mesh(scene.mesh) if mesh is None else mesh)


def warn_of_start_in_ground(scene, model):
    """Log a warning when free vertices start below the ground: its penalty springs then start
    compressed and push the body out (the guard counts their energy as put in)."""
    x0 = initial_state(scene, model).x
    below = (x0[:, 2] < model.ground_height) & ~model.held[:, 2]
    if below.any():
        log.warning("ground.height = %g m: %d vertices start below it (the deepest by %.3g m), so the ground's "
                    "springs start compressed, with %.3g J, and push the body out; to start on the ground, lower "
                    "ground.height or move the body (initial_deformation.translation)",
                    model.ground_height, int(below.sum()), float(model.ground_height - x0[below, 2].min()),
                    ground_spring_energy(model, x0))


def frame_energy(model, state):
    """Kinetic, elastic and gravitational energy [J] of ``state``."""
    return {
        "kinetic": kinetic_energy(state.v, model.mass),
        "elastic": elastic_energy(state.x, model.tets, model.Dm_inv, model.rest_volume,
                                  model.material_id, model.lam, model.mu),
        "gravity": gravity_energy(state.x, model.mass, model.gravity),
    }


def frame_fields(model, state, fields):
    """``{name: array}`` of the array fields in ``fields`` other than ``velocities`` (see
    ``io.fields.FIELDS``) for ``state``: vertex fields in the user's vertex order, tet fields in
    the user's tet order.  Empty, and no kernel runs, when ``fields`` asks for none of them."""
    out = tet_fields(state.x, model.tets, model.Dm_inv, model.material_id, model.lam, model.mu, fields)
    for name, values in out.items():
        user = np.empty_like(values)
        user[model.tet_order] = values
        out[name] = user
    if "displacement" in fields:
        out["displacement"] = model.to_user_order(state.x - model.rest_points)
    if "speed" in fields:
        out["speed"] = model.to_user_order(np.sqrt(np.einsum("ij,ij->i", state.v, state.v)))
    return out


# How the colour scatter's parts ran in the last calls of ``step`` (``PartSchedule``): one for the
# process, as another process taking a core concerns every run in it.
PART_SCHEDULE = PartSchedule()
# Whether the step of each large mesh fetches ahead (``PrefetchChoice``), by block layout and
# thread count.
PREFETCH_CHOICES = weakref.WeakKeyDictionary()


def prefetch_trial_running(model, threads=None):
    """Whether the step of ``model`` is still timing its prefetches against none (``PrefetchChoice.trying``)
    for calls made on ``threads`` threads (``numba.get_num_threads()`` when calling ``step``; None: for
    any thread count): half of such a trial's calls run the slower way, so a caller who times the
    step (a benchmark) ends the trial first.  False for a mesh that does not measure."""
    choices = PREFETCH_CHOICES.get(model.blocks, {})
    if threads is not None:
        choice = choices.get(step_threads(model.tet_count, threads, threading_layer()))
        return choice is not None and choice.trying
    return any(choice.trying for choice in choices.values())


def advance_arguments(model, state, dt, damping, work, prefetch, step_count, threads, one_region):
    """``advance``'s arguments for ``step_count`` steps of ``dt`` [s] of ``model`` from ``state``
    (float64), or, in float32, from ``work`` (``SinglePrecisionWork``, loaded from the state),
    ``prefetch`` or not (``step_arguments``), on ``threads``, ``one_region`` or not
    (``PartSchedule``); and the parts those steps run (0 for the csr scatter)."""
    damping_factor = math.exp(-damping * dt) if damping > 0.0 else None
    if model.precision == "float32":
        x, rest, v, held_start = work.u, work.rest, work.v, work.held_start
        inv_mass, gravity, external_accel = work.inv_mass, work.gravity, work.external_accel
        held_velocity = work.held_velocity
        dt, lam, mu = np.float32(dt), np.float32(model.lam), np.float32(model.mu)
        forces = work.forces
    else:
        x, rest, v, held_start = state.x, None, state.v, state.held_start
        inv_mass, held_velocity = model.inv_mass, model.held_velocity
        gravity = tuple(float(g) for g in model.gravity)
        external_accel = model.external_accel if model.has_tractions else None
        lam, mu = model.lam, model.mu
        forces = work
    blocks, colour_offsets, scatter, offsets, slots, vertex_forces, corner = step_arguments(model, forces, prefetch)
    arguments = (x, rest, v, state.step, step_count, dt, blocks, colour_offsets, scatter, model.material_id, lam, mu,
                 offsets, slots, vertex_forces, corner, inv_mass, gravity, external_accel, model.held, held_start,
                 held_velocity, *model.ground_arguments(), damping_factor, threads, one_region)
    return arguments, step_count * (colour_offsets[-1] if scatter else 0)


def step_calls(scene, model, state=None):
    """The compiled step's calls ``step`` will make for ``scene``'s ``model`` from ``state`` (default:
    the initial state), as ``[(driver, arguments), ...]`` (``advance_driver``): with prefetches
    and, for a mesh that times them, without.  The types of the arguments are what they are for:
    dt is 0 s and no step is taken."""
    state = initial_state(scene, model) if state is None else state
    work = work_buffer(model)
    threads = step_threads(model.tet_count, numba.get_num_threads(), threading_layer())
    calls = []
    for prefetch in (False, True) if model.blocks.measure_prefetch else (True,):
        arguments, _ = advance_arguments(model, state, 0.0, scene.damping, work, prefetch, 0, threads, True)
        calls.append(advance_driver(*arguments))
    return calls


def run_calls(scene, model):
    """The calls of compiled kernels a run of ``scene``'s ``model`` makes that take longest to
    compile, in the order the run first makes them, as ``[(kernel, arguments), ...]``: the guard's
    measure of the tets (``guard.element_measure_call``), then the step's (``step_calls``)."""
    state = initial_state(scene, model)
    m = model.tet_count
    guard_call = element_measure_call(model, state.x, np.empty(m), np.empty(m), np.ones(m), np.ones(m),
                                      RECHECK_CHANGE)
    return [guard_call] + step_calls(scene, model, state)


def compile_run_ahead(scene, model):
    """Start compiling the kernels of ``run_calls`` in a helper process, where Numba's disk cache
    lacks them (``kernels.compile_ahead``): this process compiles the stable step, the energies and
    the fields meanwhile, and waits for the helper before it first calls one of them.  Returns how
    many specialisations the helper took (0: none)."""
    if not compile_ahead.enabled():
        return 0
    return compile_ahead.submit(run_calls(scene, model))


def step(model, state, dt, step_count, damping, work):
    """Advance ``state`` in place by ``step_count`` symplectic-Euler steps of ``dt`` [s]; work: the
    buffer of ``work_buffer(model)``.  A float32 model steps displacements in float32
    (``integrators.symplectic_euler.SinglePrecisionWork``); ``state`` stays float64.  A large mesh
    steps with its prefetches or without them, whichever its calls time faster (``PrefetchChoice``,
    one per block layout and thread count in ``PREFETCH_CHOICES``): the same bits either way.  Its
    first call compiles (or loads) both ways, the second by a call of no step, so that a caller
    who times the calls after the first (a speed sample, a benchmark) times no compiling; it
    first waits for a helper compiling the step (``compile_run_ahead``), if one runs."""
    if model.precision == "float32":
        work.load(state, model.rest_points)
    available = numba.get_num_threads()
    threads = step_threads(model.tet_count, available, threading_layer())
    one_region = PART_SCHEDULE.one_region()

    def advance_way(prefetch, steps):
        arguments, parts = advance_arguments(model, state, dt, damping, work, prefetch, steps, threads, one_region)
        return advance(*arguments), parts

    compile_ahead.wait()
    choice = None
    numba.set_num_threads(threads)
    try:
        if model.blocks.measure_prefetch:
            choices = PREFETCH_CHOICES.setdefault(model.blocks, {})
            if threads not in choices:
                advance_way(False, 0)          # compiles (or loads) the step without prefetches; moves nothing
                choices[threads] = PrefetchChoice()
            choice = choices[threads]
        prefetch = choice is None or choice.prefetch_next()
        started = _time.perf_counter()
        long_waits, parts = advance_way(prefetch, step_count)
        seconds = _time.perf_counter() - started
    finally:
        numba.set_num_threads(available)
    if choice is not None:
        choice.record(prefetch, seconds, step_count)
    PART_SCHEDULE.record(one_region, long_waits, parts)
    if model.precision == "float32":
        work.store(state, model.rest_points)
    state.step += step_count


def advance_substeps(model, state, dt, step_count, substeps, damping, work):
    """Advance ``state`` by ``step_count`` steps of ``dt`` [s], each split into ``substeps`` equal ones.

    Returns the number of steps taken (``step_count * substeps``).
    """
    if substeps == 1:
        step(model, state, dt, step_count, damping, work)
        return step_count
    fine = State(x=state.x, v=state.v, step=state.step * substeps, held_start=state.held_start)
    step(model, fine, dt / substeps, step_count * substeps, damping, work)
    state.step += step_count
    return step_count * substeps


def simulate(prepared, output_path, progress=None, should_stop=None, resume=False, overwrite=True):
    """Run a prepared scene, writing frames to ``output_path``; returns a ``RunSummary``.

    progress: optional callable ``progress(steps_done, total_steps)`` called after every frame.
    should_stop: optional callable checked after every frame; when it returns True the run ends
    there, cleanly, with status ``interrupted`` (a signal handler sets it: Ctrl-C, SIGTERM).
    resume: continue the run already in ``output_path`` from its last complete frame (see
    ``check_resumable``); on the same machine and thread count the trajectory is the same, bit
    for bit, as a run that never stopped.
    overwrite: whether an existing ``output_path`` may be replaced; checked again just before the
    file is made, since meshing and compiling may give another run time to write it.
    On an exception or KeyboardInterrupt the file keeps its frames and gets status ``failed`` /
    ``interrupted``.
    """
    started = _time.perf_counter()
    with compile_timer() as compiled:
        status, frames, steps_taken, step_reached = _simulate(prepared, output_path, progress, should_stop, resume,
                                                              overwrite, compiled, started)
    wall = _time.perf_counter() - started
    compiling = compiled()
    plan = prepared.plan
    return RunSummary(steps=plan.total_steps, dt=plan.dt, wall_time_s=wall,
                      tet_steps_per_s=prepared.model.tet_count * steps_taken / max(wall - compiling, 1e-12),
                      frames=frames, path=str(output_path), status=status, time=step_reached * plan.dt,
                      compile_time_s=compiling, step=step_reached)


def _simulate(prepared, output_path, progress, should_stop, resume, overwrite, compiled, started):
    """``simulate``'s run: returns its status, the frames in the file, the steps taken (sub-steps
    counted) and the step of the plan reached.  compiled: the compile time so far [s], a
    function (``kernels.jit.compile_timer``), which the file records with its wall time, counted
    from ``started`` (a ``time.perf_counter()`` reading, when the compile timer started)."""
    scene, model, plan = prepared.scene, prepared.model, prepared.plan
    state = initial_state(scene, model)
    fields = scene.output.fields
    work = work_buffer(model)
    guard = FrameGuard(model, prepared.wave_speed, plan.dt, scene.time.dt_policy, state)

    def check_and_write_frame(writer, time):
        """The guard's check of the frame at ``time`` [s], then the frame written; returns the
        sub-steps per step for the next frame.  The energies are computed once for both."""
        energy = frame_energy(model, state)
        substeps = guard.check(state, time, energy)
        writer.append_frame(time, state.step, model.to_user_order(state.x), model.to_user_order(state.v),
                            energy if "energy" in fields else None, guard.snapshot(),
                            frame_fields(model, state, fields))
        writer.compile_time_s = compiled()
        return substeps

    if resume:
        writer, stored = RunWriter.reopen(output_path, fields, frames=len(plan.frame_steps), started=started,
                                          needs=FrameGuard.SNAPSHOT_NAMES, mesh=(model.mesh.points, model.mesh.tets),
                                          attributes=run_sources(model.mesh))
        state.x[...] = model.from_user_order(stored["positions"])
        state.v[...] = model.from_user_order(stored["velocities"])
        state.step = int(stored["step"])
        guard.restore(stored)
        substeps = guard.substeps if scene.time.dt_policy != "allow" else 1
    else:
        check_writable(output_path, overwrite)
        writer = RunWriter(output_path, model.mesh.points, model.mesh.tets, model.to_user_order(model.fixed),
                           scene_to_yaml(scene), plan.dt, plan.total_steps, fields, frames=len(plan.frame_steps),
                           resume_template=guard.snapshot(), started=started, overwrite=overwrite,
                           attributes=run_sources(model.mesh))
    with writer:
        if not resume:
            substeps = check_and_write_frame(writer, 0.0)
        steps_taken = 0
        status = "complete"
        for target in plan.frame_steps:
            if target <= state.step:
                continue
            steps = target - state.step
            while target - state.step > RECHECK_STEPS:
                steps_taken += advance_substeps(model, state, plan.dt, RECHECK_STEPS, substeps, scene.damping,
                                                work)
                substeps = guard.recheck_step(state, state.step * plan.dt)
            steps_taken += advance_substeps(model, state, plan.dt, target - state.step, substeps, scene.damping,
                                            work)
            guard.record_held_work(state, steps * plan.dt)
            substeps = check_and_write_frame(writer, state.step * plan.dt)
            if progress is not None:
                progress(state.step, plan.total_steps)
            if should_stop is not None and should_stop() and state.step < plan.total_steps:
                status = "interrupted"
                frames = writer.frame_count
                writer.finish(status, f"stopped on request at t = {state.step * plan.dt:.6g} s "
                                      f"(step {state.step} of {plan.total_steps})")
                break
        else:
            frames = writer.frame_count
    return status, frames, steps_taken, state.step


# A run estimated to take longer than this [s of wall time] starts only when confirmed (--yes).
LONG_RUN_S = 3600.0
# Below any speed softsim falls to [tet-steps/s] (a few hundred tets on one thread step at about
# 3e7): a run shorter than LONG_RUN_S even at this speed is not measured.  The measuring bursts
# double until one lasts SPEED_SAMPLE_S, so they take 1 to 4 times it: at most 5 % of a run they
# measure (7.2e9 tet-steps or more: 24 s at the fastest 3e8 tet-steps/s, 4 min at 3e7).
SLOWEST_TET_STEPS_PER_S = 2e6
# Wall time [s] of the burst of steps that measures this machine's speed for a long run.
SPEED_SAMPLE_S = 0.3
# How much slower than the burst a run may go: the burst steps bare for a fraction of a second;
# a run also writes its frames and checks each one, and a shared machine's speed drifts by up to
# 2x.  The cantilever scene for 2000 s, a frame a second, estimated at 43 min, stepped at 0.66x
# the burst's speed for the 10 min it was let run (68 min in all at that speed; 2-core host,
# 2026-12-06); with the example's fields and frames, runs went at 0.3-0.45x.  A run is timed
# against LONG_RUN_S at the burst's speed over this.
SPEED_MARGIN = 2.0


@dataclass(frozen=True)
class RunEstimate:
    """What a prepared run will cost: ``tet_steps`` (sub-steps counted), ``seconds`` of wall time
    at ``tet_steps_per_s`` measured on this machine (both None when the run is short even at the
    slowest speed, ``SLOWEST_TET_STEPS_PER_S``, so nothing was measured), and the output file's size
    against the free disk."""

    tets: int
    steps: int
    tet_steps: float
    tet_steps_per_s: float
    seconds: float
    output_bytes: int
    free_bytes: int

    def problems(self):
        """The reasons (text) this run needs confirmation; empty when it does not."""
        found = []
        if self.seconds is not None and self.seconds * SPEED_MARGIN > LONG_RUN_S:
            found.append(f"{self.tets:,} tets x {self.steps:,} steps take about {_duration_text(self.seconds)} "
                         f"at this machine's measured {self.tet_steps_per_s / 1e6:.3g} M tet-steps/s, up to "
                         f"{_duration_text(self.seconds * SPEED_MARGIN)} with the frames and the machine's drift")
        if self.output_bytes > self.free_bytes:
            found.append(f"the output needs about {self.output_bytes / 1e9:.3g} GB but only "
                         f"{self.free_bytes / 1e9:.3g} GB are free (the run would stop when the disk is full)")
        return found


def _duration_text(seconds):
    if seconds >= 2 * 86400:
        return f"{seconds / 86400:.1f} days"
    if seconds >= 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 60:.0f} min"


def frame_bytes(node_count, tet_count, fields):
    """Bytes one frame adds to the output file: positions plus the fields asked for."""
    from .io.fields import FIELDS

    count = {"vertex": node_count, "tet": tet_count, "frame": 1}
    total = 8 * (3 * node_count + 1)                      # frames/points and frames/time
    for name in fields:
        spec = FIELDS[name]
        total += 8 * count[spec.location] * int(np.prod(spec.shape, dtype=np.int64)) * len(spec.datasets)
    return total


def estimate_run(prepared, output_path):
    """A ``RunEstimate`` for ``prepared``: its speed is measured by a short burst of steps on a copy
    of the initial state, only when the run could be long at the slowest speed (the burst also
    compiles the kernels, which the run would do anyway)."""
    scene, model, plan = prepared.scene, prepared.model, prepared.plan
    tet_steps = float(model.tet_count) * plan.total_steps * prepared.substeps
    seconds, speed = None, None
    if tet_steps / SLOWEST_TET_STEPS_PER_S > LONG_RUN_S:
        state = initial_state(scene, model)
        buffer = work_buffer(model)
        advance_substeps(model, state, plan.dt, 1, prepared.substeps, scene.damping, buffer)   # compile
        steps, elapsed = 1, 0.0
        while elapsed < SPEED_SAMPLE_S and steps < plan.total_steps:
            started = _time.perf_counter()
            advance_substeps(model, state, plan.dt, steps, prepared.substeps, scene.damping, buffer)
            elapsed = _time.perf_counter() - started
            steps *= 2
        speed = model.tet_count * (steps // 2) * prepared.substeps / max(elapsed, 1e-9)
        seconds = tet_steps / speed
    output_bytes = len(plan.frame_steps) * frame_bytes(model.node_count, model.tet_count, scene.output.fields)
    free = free_bytes(output_path)
    return RunEstimate(tets=model.tet_count, steps=plan.total_steps * prepared.substeps, tet_steps=tet_steps, tet_steps_per_s=speed, seconds=seconds,
                       output_bytes=int(output_bytes), free_bytes=int(free))


def run_sources(mesh):
    """The root attributes that tell what a run of ``mesh`` (a ``TetMesh``) was made from besides its
    scene: ``mesh_file_sha256``, the content of a mesh file, for ``run_file_difference``."""
    return {} if mesh.source_sha256 is None else {"mesh_file_sha256": mesh.source_sha256}


def check_run_cost(prepared, output_path, confirmed=False):
    """Raise ``SimulationError`` if the run would take over ``LONG_RUN_S`` or outgrow the free disk,
    unless ``confirmed``; returns the reasons (empty for an ordinary run) for the caller to show."""
    problems = estimate_run(prepared, output_path).problems()
    if problems and not confirmed:
        raise SimulationError(f"{'; '.join(problems)}; continue with --yes")
    return problems


def check_resumable(scene, output_path):
    """Raise ``SimulationError`` unless ``output_path`` holds an unfinished run of this same scene;
    return ``(frames, time)`` of the resume state the run goes on from: the complete frames it
    keeps and the simulated time [s] of the last.

    The stored ``config`` must equal the scene's (all but ``output.path``), and a mesh file's
    content the one the run read (``run_file_difference``): resuming a changed scene would splice
    two different simulations.
    """
    import h5py

    path = Path(output_path)
    if not path.is_file():
        raise SimulationError(f"--resume: '{output_path}' does not exist; there is nothing to resume")
    refuse_if_being_written(output_path, resuming=True)
    try:
        with h5py.File(path, "r") as f:
            stored = attributes_of(f)
            stored_state = read_resume_state(f) if "state" in f else None
            frames = frames_written(f)
    except (OSError, KeyError) as exc:
        raise SimulationError(f"--resume: '{output_path}' is not a softsim output file ({exc})") from None
    if "config" not in stored:
        raise SimulationError(f"--resume: '{output_path}' is not a softsim output file (it has no config)")
    if stored.get("status") == "complete":
        raise SimulationError(f"--resume: '{output_path}' is complete; there is nothing to resume")
    if frames == 0:
        raise SimulationError(f"--resume: '{output_path}' has no complete frame to resume from; "
                              f"start the run again with --overwrite")
    if stored_state is None:
        raise SimulationError(f"--resume: '{output_path}' has no intact state/ to resume from")
    require_resume_names(output_path, stored_state, FrameGuard.SNAPSHOT_NAMES)
    key = run_file_difference(stored, scene)
    if key is not None:
        raise SimulationError(f"--resume: the scene changed since '{output_path}' was written ({key}); "
                              f"resuming it would splice two different runs")
    return int(stored_state["frames"]), float(stored_state["time"])


def scene_difference(stored_yaml, scene):
    """``None`` if ``scene`` equals the scene stored in a run file (its ``config`` YAML), all but
    ``output.path``; else the first difference as ``dotted.key: old -> new`` (for messages)."""
    import yaml

    stored, current = yaml.safe_load(stored_yaml), yaml.safe_load(scene_to_yaml(scene))
    for d in (stored, current):
        d.get("output", {}).pop("path", None)
    return None if stored == current else _first_difference(stored, current)


def run_file_difference(stored, scene, digests=None):
    """``None`` if a run file whose root attributes are ``stored`` (``io.hdf5.RUN_ATTRIBUTES``:
    ``config`` and, from a mesh file, ``mesh_file_sha256``) was written for ``scene`` as it is now;
    else the first difference, for messages.  A mesh file's content counts: the scene names the
    file, not what it holds.  (A file written before softsim stored the hash is taken as matching
    here; a resume still compares the meshes themselves, ``RunWriter.reopen``.)  digests: a dict
    from mesh file to hash, filled as files are hashed, so that a caller comparing many runs of one
    file (a sweep) reads it once."""
    key = scene_difference(stored["config"], scene)
    if key is None and scene.mesh.shape == "file" and "mesh_file_sha256" in stored:
        digests = {} if digests is None else digests
        if scene.mesh.file not in digests:
            digests[scene.mesh.file] = mesh_file_sha256(scene.mesh.file)
        now = digests[scene.mesh.file]
        if now != stored["mesh_file_sha256"]:
            key = (f"mesh.file: the content of '{scene.mesh.file}' changed (SHA-256 "
                   f"{stored['mesh_file_sha256'][:12]}... -> {now[:12]}...)")
    return key


def _first_difference(a, b, prefix=""):
    """Dotted key of the first difference between two nested mappings (for messages)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                return _first_difference(a.get(key), b.get(key), f"{prefix}{key}.")
    return f"{prefix.rstrip('.')}: {a!r} -> {b!r}"


def run(scene, output_path=None, progress=None):
    """Prepare and simulate ``scene``; ``output_path`` defaults to the scene's ``output.path``."""
    prepared = prepare(scene)
    return simulate(prepared, output_path or scene.output.path, progress)
