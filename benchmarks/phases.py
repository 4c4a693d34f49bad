"""Where the step's time goes: the gather, the lane loop and the scatter of every block and the
vertex update, timed alone and added one after the other, against the whole step, on one thread.

    python -m benchmarks.phases [--model stvk] [--tets 100000] [--precision float64] [--rounds 9]

Each variant walks every block (or vertex) of the benchmark beam in order, as one thread of the
step does, on the step's own arrays (so their data come from where the step's come from: cache
or memory):

- ``gather``: the corners' positions into the block's scratch buffer (``gather_corners``);
- ``gather + lanes``: and the material law's lane loop over the block (``model_forces``);
- ``gather + lanes + scatter``: and the corner forces added into the vertices (``scatter_block``);
- ``scatter``: the scatter alone, of whatever the buffer holds;
- ``vertex update``: every part's vertices moved from their forces, as a step begins the part
  (``update_from_forces``, the parts' runs of vertices in order), alone; with ``dt = 0``, so that
  the positions stay where they are;
- ``gather + lanes + scatter + update``: the four together;
- ``step``: ``simulation.step``, which adds the prefetches and the schedule.

Nanoseconds per tet, medians over interleaved rounds (the variants alternate, so the machine's
drift hits all alike).  Differences between the cumulative rows are what each phase adds.
"""

import argparse
import statistics

import numba
import numpy as np

from softsim.integrators.symplectic_euler import update_from_forces
from softsim.kernels.blocked import BLOCK, ROWS, gather_corners, model_forces, scatter_block
from softsim.kernels.polar3 import NEWTON_FIRST_STEPS
from softsim.kernels.simd import FORCE_COLUMNS

from .beam import Softsim, prepared_beam
from .timing import interleaved


@numba.njit
def gather_all(x, block_tets, whole_rows, buf, repeats):
    for _ in range(repeats):
        for b in range(block_tets.shape[0]):
            gather_corners(x, block_tets, b, buf, whole_rows[b])


@numba.njit
def gather_and_lanes(x, block_tets, whole_rows, block_rest, model, lam, mu, rest, first_steps, buf, repeats):
    for _ in range(repeats):
        for b in range(block_tets.shape[0]):
            gather_corners(x, block_tets, b, buf, whole_rows[b])
            first_steps[b] = model_forces(block_rest[b], buf, model, lam, mu, rest, None, first_steps[b])


@numba.njit
def gather_lanes_and_scatter(x, block_tets, whole_rows, block_rest, model, lam, mu, rest, first_steps, buf,
                             vertex_forces, repeats):
    for _ in range(repeats):
        for b in range(block_tets.shape[0]):
            gather_corners(x, block_tets, b, buf, whole_rows[b])
            first_steps[b] = model_forces(block_rest[b], buf, model, lam, mu, rest, None, first_steps[b])
            scatter_block(block_tets, b, BLOCK, buf, vertex_forces)


@numba.njit
def update_all(x, rest, v, vertex_forces, owned_runs, inv_mass, gravity, held, held_start, held_velocity, repeats):
    """The vertex update of every part's runs of vertices in order, ``dt = 0``."""
    dt = x.dtype.type(0.0)
    for _ in range(repeats):
        for r in range(owned_runs.shape[0]):
            for i in range(owned_runs[r, 0], owned_runs[r, 1]):
                update_from_forces(x, rest, v, vertex_forces, i, dt, 0.0, inv_mass, gravity, None, held, held_start,
                                   held_velocity, None, None)


@numba.njit
def scatter_all(block_tets, buf, vertex_forces, repeats):
    for _ in range(repeats):
        for b in range(block_tets.shape[0]):
            scatter_block(block_tets, b, BLOCK, buf, vertex_forces)


def phase_times(model="stvk", tets=100_000, precision="float64", rounds=9, seconds=0.2):
    """``{variant: ns per tet}`` (medians over ``rounds`` interleaved rounds of about ``seconds``
    each, ``timing.interleaved``) of the beam of about ``tets`` tets."""
    numba.set_num_threads(1)
    runner = Softsim(prepared_beam(tets, model, precision=precision))
    m, layout = runner.model, runner.model.blocks
    if precision == "float32":
        work = runner.work
        work.load(runner.state, m.rest_points)
        x, rest, v, held_start = work.u, work.rest, work.v, work.held_start
        inv_mass, gravity, held_velocity = work.inv_mass, work.gravity, work.held_velocity
    else:
        x, rest, v, held_start = runner.state.x, None, runner.state.v, runner.state.held_start
        inv_mass, gravity, held_velocity = m.inv_mass, tuple(float(g) for g in m.gravity), m.held_velocity
    dtype = x.dtype.type
    lam, mu = dtype(m.lam), dtype(m.mu)
    buf = np.zeros(ROWS * BLOCK, x.dtype)
    vertex_forces = np.zeros((m.node_count, FORCE_COLUMNS), x.dtype)
    first_steps = np.full(layout.tets.shape[0], NEWTON_FIRST_STEPS, np.uint8)   # as step_arguments
    common = (x, layout.tets, layout.whole_rows)
    vertex_update = (x, rest, v, vertex_forces, layout.owned_runs, inv_mass, gravity, m.held, held_start, held_velocity)
    law = (layout.rest, m.material_id, lam, mu, rest, first_steps, buf)
    passes = {
        "gather": lambda r: gather_all(*common, buf, r),
        "gather + lanes": lambda r: gather_and_lanes(*common, *law, r),
        "gather + lanes + scatter": lambda r: gather_lanes_and_scatter(*common, *law, vertex_forces, r),
        "scatter": lambda r: scatter_all(layout.tets, buf, vertex_forces, r),
        "vertex update": lambda r: update_all(*vertex_update, r),
        "gather + lanes + scatter + update": lambda r: (
            gather_lanes_and_scatter(*common, *law, vertex_forces, r), update_all(*vertex_update, r)),
        "step": runner.run,
    }
    runners = {name: _Passes(run, m.tet_count) for name, run in passes.items()}
    rates = interleaved(runners, seconds, rounds)          # M tet-steps/s
    return {name: 1e3 / statistics.median(r) for name, r in rates.items()}


class _Passes:
    """A runner for ``timing.interleaved``: ``run(steps)`` makes ``steps`` passes over the mesh."""

    def __init__(self, run, tet_count):
        self.run = run
        self.tet_count = tet_count


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="stvk")
    parser.add_argument("--tets", type=int, default=100_000)
    parser.add_argument("--precision", default="float64", choices=("float64", "float32"))
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args()
    times = phase_times(args.model, args.tets, args.precision, args.rounds)
    width = max(len(name) for name in times)
    for name, ns in times.items():
        print(f"{name:{width}s} {ns:6.2f} ns per tet")


if __name__ == "__main__":
    main()
