"""The scene of the performance issue and a softsim runner for it.

A 1 x 0.25 x 0.25 m box beam cut into 5 tets per hex cell (``mesh.structured: true``), pinned at
x = 0, under gravity, symplectic Euler, float64.  The peers (``peers.py``) get the same mesh, rest
state, masses, held vertices and dt from the ``Model`` softsim builds, so all of them step the same
system and must reach the same positions.
"""

import dataclasses

import numba
import numpy as np

from softsim.config import parse_scene
from softsim.integrators.symplectic_euler import work_buffer
from softsim.kernels.blocked import build_block_layout
from softsim.model import initial_state
from softsim.simulation import prefetch_trial_running, prepare, step, step_calls

YOUNGS_MODULUS = 1e8
POISSONS_RATIO = 0.3
DENSITY = 1000.0


def beam_scene(target_tets, model="stvk", **extra):
    """Validated scene of the benchmark beam with about ``target_tets`` tets; ``extra`` adds keys."""
    element_size = (1.0 * 0.25 * 0.25 * 5.0 / target_tets) ** (1.0 / 3.0)
    scene = {
        "mesh": {"shape": "box", "size": [1.0, 0.25, 0.25], "element_size": element_size, "structured": True},
        "material": {"model": model, "youngs_modulus": YOUNGS_MODULUS, "poissons_ratio": POISSONS_RATIO,
                     "density": DENSITY},
        "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
        "time": {"duration": 1.0},
    }
    scene.update(extra)
    return parse_scene(scene)


class Softsim:
    """softsim's step loop on a prepared scene; ``run(steps)`` advances the state in place."""

    name = "softsim"

    def __init__(self, prepared, scatter=None):
        self.prepared = prepared
        model = prepared.model
        if scatter is not None and scatter != model.blocks.scatter:
            model = dataclasses.replace(model, blocks=build_block_layout(
                model.tets, model.Dm_inv, model.rest_volume, model.node_count, scatter,
                dtype=model.blocks.rest.dtype, model=model.material_id))
        self.model = model
        self.scatter = model.blocks.scatter
        self.dt = prepared.plan.dt
        self.damping = prepared.scene.damping
        self.state = initial_state(prepared.scene, model)
        self.work = work_buffer(model)

    @property
    def tet_count(self):
        return self.model.tet_count

    def run(self, steps):
        step(self.model, self.state, self.dt, steps, self.damping, self.work)

    def step_calls(self):
        """The compiled step's calls ``run`` makes (``simulation.step_calls``), to compile them ahead
        (``timing.compile_steps_ahead``)."""
        return step_calls(self.prepared.scene, self.model, self.state)

    def settle(self, steps):
        """Where the step measures whether to prefetch (``BlockLayout.measure_prefetch``), end its
        trial on the threads Numba is set to with calls of ``steps`` steps (``PrefetchChoice``: the
        calibration's calls began it), so that the timed rounds run the way a long run keeps.
        Inside the rounds, half of the trial's calls ran the slower way: on the 2M beam the median
        of 7 rounds came out at 136-143 M tet-steps/s, the faster way running 154-160."""
        while prefetch_trial_running(self.model, numba.get_num_threads()):
            self.run(steps)

    def positions(self):
        """Positions [m] (n, 3) in softsim's internal vertex order."""
        return self.state.x.copy()


def prepared_beam(target_tets, model="stvk", **extra):
    return prepare(beam_scene(target_tets, model, **extra))


def system_arrays(prepared):
    """The arrays a peer needs, float64 / int32, in softsim's internal order (held: any axis held)."""
    m = prepared.model
    state = initial_state(prepared.scene, m)
    return dict(
        x=np.ascontiguousarray(state.x), v=np.ascontiguousarray(state.v),
        tets=np.ascontiguousarray(m.tets.astype(np.int32)), Dm_inv=np.ascontiguousarray(m.Dm_inv),
        rest_volume=np.ascontiguousarray(m.rest_volume), inv_mass=np.ascontiguousarray(m.inv_mass),
        held=np.ascontiguousarray(m.held.any(axis=1).astype(np.int32)), gravity=np.asarray(m.gravity, dtype=np.float64),
        lam=float(m.lam), mu=float(m.mu), dt=float(prepared.plan.dt),
    )


def threads():
    return numba.get_num_threads()
