"""Orchestration of one run: scene -> mesh -> model -> time loop -> HDF5.

``prepare`` does everything that can fail on bad input (meshing, checks, time plan) before any
file is written; ``simulate`` runs the prepared scene frame by frame.  Kernels do the numbers;
this module only decides what to call and in which order.
"""

import logging
import math
import time as _time
from dataclasses import dataclass

import numpy as np

from .config import scene_to_yaml
from .integrators.symplectic_euler import advance
from .integrators.timestep import dilatational_wave_speed, plan_time, stable_step_estimate
from .io.hdf5 import RunWriter, check_writable
from .kernels.energy import elastic_energy, gravity_energy, kinetic_energy
from .mesh import build_mesh
from .mesh.quality import altitudes
from .model import build_model, initial_state

log = logging.getLogger("softsim")


@dataclass(frozen=True)
class Prepared:
    """A scene ready to run: its mesh, model, time plan and stable-step estimate [s]."""

    scene: object
    model: object
    plan: object
    dt_estimate: float

    @property
    def mesh(self):
        return self.model.mesh


@dataclass(frozen=True)
class RunSummary:
    """What a finished run reports: steps, dt [s], wall time [s], tet-steps per second, output path."""

    steps: int
    dt: float
    wall_time_s: float
    tet_steps_per_s: float
    frames: int
    path: str


def stable_dt_estimate(scene, model):
    """Estimated largest stable symplectic-Euler step [s] of this mesh, material and contact."""
    material = scene.material
    c_p = dilatational_wave_speed(material.youngs_modulus, material.poissons_ratio, material.density)
    h_min = float(altitudes(model.rest_points, model.tets).min())
    if model.has_ground:
        return stable_step_estimate(h_min, c_p, model.contact_stiffness_bound, model.mass)
    return stable_step_estimate(h_min, c_p)


def prepare(scene):
    """Mesh the scene, build its model and time plan; raises ``SoftsimError`` on bad input."""
    mesh = build_mesh(scene.mesh)
    model = build_model(scene, mesh)
    dt_estimate = stable_dt_estimate(scene, model)
    dt = None if scene.time.dt == "auto" else float(scene.time.dt)
    if dt is not None and dt > dt_estimate:
        log.warning("time.dt = %.4g s is above the stable-step estimate %.4g s: the run may blow up "
                    "(dt: auto picks a stable step)", dt, dt_estimate)
    plan = plan_time(scene.time.duration, scene.output.frame_interval, dt=dt, dt_estimate=dt_estimate)
    return Prepared(scene=scene, model=model, plan=plan, dt_estimate=dt_estimate)


def frame_energy(model, state):
    """Kinetic, elastic and gravitational energy [J] of ``state``."""
    return {
        "kinetic": kinetic_energy(state.v, model.mass),
        "elastic": elastic_energy(state.x, model.tets, model.Dm_inv, model.rest_volume,
                                  model.material_id, model.lam, model.mu),
        "gravity": gravity_energy(state.x, model.mass, model.gravity),
    }


def step(model, state, dt, step_count, damping, corner_forces):
    """Advance ``state`` in place by ``step_count`` symplectic-Euler steps of ``dt`` [s]."""
    advance(state.x, state.v, state.step, step_count, dt,
            model.tets, model.Dm_inv, model.rest_volume, model.material_id, model.lam, model.mu,
            model.csr_offsets, model.csr_slots, corner_forces,
            model.inv_mass, model.external_accel,
            model.held, state.held_start, model.held_velocity,
            model.ground_arguments(), math.exp(-damping * dt) if damping > 0.0 else None)
    state.step += step_count


def simulate(prepared, output_path, progress=None):
    """Run a prepared scene, writing frames to ``output_path``; returns a ``RunSummary``.

    progress: optional callable ``progress(steps_done, total_steps)`` called after every frame.
    On an exception or Ctrl-C the file keeps its frames and gets status ``failed`` / ``interrupted``.
    """
    scene, model, plan = prepared.scene, prepared.model, prepared.plan
    check_writable(output_path)
    state = initial_state(scene, model)
    fields = scene.output.fields
    corner_forces = np.empty((model.tet_count, 4, 3))

    def write_frame(writer):
        energy = frame_energy(model, state) if "energy" in fields else None
        writer.append_frame(state.step * plan.dt, state.step, model.to_user_order(state.x),
                            model.to_user_order(state.v), energy)

    fixed = model.to_user_order(model.fixed)
    started = _time.perf_counter()
    with RunWriter(output_path, model.mesh.points, model.mesh.tets, fixed, scene_to_yaml(scene),
                   plan.dt, plan.total_steps, fields) as writer:
        write_frame(writer)
        for target in plan.frame_steps[1:]:
            step(model, state, plan.dt, target - state.step, scene.damping, corner_forces)
            write_frame(writer)
            if progress is not None:
                progress(state.step, plan.total_steps)
        frames = writer.frame_count
    wall = _time.perf_counter() - started
    return RunSummary(steps=plan.total_steps, dt=plan.dt, wall_time_s=wall,
                      tet_steps_per_s=model.tet_count * plan.total_steps / max(wall, 1e-12),
                      frames=frames, path=str(output_path))


def run(scene, output_path=None, progress=None):
    """Prepare and simulate ``scene``; ``output_path`` defaults to the scene's ``output.path``."""
    prepared = prepare(scene)
    return simulate(prepared, output_path or scene.output.path, progress)
