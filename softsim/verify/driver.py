"""Running one verification scene through the library, timing only the time steps.

``Run`` prepares a scene with ``softsim.simulation.prepare`` (meshing, model, stable step) and
advances it with ``softsim.simulation.step``, the same compiled loop ``softsim run`` uses, but
without writing frames: the cases measure what they need between calls.  ``mutate`` replaces the
prepared ``Model`` before anything runs (the tests feed broken material constants or volumes in
this way), and the time step is then taken from the model actually run.

Wall time counts the calls to ``step`` only: not meshing, not the one-step JIT warm-up, not the
measurements between calls (``setup_s`` holds the preparation time).

Within ``recording_step_calls`` a ``Run`` runs nothing: it meshes its scene, builds its model,
records the calls of the compiled step it would make and raises ``RunRecorded``.  ``softsim
verify`` collects its cases' steps so, to compile them on both cores before any timed step.
"""

import contextlib
import copy
import math
import time as _time
from dataclasses import replace

import numpy as np

from ..config import parse_scene
from ..integrators.symplectic_euler import work_buffer
from ..integrators.timestep import AUTO_SAFETY
from ..model import State, initial_state
from ..simulation import prepare, scene_model, stable_dt_estimate, step, step_calls


# Relative change per chunk below which a float32 run counts as at rest: float32 round-off keeps
# the last bits of a relaxed state moving (about 1e-7 relative).
FLOAT32_REST_TOLERANCE = 1e-6
# The list ``Run`` appends its step's calls to, instead of running, within ``recording_step_calls``.
_recorded_calls = None


class RunRecorded(Exception):
    """Raised by ``Run`` within ``recording_step_calls``, once it has recorded its step's calls."""


@contextlib.contextmanager
def recording_step_calls():
    """Within: each ``Run(...)`` meshes its scene, builds its model, appends the calls of the
    compiled step that its runs make (``simulation.step_calls``, ``[(kernel, arguments), ...]``)
    to the list this yields, and raises ``RunRecorded``: nothing is stepped or timed."""
    global _recorded_calls
    outer, _recorded_calls = _recorded_calls, []
    try:
        yield _recorded_calls
    finally:
        _recorded_calls = outer


class Run:
    """A prepared verification scene and its state, advanced in timed chunks.

    scene_data: the raw scene mapping (validated with ``parse_scene``); dt_factor: the step is
    ``dt_factor x`` the ``dt: auto`` step (``AUTO_SAFETY x`` the stable-step bound) of the model
    run; mutate: optional ``Model -> Model`` applied after preparation; precision: of the step.
    Attributes: scene, model (the one stepped), reference_model (as prepared, before ``mutate``:
    energies are measured with it, so a broken force shows as energy that is not conserved), dt [s],
    state, steps (taken), wall_time_s, setup_s.
    """

    def __init__(self, scene_data, dt_factor=1.0, mutate=None, precision="float64"):
        started = _time.perf_counter()
        self.scene = parse_scene({**copy.deepcopy(scene_data), "precision": precision})
        if _recorded_calls is not None:
            model = scene_model(self.scene)
            _recorded_calls.extend(step_calls(self.scene, model if mutate is None else mutate(model)))
            raise RunRecorded
        prepared = prepare(self.scene)
        model = prepared.model if mutate is None else mutate(prepared.model)
        self.model = model
        self.reference_model = prepared.model     # as built: what energies are measured with
        bound = prepared.dt_estimate if mutate is None else stable_dt_estimate(model)
        self.dt = dt_factor * AUTO_SAFETY * bound
        self.damping = self.scene.damping
        self.state = initial_state(self.scene, model)
        self._corner_forces = work_buffer(model)
        self.steps = 0
        self.wall_time_s = 0.0
        self._warm_up()
        self.setup_s = _time.perf_counter() - started

    def _warm_up(self):
        """One step on a throw-away copy: compiles (or loads) this scene's specialisations of the
        loop (both ways of a step that times its prefetches: ``simulation.step``), so that the timed
        steps compile nothing."""
        s = self.state
        scratch = State(x=s.x.copy(), v=s.v.copy(), step=s.step, held_start=s.held_start.copy())
        step(self.model, scratch, self.dt, 1, self.damping, self._corner_forces)

    @property
    def time(self):
        """Simulated time reached [s]."""
        return self.steps * self.dt

    @property
    def tet_count(self):
        return self.model.tet_count

    def restart_from(self, x, v=None):
        """Set the free components of the state to positions ``x`` (and velocities ``v``, default 0)."""
        held = self.model.held
        self.state.x[...] = np.where(held, self.state.x, x)
        self.state.v[...] = np.where(held, self.state.v, 0.0 if v is None else v)

    def advance(self, steps):
        """Take ``steps`` time steps (timed)."""
        if steps <= 0:
            return
        started = _time.perf_counter()
        step(self.model, self.state, self.dt, int(steps), self.damping, self._corner_forces)
        self.wall_time_s += _time.perf_counter() - started
        self.steps += int(steps)

    def steps_for(self, duration):
        """Whole steps covering ``duration`` [s] (at least one)."""
        return max(1, math.ceil(duration / self.dt - 1e-9))

    def relax(self, measure, interval, rel_tol, max_time, min_time=0.0):
        """Advance in chunks of ``interval`` [s] until ``measure()`` changes by less than ``rel_tol``
        of its size over one chunk (after ``min_time``), or until ``max_time`` [s].  A float32 run
        uses at least ``FLOAT32_REST_TOLERANCE``.

        Returns ``(value, converged)``.  With damping ``2 omega`` for the slowest mode and
        ``interval = 1 / omega`` the remaining transient is about the last change.
        """
        if self.scene.precision == "float32":
            rel_tol = max(rel_tol, FLOAT32_REST_TOLERANCE)
        chunk = self.steps_for(interval)
        previous = measure()
        while self.time < max_time:
            self.advance(chunk)
            value = measure()
            if self.time >= min_time and abs(value - previous) <= rel_tol * abs(value):
                return value, True
            previous = value
        return previous, False


