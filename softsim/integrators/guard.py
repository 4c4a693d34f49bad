"""Once-per-frame checks of a running simulation: the stable step on the deformed mesh, and a
blow-up guard that stops a run before anything non-finite or meaningless is written.

Explicit time stepping is only conditionally stable.  Every frame:

1. the stable step of the *deformed* state: softsim's kernels are total-Lagrangian (rest-state
   gradients, rest masses), so deformation changes the stable step only through the material's
   tangent stiffness (neohookean and stvk stiffen where they stretch; a squashed corotated element
   does not need a smaller step).  Whenever any element's J or stretch has moved by more than
   ``RECHECK_CHANGE`` since the last look (more where that look left a margin), the largest
   eigenvalue of ``M^-1 K`` is recomputed at the current state (``stability.exact_stable_step``);
   the run sub-steps, or stops under ``dt_policy: refuse``;
2. positions and velocities must be finite;
3. the mechanical energy (kinetic + elastic) must stay below ``ENERGY_GUARD_FACTOR`` times what
   could have been put in: its initial value, the energy of the ground's springs where the body
   starts in the ground (``ground_spring_energy``), the work of gravity, of the tractions and of
   the prescribed motion of held vertices;
4. models that cannot handle inversion (``linear``, ``stvk``) must see no element with J <= 0.

A failed check raises ``SimulationError`` naming the simulated time, the step and the element or
vertex (in the user's numbering) where the trouble is.
"""

import math

import numpy as np

from ..errors import SimulationError
from ..kernels import compile_ahead
from ..kernels.element_checks import all_finite, block_volume_ratios_and_stretches, element_volume_ratios_and_stretches
from ..kernels.energy import elastic_energy, gravity_energy, kinetic_energy
from ..kernels.forces import elastic_forces
from ..kernels.jit import CompileTimeConstant
from ..materials.models import INVERSION_SAFE, MODEL_IDS
from .stability import exact_stable_step

ENERGY_GUARD_FACTOR = 10.0
# Within a frame, the stable step is re-checked at least every this many planned steps (one pass
# over the tets, a few percent of the stepping work), so a fast collapse inside a long frame is seen.
RECHECK_STEPS = 32
# Relative change of any element's J or stretch that triggers a new eigenvalue estimate, while
# the step is at the sub-steps' limit, EIGEN_SAFETY x 2 / omega_max (and before the first look).
# A tangent stiffness growing at most as the fourth power of the stretch (neo-Hookean's volume
# term; StVK's grows as the square) then lets the limit fall by at most (1 + RECHECK_CHANGE)^-2
# unseen: the step may reach 0.8 x 1.05^2 = 0.88 of the limit.  Where the last look left a margin
# m = EIGEN_SAFETY x limit / step > 1, the guard keeps that same worst case and looks again only
# after a change of (1 + RECHECK_CHANGE) sqrt(m) - 1, at most RECHECK_CHANGE_MAX (``FrameGuard.
# recheck_change``).  dt: auto leaves m >= 1.17 at rest (1.33 where it took the eigenvalue
# limit): a change of 14-25 %.  A bouncing rubber cube (12.6k tets, 1.5 s) looked 119 times at a
# fixed 5 %, 8 times with the margin: the looks had cost a third of its run.
RECHECK_CHANGE = 0.05
RECHECK_CHANGE_MAX = 0.25
# Sub-steps are sized to this fraction of the eigenvalue limit 2 / omega_max.
EIGEN_SAFETY = 0.8
# A frame may be split into at most this many sub-steps per step before the run is stopped.
MAX_SUBSTEPS = 1000
_INVERSION_SAFE_IDS = tuple(MODEL_IDS[name] for name in INVERSION_SAFE)
_MODEL_NAMES = {v: k for k, v in MODEL_IDS.items()}


