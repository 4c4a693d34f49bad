"""Elastic step throughput in million tet-steps per second (tets x steps / wall seconds).

The scene of the performance issue: a 1 x 0.25 x 0.25 m box beam cut into 5 tets per hex cell,
float64, pinned at x = 0, gravity, symplectic Euler.  JIT compilation is excluded (one warm-up
call first); each size is timed ``--repeats`` times and the median is reported.

    python benchmarks/throughput.py --tets 10000 100000 --model stvk --repeats 5
"""

import argparse
import statistics
import time

import numba
import numpy as np

from softsim.config import parse_scene
from softsim.simulation import prepare, step


def beam_scene(target_tets, model):
    """Scene dict of the benchmark beam with about ``target_tets`` tets (5 per cell)."""
    element_size = (1.0 * 0.25 * 0.25 * 5.0 / target_tets) ** (1.0 / 3.0)
    return parse_scene({
        "mesh": {"shape": "box", "size": [1.0, 0.25, 0.25], "element_size": element_size, "structured": True},
        "material": {"model": model, "youngs_modulus": 1e8, "poissons_ratio": 0.3, "density": 1000.0},
        "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
        "time": {"duration": 1.0},
    })


def throughput(target_tets, model, steps, repeats):
    """(tet_count, [M tet-steps/s per repeat]) for the beam of about ``target_tets`` tets."""
    prepared = prepare(beam_scene(target_tets, model))
    model_ = prepared.model
    from softsim.model import initial_state

    state = initial_state(prepared.scene, model_)
    buffer = np.empty((model_.tet_count, 4, 3))
    step(model_, state, prepared.plan.dt, 1, 0.0, buffer)       # compile / load from cache
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        step(model_, state, prepared.plan.dt, steps, 0.0, buffer)
        wall = time.perf_counter() - start
        rates.append(model_.tet_count * steps / wall / 1e6)
    return model_.tet_count, rates


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tets", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--model", default="stvk", choices=["linear", "stvk", "corotated", "neohookean"])
    parser.add_argument("--tet-steps", type=float, default=2e7, help="work per timed repeat (tets x steps)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"threads: {numba.get_num_threads()}, model: {args.model}")
    for target in args.tets:
        steps = max(1, int(args.tet_steps / target))
        tets, rates = throughput(target, args.model, steps, args.repeats)
        print(f"{tets:>9} tets x {steps:>5} steps: median {statistics.median(rates):6.2f} M tet-steps/s "
              f"(min {min(rates):.2f}, max {max(rates):.2f}, {args.repeats} repeats)")
    print(f"threading layer: {numba.threading_layer()}")


if __name__ == "__main__":
    main()