def with_lame(model, lam=None, mu=None):
    """``model`` with other Lame parameters (for mutation tests and what-ifs)."""
    return replace(model, lam=model.lam if lam is None else float(lam), mu=model.mu if mu is None else float(mu))


def with_rest_state(model, Dm_inv=None, rest_volume=None):
    """``model`` with other rest shape matrices ``Dm_inv`` (m, 3, 3) [1/m] or rest volumes (m,)
    [m^3] in its force computation (masses unchanged), for mutation tests; the step's blocked copy
    of the rest state (``model.blocks``), where the model has one, is rebuilt from them."""
    Dm_inv = model.Dm_inv if Dm_inv is None else np.ascontiguousarray(Dm_inv, dtype=np.float64)
    rest_volume = model.rest_volume if rest_volume is None else np.ascontiguousarray(rest_volume, dtype=np.float64)
    changes = {"Dm_inv": Dm_inv, "rest_volume": rest_volume}
    if getattr(model, "blocks", None) is not None:
        from ..kernels.blocked import build_block_layout

        # stored whatever the mesh's size: computed from the rest positions, they would not be these
        changes["blocks"] = build_block_layout(model.tets, Dm_inv, rest_volume, model.node_count,
                                               scatter=model.blocks.scatter, dtype=model.blocks.rest.dtype,
                                               rest_from_points=False, model=model.material_id)
    return replace(model, **changes)


def tet_deformation_gradients(rest_points, x, tets):
    """``F = Ds Dm^-1`` of every tet, shape (m, 3, 3), computed in NumPy from rest and current positions."""
    X = rest_points[tets]
    Y = x[tets]
    Dm = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))
    Ds = np.transpose(Y[:, 1:] - Y[:, :1], (0, 2, 1))
    return Ds @ np.linalg.inv(Dm)


def unique_edges(tets):
    """The distinct edges (k, 2) of a tet mesh."""
    pairs = np.concatenate([tets[:, [a, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))])
    return np.unique(np.sort(pairs, axis=1), axis=0)


def face_mask(points, axis, value, tolerance=1e-9):
    """Bool mask of ``points`` on the plane ``coordinate[axis] == value``."""
    return np.abs(points[:, axis] - value) <= tolerance