def ground_spring_energy(model, x):
    """Energy [J] held in the ground's penalty springs at positions ``x`` (n, 3) [m]:
    ``sum_i 1/2 k A_i d_i^2`` over the vertices whose z is free, ``d_i`` their depth below the
    ground where positive, ``A_i`` their share of the boundary area facing down, as the step
    computes it (``symplectic_euler.part_face_areas``: a third of each face's area vector's z,
    summed, where negative), k the ground's stiffness [Pa/m].  The step's contact force on a
    vertex is ``k d_i A_i``.  0 without a ground."""
    if not model.has_ground:
        return 0.0
    faces = model.boundary_faces
    p = x[faces]
    u, w = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area_z = np.zeros(x.shape[0])
    np.add.at(area_z, faces.ravel(), np.repeat((u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]) / 6.0, 3))
    depth = np.where(model.held[:, 2], 0.0, np.maximum(model.ground_height - x[:, 2], 0.0))
    return float(0.5 * model.ground_stiffness * (np.maximum(-area_z, 0.0) * depth ** 2).sum())


def recheck_change(margin):
    """Relative change of J or stretch after which the guard looks at the stable step again, after a
    look that left the step ``margin`` = EIGEN_SAFETY x limit / step (>= 1) below its sub-step limit
    (see ``RECHECK_CHANGE``)."""
    return min(RECHECK_CHANGE_MAX, max(RECHECK_CHANGE, (1.0 + RECHECK_CHANGE) * math.sqrt(margin) - 1.0))


def element_measure_call(model, x, J, stretch, J_seen, stretch_seen, limit):
    """The kernel that measures the volume ratio J and the stretch of every tet of ``model`` at
    positions ``x`` (n, 3) [m] into ``J`` and ``stretch`` (m,), and whether any moved by more than
    ``limit`` (relative) from ``J_seen`` and ``stretch_seen`` (m,), with its arguments: ``(kernel,
    arguments)``.  In the vectorised blocks of the step where their rest data is float64
    (``block_volume_ratios_and_stretches``), else tet by tet."""
    if model.blocks.rest.dtype == np.float64:
        blocks = model.blocks
        return block_volume_ratios_and_stretches, (x, blocks.tets, blocks.rest, CompileTimeConstant(blocks.triangular),
                                                   model.tet_count, blocks.whole_rows,
                                                   J, stretch, J_seen, stretch_seen, limit,
                                                   blocks.points_for_rest(model.rest_points))
    return element_volume_ratios_and_stretches, (x, model.tets, model.Dm_inv, J, stretch, J_seen, stretch_seen, limit)


