"""Measurements that need a fresh process, printed as one JSON line (run by the suite):

    python -m benchmarks.probe memory TETS      peak RSS of preparing and stepping a beam, with a breakdown
    python -m benchmarks.probe startup TETS     seconds from process start to the first step done
    python -m benchmarks.probe layer TETS SECONDS   M tet-steps/s of the beam on this process's threading layer
"""

import json
import resource
import sys
import time

START = time.perf_counter()


def _rss_now():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def _peak_rss():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def memory(tets):
    import numpy as np

    from benchmarks.beam import Softsim, prepared_beam

    baseline = _rss_now()
    prepared = prepared_beam(tets)
    after_prepare = _peak_rss()
    sim = Softsim(prepared)
    sim.run(10)
    model = prepared.model
    arrays = {}
    for name, value in vars(model).items():
        if isinstance(value, np.ndarray):
            arrays[name] = value.nbytes
    for name in ("tets", "rest", "colour_offsets", "colour_parts"):
        arrays[f"blocks.{name}"] = getattr(model.blocks, name).nbytes
    arrays["state (x, v, held_start)"] = 3 * sim.state.x.nbytes
    arrays["work buffer"] = sim.work.nbytes
    mesh = model.mesh
    arrays["mesh (user order)"] = mesh.points.nbytes + mesh.tets.nbytes
    return dict(tets=model.tet_count, baseline_rss=baseline, peak_after_prepare=after_prepare,
                peak_rss=_peak_rss(), arrays=arrays)


def startup(tets):
    from benchmarks.beam import Softsim, prepared_beam

    imported = time.perf_counter() - START
    prepared = prepared_beam(tets)
    ready = time.perf_counter() - START
    sim = Softsim(prepared)
    sim.run(1)
    first_step = time.perf_counter() - START
    return dict(import_s=imported, prepare_s=ready - imported, first_step_s=first_step - ready, total_s=first_step)


def layer(tets, seconds):
    import numba

    from benchmarks.beam import Softsim, prepared_beam
    from benchmarks.timing import interleaved

    sim = Softsim(prepared_beam(tets))
    rates = interleaved({"softsim": sim}, seconds, 3)["softsim"]
    return dict(layer=numba.threading_layer(), threads=numba.get_num_threads(), rates=rates)


def main(argv):
    kind, *args = argv
    if kind == "memory":
        out = memory(int(args[0]))
    elif kind == "startup":
        out = startup(int(args[0]))
    elif kind == "layer":
        out = layer(int(args[0]), float(args[1]))
    else:
        raise SystemExit(f"unknown probe {kind!r}")
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
