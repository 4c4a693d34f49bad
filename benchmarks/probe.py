"""Measurements that need a fresh process, printed as one JSON line (run by the suite):

    python -m benchmarks.probe memory TETS      peak RSS of preparing and stepping a beam, with a breakdown
    python -m benchmarks.probe startup TETS     seconds from process start to the first step done
    python -m benchmarks.probe layer TETS SECONDS   M tet-steps/s of the beam on this process's threading layer
    python -m benchmarks.probe asm              floating-point arithmetic instructions of each lane loop (float64, float32),
                                                by vector width (run with an empty NUMBA_CACHE_DIR: Numba
                                                shows no machine code for cached functions)
"""

import dataclasses
import json
import resource
import sys
import time

START = time.perf_counter()


def _rss_now():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def _peak_rss():
    """This process's peak resident memory [bytes]: ``VmHWM`` (getrusage's ru_maxrss survives
    exec, so a child of a large process would report its parent's size)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
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
    block_arrays = [f.name for f in dataclasses.fields(model.blocks)
                    if isinstance(getattr(model.blocks, f.name), np.ndarray)]
    for name in block_arrays:
        arrays[f"blocks.{name}"] = getattr(model.blocks, name).nbytes
    arrays["state (x, v, held_start)"] = 3 * sim.state.x.nbytes
    arrays["work buffer"] = sim.work.nbytes
    mesh = model.mesh
    arrays["mesh (user order)"] = mesh.points.nbytes + mesh.tets.nbytes
    # What one step reads or writes: the block layout, the scatter's arrays, the state, the
    # per-vertex constants (the external accelerations only with tractions, the ground's faces
    # only with a ground).
    touched = [f"blocks.{name}" for name in block_arrays]
    touched += ["state (x, v, held_start)", "work buffer", "inv_mass", "held", "held_velocity"]
    if model.has_tractions:
        touched += ["external_accel"]
    if model.blocks.scatter == "csr":
        touched += ["csr_offsets", "csr_slots"]
    if model.has_ground:
        touched += ["part_face_offsets", "part_faces"]
    return dict(tets=model.tet_count, baseline_rss=baseline, peak_after_prepare=after_prepare,
                peak_rss=_peak_rss(), arrays=arrays, step_arrays=sum(arrays[name] for name in touched),
                step_array_names=touched)


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


def asm():
    import re

    import numpy as np

    from softsim.kernels import blocked
    from softsim.materials.models import MODEL_IDS

    loops = [(name, f"{name}_block", np.float64) for name in ("linear", "stvk", "corotated", "neohookean")]
    loops += [(f"{name} float32", f"{name}_displacement_block", np.float32) for name in ("linear", "stvk", "neohookean")]
    out = {}
    for name, function, dtype in loops:
        buf = np.zeros(blocked.ROWS * blocked.BLOCK, dtype=dtype)
        lanes = blocked.lanes_per_group(dtype)
        rows = blocked.rest_rows(blocked.uses_triangular_rest(MODEL_IDS[name.split()[0]], dtype))
        rest = np.full((blocked.BLOCK // lanes, rows, lanes), 0.1, dtype=dtype)
        fn = getattr(blocked, function)
        args = (rest, buf, dtype(1.0), dtype(1.0), rest)
        if function == "corotated_block":
            # the first steps as the step passes them, an int: left out, Numba compiles for the
            # default alone (the four-step loop, without the two- and three-step ones)
            args += (blocked.NEWTON_FIRST_STEPS,)
        fn(*args)
        code = "\n".join(fn.inspect_asm().values())
        counts = {}
        for m in re.finditer(r"^\s+(v(?:fn?m(?:add|sub)\w*|mul|add|sub|div|sqrt)\d*(?:pd|sd|ps|ss))\s+([^\n]*)", code, re.M):
            op, operands = m.group(1), m.group(2)
            width = "zmm" if "zmm" in operands else "ymm" if "ymm" in operands else "xmm"
            kind = "scalar" if op.endswith(("sd", "ss")) else f"packed {width}"
            key = f"{'fma' if 'fm' in op else 'arith'} {kind}"
            counts[key] = counts.get(key, 0) + 1
        out[name] = counts
    out.update(memory_moves())
    return out


def memory_moves():
    """The store instructions in the compiled gather and scatter of a block (``kernels.simd``), by
    register width: the hand-written IR stores vectors (the gather a row of lanes at a time, the
    scatter a vertex's forces at a time), where plain loops store every value on its own."""
    import re

    import numpy as np

    from softsim.kernels import blocked
    from softsim.kernels.simd import FORCE_COLUMNS

    out = {}
    for dtype in (np.float64, np.float32):
        x = np.zeros((10, 3), dtype=dtype)
        tets = np.zeros((1, 4, blocked.BLOCK), dtype=np.uint32)
        buf = np.zeros(blocked.ROWS * blocked.BLOCK, dtype=dtype)
        forces = np.zeros((10, FORCE_COLUMNS), dtype=dtype)
        blocked.gather_corners(x, tets, 0, buf)
        blocked.scatter_block(tets, 0, blocked.BLOCK, buf, forces)
        for name, fn in (("gather", blocked.gather_corners), ("scatter", blocked.scatter_block)):
            signature = next(sig for sig in fn.signatures if np.dtype(dtype).name in str(sig))
            code = fn.inspect_asm(signature).split("_ZN7cpython")[0]     # not the Python wrapper
            counts = {}
            for m in re.finditer(r"^\s+(v?mov\w*)\s+%([xyz]mm\d+), [^\n]*\(", code, re.M):   # float stores
                register = m.group(2)
                kind = "store " + (register[:3] if register[:3] in ("zmm", "ymm") else
                                   "xmm" if m.group(1) in ("vmovups", "vmovaps", "vmovupd", "vmovapd") else "scalar")
                counts[kind] = counts.get(kind, 0) + 1
            out[f"{name} {np.dtype(dtype).name}"] = counts
    return out


def main(argv):
    kind, *args = argv
    if kind == "memory":
        out = memory(int(args[0]))
    elif kind == "startup":
        out = startup(int(args[0]))
    elif kind == "asm":
        out = asm()
    elif kind == "layer":
        out = layer(int(args[0]), float(args[1]))
    else:
        raise SystemExit(f"unknown probe {kind!r}")
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