class FrameGuard:
    """Checks a model's state once per frame (``check``) and tracks the energy put in.

    model: ``softsim.model.Model``; wave_speed: dilatational wave speed [m/s]; dt: the planned step [s];
    policy: ``substep`` | ``refuse`` | ``allow``; state0: the initial ``State``.
    """

    def __init__(self, model, wave_speed, dt, policy, state0):
        self.model = model
        self.wave_speed = wave_speed
        self.dt = dt
        self.policy = policy
        self.J = np.empty(model.tet_count)
        self.stretch = np.empty(model.tet_count)
        self.J_seen = np.ones(model.tet_count)          # J and stretch at the last eigenvalue look
        self.stretch_seen = np.ones(model.tet_count)
        self.substeps = 1
        self.recheck_change = RECHECK_CHANGE    # set by each eigenvalue look from its margin (``_substeps``)
        self.x0 = state0.x.copy()
        self.gravity0 = gravity_energy(state0.x, model.mass, model.gravity)
        # a body that starts in the ground is pushed out by its compressed springs: their energy too
        self.mechanical0 = (kinetic_energy(state0.v, model.mass) + self._elastic(state0.x)
                            + ground_spring_energy(model, state0.x))
        self.moving_held = np.flatnonzero((model.held & (model.held_velocity != 0.0)).any(axis=1))
        self.held_work = 0.0
        self.held_power = self._held_power(state0) if self.moving_held.size else 0.0
        # the energy scale of the material: below it, "growth" is round-off
        self.energy_floor = 1e-9 * model.mass.sum() * wave_speed ** 2

    def _elastic(self, x):
        m = self.model
        return elastic_energy(x, m.tets, m.Dm_inv, m.rest_volume, m.material_id, m.lam, m.mu)

    def _where(self, time, step):
        return f"at t = {time:.6g} s (step {step})"

    def _user_tet(self, e):
        return int(self.model.tet_order[e])

    def _user_vertex(self, i):
        return int(self.model.vertex_order[i])

    def _held_power(self, state):
        """Power [W] the prescribed motion of held vertices puts into the body: -sum f_i . v_i."""
        m = self.model
        f = elastic_forces(state.x, m.tets, m.Dm_inv, m.rest_volume, m.material_id, m.lam, m.mu,
                           m.csr_offsets, m.csr_slots)[self.moving_held]
        return -float((f * m.held_velocity[self.moving_held]).sum())

    def record_held_work(self, state, frame_time):
        """Add the work [J] of the moving held vertices over the last ``frame_time`` [s] (trapezoid rule).

        Signed, so that the wildly alternating forces of a blow-up do not inflate the budget.
        """
        if self.moving_held.size == 0:
            return
        power = self._held_power(state)
        self.held_work += 0.5 * (self.held_power + power) * frame_time
        self.held_power = power

    def check(self, state, time, energy):
        """Check a frame's ``state`` at ``time`` [s]; return the sub-steps per step for the next frame.

        energy: the state's kinetic, elastic and gravitational energy [J] (``{"kinetic": ...,
        "elastic": ..., "gravity": ...}``, ``simulation.frame_energy``), which the frame also writes.
        Raises ``SimulationError`` if the state is non-finite, blown up, inverted where the model
        cannot handle it, or (under ``refuse``) needs a smaller step than the one in use.
        """
        m = self.model
        where = self._where(time, state.step)
        self._check_finite(state, where)
        moved = self._measure_elements(state.x)
        if m.material_id not in _INVERSION_SAFE_IDS:
            e = int(np.argmin(self.J))
            if self.J[e] <= 0.0:
                raise SimulationError(
                    f"element {self._user_tet(e)} inverted (J = {self.J[e]:.3g}) {where}; the "
                    f"{_MODEL_NAMES[m.material_id]} model cannot recover from inversion: use neohookean or corotated")
        mechanical = energy["kinetic"] + energy["elastic"]
        gravity_in = self.gravity0 - energy["gravity"]
        traction_in = float((m.traction_force * (state.x - self.x0)).sum())
        budget = self.mechanical0 + max(gravity_in, 0.0) + max(traction_in, 0.0) + max(self.held_work, 0.0)
        if mechanical > ENERGY_GUARD_FACTOR * budget + self.energy_floor:
            speed = np.linalg.norm(state.v, axis=1)
            i = int(np.argmax(speed))
            raise SimulationError(
                f"the simulation blew up {where}: energy {mechanical:.3g} J is over {ENERGY_GUARD_FACTOR:g}x the "
                f"{budget:.3g} J put in (fastest vertex {self._user_vertex(i)}); "
                f"try a smaller time.dt (this run used {self.dt:.3g} s)")
        return self._substeps(state, time, moved)

    # The names of ``snapshot``'s entries (a run file's resume state holds them).
    SNAPSHOT_NAMES = ("guard_J_seen", "guard_stretch_seen", "guard_substeps", "guard_recheck_change",
                      "guard_held_work", "guard_held_power")

    def snapshot(self):
        """What a resumed run needs to take the same decisions: dict of arrays and numbers."""
        return {"guard_J_seen": self.J_seen.copy(), "guard_stretch_seen": self.stretch_seen.copy(),
                "guard_substeps": int(self.substeps), "guard_recheck_change": float(self.recheck_change),
                "guard_held_work": float(self.held_work), "guard_held_power": float(self.held_power)}

    def restore(self, snapshot):
        """Take back a ``snapshot`` stored with the frame a run resumes from."""
        self.J_seen[:] = snapshot["guard_J_seen"]
        self.stretch_seen[:] = snapshot["guard_stretch_seen"]
        self.substeps = int(snapshot["guard_substeps"])
        self.recheck_change = float(snapshot["guard_recheck_change"])
        self.held_work = float(snapshot["guard_held_work"])
        self.held_power = float(snapshot["guard_held_power"])

    def _check_finite(self, state, where):
        if all_finite(state.x, state.v):
            return
        bad = ~(np.isfinite(state.x).all(axis=1) & np.isfinite(state.v).all(axis=1))
        if bad.any():
            i = int(np.argmax(bad))
            raise SimulationError(f"the simulation blew up {where}: vertex {self._user_vertex(i)} is not finite; "
                                  f"try a smaller time.dt (this run used {self.dt:.3g} s)")

    def recheck_step(self, state, time):
        """Sub-steps per planned step, looking only at the deformation (between frames)."""
        if self.policy == "allow":
            return 1
        self._check_finite(state, self._where(time, state.step))
        return self._substeps(state, time, self._measure_elements(state.x))

    def _measure_elements(self, x):
        """``self.J`` and ``self.stretch`` of every tet at positions ``x`` (``element_measure_call``).
        Returns whether any tet moved by more than ``recheck_change`` since the last eigenvalue look
        (NaN counts as moved)."""
        kernel, arguments = element_measure_call(self.model, x, self.J, self.stretch, self.J_seen, self.stretch_seen,
                                                 self.recheck_change)
        compile_ahead.wait(kernel)
        return kernel(*arguments)

    def _substeps(self, state, time, moved):
        """Sub-steps per planned step at the state whose J and stretch ``self`` holds; ``moved``: whether
        they moved enough to look at the stable step again (``_measure_elements``)."""
        if self.policy == "allow":
            return 1
        if not moved:
            return self.substeps
        self.J_seen[:] = self.J
        self.stretch_seen[:] = self.stretch
        # Forward differences (one force evaluation an application) where no element is inverted:
        # corotated's forces jump at an exact reflection, where a difference of forces measures the
        # jump, not the stiffness, and the two forms then disagree (the mirrored cube: 9.7e-7 against
        # 1.7e-6 s); there the guard keeps the central form it always took.
        differences = "forward" if self.J.min(initial=1.0) > 0.0 else "central"
        safe = EIGEN_SAFETY * exact_stable_step(self.model, state.x, iterations=80, tol=1e-2, differences=differences)
        where = self._where(time, state.step)
        if not safe > 0.0:
            raise SimulationError(f"the simulation blew up {where}: its elastic forces are no longer finite; "
                                  f"try a smaller time.dt (this run used {self.dt:.3g} s)")
        if self.dt <= safe * (1.0 + 1e-9):
            self.substeps = 1
        elif self.policy == "refuse":
            raise SimulationError(f"the safe step ({EIGEN_SAFETY:g} x the stability limit) fell to {safe:.3g} s, "
                                  f"below dt = {self.dt:.3g} s, {where} (dt_policy: refuse)")
        else:
            self.substeps = math.ceil(self.dt / safe - 1e-9)
            if self.substeps > MAX_SUBSTEPS:
                e = int(np.argmax(self.stretch))
                raise SimulationError(
                    f"the safe step ({EIGEN_SAFETY:g} x the stability limit) fell to {safe:.3g} s {where} "
                    f"(most stretched element {self._user_tet(e)}, "
                    f"J = {self.J[e]:.3g}): more than {MAX_SUBSTEPS} sub-steps per step")
        self.recheck_change = recheck_change(safe / (self.dt / self.substeps))
        return self.substeps
