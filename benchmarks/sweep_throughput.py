"""Sweep throughput in runs per minute: ``softsim sweep`` on 1 and 2 local workers against a plain loop.

The runs: a clamped 0.5 x 0.1 x 0.1 m bar (structured, 5 tets per cell) sagging under gravity,
one run per Young's modulus, ``--runs`` of them, each ``--duration`` simulated seconds with
``dt: auto``.  The same runs are timed three ways, each ``--repeats`` times (median printed):

- ``loop``: ``prepare`` + ``simulate`` one after the other in this process, the loop a user
  would write, with Numba's default threads (every core) and with 1 thread;
- ``sweep, 1 worker``: ``run_sweep`` on a local cluster of 1 worker x all cores as Numba threads;
- ``sweep, 2 workers``: 2 workers x (cores / 2) Numba threads (on 2 cores: 1 thread each).

Cluster start-up (about 2-5 s) and JIT loading are excluded: each cluster first runs a warm-up
sweep; the start-up time is printed on its own.  Both clusters stay up and the modes take turns
in each round, so a busy machine slows them alike; the median and the best round are printed.  Files go to a temporary folder; results come
back through Dask as they would from a remote cluster.

    python benchmarks/sweep_throughput.py --runs 6 --repeats 3
"""

import argparse
import contextlib
import statistics
import tempfile
import time
from pathlib import Path

import numba

from softsim.sweep import expand_sweep, local_client, local_layout, parse_sweep, run_sweep
from softsim.kernels.compile_ahead import available_cores


def make_runs(run_count, element_size, duration, folder):
    base = {
        "mesh": {"shape": "box", "size": [0.5, 0.1, 0.1], "origin": [0.0, -0.05, -0.05],
                 "element_size": element_size, "structured": True},
        "material": {"model": "stvk", "youngs_modulus": 1e7, "poissons_ratio": 0.3, "density": 1000.0},
        "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
        "damping": 10.0,
        "time": {"duration": duration},
        "output": {"frame_interval": duration / 20},
    }
    moduli = [1e7 * (1.0 + 0.25 * i) for i in range(run_count)]
    sweep = parse_sweep({"base": base, "parameters": {"material.youngs_modulus": moduli}}, folder)
    return expand_sweep(sweep, folder)


def time_loop(runs):
    from softsim.simulation import prepare, simulate

    start = time.perf_counter()
    for run in runs:
        simulate(prepare(run.scene), run.path)
    return time.perf_counter() - start


def time_sweep(client, runs, folder, numba_threads):
    start = time.perf_counter()
    result = run_sweep(runs, folder, client, force=True, numba_threads=numba_threads)
    wall = time.perf_counter() - start
    assert not result.failed, result.failed[0]["status_reason"]
    return wall


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--element-size", type=float, default=0.025, help="[m]; 0.025: 1600 tets")
    parser.add_argument("--duration", type=float, default=0.1, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    cores = available_cores()
    default_threads = numba.get_num_threads()
    with tempfile.TemporaryDirectory(prefix="softsim-sweep-bench-") as tmp, contextlib.ExitStack() as stack:
        folder = Path(tmp)
        runs = make_runs(args.runs, args.element_size, args.duration, folder)
        from softsim.simulation import prepare

        prepared = prepare(runs[0].scene)
        print(f"{len(runs)} runs of {prepared.model.tet_count} tets, {prepared.plan.total_steps} steps each "
              f"(first run); {cores} cores; {args.repeats} rounds, the modes interleaved in each")
        time_loop(runs[:1])                                  # JIT load in this process
        modes = {}
        for threads in sorted({default_threads, 1}, reverse=True):
            modes[f"loop, {threads} Numba thread{'s' if threads > 1 else ''}"] = \
                lambda threads=threads: _with_threads(threads, time_loop, runs)
        for workers in (1, 2):
            workers, threads = local_layout(len(runs), workers, cores)
            start = time.perf_counter()
            client = stack.enter_context(local_client(workers, threads))
            startup = time.perf_counter() - start
            time_sweep(client, runs[:workers], folder, threads)          # warm-up: JIT load in the workers
            label = (f"sweep, {workers} worker{'s' if workers > 1 else ''} x {threads} Numba "
                     f"thread{'s' if threads > 1 else ''} (start-up {startup:.1f} s)")
            modes[label] = lambda client=client, threads=threads: time_sweep(client, runs, folder, threads)
        walls = {label: [] for label in modes}
        for _ in range(args.repeats):
            for label, measure in modes.items():
                walls[label].append(measure())
        for label, times in walls.items():
            median = statistics.median(times)
            print(f"{label:56s} median {60.0 * len(runs) / median:6.1f} runs/min, best {60.0 * len(runs) / min(times):6.1f}"
                  f"  (walls: {', '.join(f'{w:.2f}' for w in times)} s)")


def _with_threads(threads, function, *args):
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        return function(*args)
    finally:
        numba.set_num_threads(previous)


if __name__ == "__main__":
    main()
