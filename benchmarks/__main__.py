"""softsim's benchmark suite, one command:

    python -m benchmarks [--quick] [-o benchmarks/results]

Measures, on this machine: throughput against tet count (10k to 2M) with the peers (Taichi and
Warp CPU, when ``pip install ".[peers]"`` is installed) and the STREAM-triad bandwidth bound
interleaved in one process; the cost per tet-step of every size, all sizes interleaved; 1 against
2 threads; each material model; each optional feature; the time outside the kernels at a frame
interval; peak memory per tet; start-up with a cold and a warm JIT cache; the Numba threading
layers; packed SIMD instructions in the compiled lane loops; what the software prefetches buy on
the large meshes.
Peers are first checked to compute the same positions.  The issue's targets are judged from the
run's rows (``benchmarks.targets``) and come first in ``results.md``.
Writes ``results.csv``, ``results.md`` and ``throughput.png`` into the output folder.
Numbers move with the machine and its load: compare only within one run.
"""

import argparse
import os
import platform
import sys
import time

import numba
from llvmlite import binding

from . import report, suite, targets


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small sizes, short timings: a smoke test (~2 min)")
    parser.add_argument("-o", "--output", default=os.path.join(os.path.dirname(__file__), "results"))
    parser.add_argument("--threads", type=int, default=2, help="softsim and Taichi threads (default 2)")
    parser.add_argument("--sizes", type=int, nargs="+", help="target tet counts of the throughput section")
    parser.add_argument("--repeats", type=int, help="interleaved rounds per measurement (default 7, quick 3)")
    parser.add_argument("--sections", nargs="+", help="run only these sections",
                        choices=["check", "throughput", "sizes", "threads", "models", "features", "overhead", "memory",
                                 "startup", "layers", "simd", "precision", "prefetch"])
    args = parser.parse_args(argv)

    quick = args.quick
    sizes = args.sizes or ([10_000, 30_000] if quick else [10_000, 30_000, 100_000, 300_000, 1_000_000, 2_000_000])
    repeats = args.repeats or (3 if quick else 7)
    seconds = 0.1 if quick else 0.4
    mid = 30_000 if quick else 100_000
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    threads = numba.get_num_threads()
    wanted = set(args.sections or [])

    def on(name):
        return not wanted or name in wanted

    started = time.perf_counter()
    rows = []
    from .stream import Stream
    stream = Stream(2_000_000 if quick else 20_000_000)
    sections = [
        ("check", lambda: suite.peer_check(10_000, threads)),
        ("throughput", lambda: suite.throughput(sizes, seconds, repeats, threads, stream)),
        ("sizes", lambda: suite.cost_against_size(sizes, seconds, repeats, threads)),
        ("threads", lambda: suite.thread_scaling([s for s in sizes if s >= mid] or sizes[-1:], seconds, repeats, threads)),
        ("models", lambda: suite.models(mid, seconds, repeats, threads)),
        ("features", lambda: suite.features(mid, seconds, repeats, threads)),
        # at the example scenes' frame interval (configs/: 4-20 ms; the cantilever's 10), and at a tenth of it
        ("overhead", lambda: suite.overhead(mid, 2 if quick else 10, threads, 0.01)
                             + suite.overhead(mid, 10 if quick else 50, threads, 0.001)),
        ("memory", lambda: suite.memory(100_000 if quick else 1_000_000, threads)),
        ("startup", lambda: suite.startup(10_000)),
        ("layers", lambda: suite.threading_layers(mid, seconds, 1 if quick else 3)),
        ("simd", suite.simd),
        ("precision", lambda: suite.precision(mid, 100_000 if quick else 1_000_000, seconds, repeats, threads)),
        ("prefetch", lambda: suite.prefetch([s for s in sizes if s >= 300_000] or sizes[-1:], seconds, repeats, threads)),
    ]
    for name, run in sections:
        if not on(name):
            continue
        suite.log(f"[{name}]")
        rows.extend(run())
    rows.append(targets.host_row("avx512" if "+avx512f" in binding.get_host_cpu_features().flatten() else "avx2"))
    judged = targets.targets(rows)
    suite.log(targets.summary(judged))
    rows = judged + rows
    machine = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba {numba.__version__} "
               f"({numba.threading_layer()} layer), {threads} threads")
    paths = report.write(rows, args.output, machine, quick, sections=args.sections)
    suite.log(f"done in {time.perf_counter() - started:.0f} s: " + ", ".join(paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
