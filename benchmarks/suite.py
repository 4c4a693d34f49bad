"""The sections of ``python -m benchmarks``; each returns rows (dicts) for the results table.

Every rate is the median over rounds of interleaved timings (``timing.interleaved``), in million
tet-steps per second (tets x steps / wall seconds, JIT compilation excluded); ratios are medians of
per-round ratios.  Row keys: section, case, tets, runner, threads, rate (M tet-steps/s), ratio,
ratio_to (what the ratio divides by), note.
"""

import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np

from softsim.integrators.guard import RECHECK_STEPS

from . import peers
from .beam import Softsim, prepared_beam, system_arrays
from .stream import BYTES_PER_TET_STEP, Stream
from .timing import interleaved, median_ratio

MODELS = ("linear", "stvk", "corotated", "neohookean")
CHECK_STEPS = 1000
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def row(section, case, tets=None, runner="softsim", threads=None, rate=None, ratio=None, ratio_to="", note=""):
    return dict(section=section, case=case, tets=tets, runner=runner, threads=threads,
                rate=None if rate is None else round(rate, 2), ratio=None if ratio is None else float(f"{ratio:.4g}"),
                ratio_to=ratio_to, note=note)


def log(text):
    print(text, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------


def peer_check(tets, threads):
    """Rows: max |x_peer - x_softsim| [m] after ``CHECK_STEPS`` steps, relative to the displacement."""
    prepared = prepared_beam(tets)
    sim = Softsim(prepared)
    arrays = system_arrays(prepared)
    sim.run(CHECK_STEPS)
    reference = sim.positions()
    displacement = float(np.abs(reference - prepared.model.rest_points).max())
    rows = []
    for name, reason in peers.available().items():
        if reason is not None:
            rows.append(row("check", "same answer", sim.tet_count, name, note=f"skipped: {reason}"))
            continue
        peer = peers.Taichi(arrays, threads) if name == "taichi" else peers.Warp(arrays)
        peer.run(CHECK_STEPS)
        diff = float(np.abs(peer.positions() - reference).max())
        if hasattr(peer, "close"):
            peer.close()
        rows.append(row("check", "same answer", sim.tet_count, name, ratio=diff / displacement, ratio_to="max displacement",
                        note=f"max abs(x - x_softsim) = {diff:.2e} m after {CHECK_STEPS} steps, float64 "
                             f"(displacement {displacement:.2e} m)"))
        log(f"  check {name}: {diff:.2e} m of {displacement:.2e} m")
    return rows


def throughput(sizes, seconds, repeats, threads, stream):
    """softsim (and both of its scatters) against Taichi, Warp and the STREAM bound, per size."""
    rows = []
    available = peers.available()
    for name, reason in available.items():
        if reason is not None:
            rows.append(row("throughput", "peer", None, name, note=f"skipped: {reason}"))
    for target in sizes:
        prepared = prepared_beam(target)
        runners = {"softsim": Softsim(prepared)}
        other = "csr" if runners["softsim"].scatter == "colour" else "colour"
        runners[f"softsim ({other})"] = Softsim(prepared, scatter=other)
        arrays = system_arrays(prepared)
        if available["taichi"] is None:
            runners["taichi"] = peers.Taichi(arrays, threads)
        if available["warp"] is None:
            runners["warp"] = peers.Warp(arrays)
        runners["bound"] = lambda: stream.bound(2) / 1e6
        rates = interleaved(runners, seconds, repeats)
        for runner in runners.values():
            if hasattr(runner, "close"):          # a peer holding memory of its own (Taichi's fields)
                runner.close()
        tets = runners["softsim"].tet_count
        med = {k: statistics.median(v) for k, v in rates.items()}
        log(f"  {tets:>9} tets: " + ", ".join(f"{k} {v:.1f}" for k, v in med.items()))
        scatter = runners["softsim"].scatter
        rows.append(row("throughput", "bound", tets, "stream triad / 272 B", threads, med["bound"],
                        note=f"{med['bound'] * BYTES_PER_TET_STEP / 1e3:.1f} GB/s"))
        rows.append(row("throughput", "softsim", tets, "softsim", threads, med["softsim"],
                        median_ratio(rates, "softsim", "bound"), "bound",
                        note=f"scatter: {scatter}; {1e3 / med['softsim']:.1f} ns per tet-step"))
        rows.append(row("throughput", f"scatter {other}", tets, f"softsim ({other})", threads,
                        med[f"softsim ({other})"], median_ratio(rates, f"softsim ({other})", "softsim"), "softsim"))
        for peer, peer_threads in (("taichi", threads), ("warp", 1)):
            if peer in rates:
                rows.append(row("throughput", peer, tets, peer, peer_threads, med[peer],
                                median_ratio(rates, "softsim", peer), f"softsim / {peer}"))
    return rows


def cost_against_size(sizes, seconds, repeats, threads):
    """softsim alone at every size, all the sizes interleaved in the same rounds: the cost per
    tet-step of each against the cheapest (the flat-cost target).  The throughput section times
    one size after another, each with its peers, a minute or more apart, and a shared host's speed
    drifts over such spans (the 100k beam's step on one thread moved between 14.2 and 17.8 ns a tet
    within 30 s of one process); here the drift hits every size alike.  Every beam stays in memory
    at once."""
    runners = {str(target): Softsim(prepared_beam(target)) for target in sizes}
    rates = interleaved(runners, seconds, repeats)
    median = {name: statistics.median(r) for name, r in rates.items()}
    cheapest = max(median, key=median.get)
    cheapest_tets = runners[cheapest].tet_count
    rows = []
    for name, sim in runners.items():
        ratio = median_ratio(rates, cheapest, name)            # cost over the cheapest's, per round
        log(f"  {sim.tet_count:>9} tets: {median[name]:.1f} ({1e3 / median[name]:.2f} ns per tet-step, "
            f"{ratio:.3f}x the cheapest)")
        rows.append(row("sizes", "softsim", sim.tet_count, "softsim", threads, median[name], ratio,
                        f"cost / {cheapest_tets:,} tets'", note=f"{1e3 / median[name]:.2f} ns per tet-step"))
    return rows


def thread_scaling(sizes, seconds, repeats, threads):
    """softsim on 1 thread and on ``threads``, interleaved (``numba.set_num_threads`` per call)."""
    rows = []

    class OnThreads:
        def __init__(self, sim, n):
            self.sim, self.n, self.tet_count = sim, n, sim.tet_count
            self.step_calls = sim.step_calls

        def run(self, steps):
            self.on_threads(self.sim.run, steps)

        def settle(self, steps):
            # each thread count's step times its prefetches apart (PrefetchChoice)
            self.on_threads(self.sim.settle, steps)

        def on_threads(self, call, steps):
            numba.set_num_threads(self.n)
            try:
                call(steps)
            finally:
                numba.set_num_threads(threads)

    for target in sizes:
        sim = Softsim(prepared_beam(target))
        runners = {"1": OnThreads(sim, 1), str(threads): OnThreads(sim, threads)}
        rates = interleaved(runners, seconds, repeats)
        ratio = median_ratio(rates, str(threads), "1")
        log(f"  {sim.tet_count:>9} tets: {threads} threads / 1 thread = {ratio:.2f}")
        rows.append(row("threads", "1 thread", sim.tet_count, "softsim", 1, statistics.median(rates["1"])))
        rows.append(row("threads", f"{threads} threads", sim.tet_count, "softsim", threads,
                        statistics.median(rates[str(threads)]), ratio, "1 thread"))
    return rows


PREFETCH_VARIANTS = ("none", "rest data", "rest data + vertex rows", "rest data computed + vertex rows")


def prefetch(sizes, seconds, repeats, threads):
    """What the step's software prefetches buy, and computing the rest data instead of reading
    them: the same mesh stepped with no prefetch, with the rest data of the block ahead only, and
    with the rows of its first-used vertices too, all three reading the stored rest data; then
    computing each block's rest data from the rest positions (``BlockLayout.rest_from_points``),
    with the vertex rows prefetched; interleaved in one process.  The variants differ only in the
    layout's ``prefetch``, first-use lists and ``rest_from_points``.  Comparing separate processes
    instead overstated the gains here: the same code ran from 75 to 111 M tet-steps/s at 1M from
    process to process."""
    from softsim.kernels.blocked import PREFETCH_BLOCKS_AHEAD, build_block_layout, prefetching

    rows = []
    for target in sizes:
        prepared = prepared_beam(target)
        model = prepared.model
        layout, n = model.blocks, model.node_count
        stored = build_block_layout(model.tets, model.Dm_inv, model.rest_volume, n, rest_from_points=False,
                                    model=model.material_id)
        variants = dict(zip(PREFETCH_VARIANTS, (
            prefetching(stored, n, None),
            prefetching(stored, n, PREFETCH_BLOCKS_AHEAD, vertex_rows=False),
            prefetching(stored, n, PREFETCH_BLOCKS_AHEAD),
            prefetching(build_block_layout(model.tets, model.Dm_inv, model.rest_volume, n, rest_from_points=True,
                                           model=model.material_id), n, PREFETCH_BLOCKS_AHEAD))))
        runners = {name: Softsim(dataclasses.replace(prepared, model=dataclasses.replace(prepared.model, blocks=blocks)))
                   for name, blocks in variants.items()}
        rates = interleaved(runners, seconds, repeats)
        tets = runners["none"].tet_count
        default = PREFETCH_VARIANTS[-1 if layout.rest_from_points else 0 if layout.prefetch is None else -2]
        # a layout that prefetches lets the run time it against none and keep the faster (PrefetchChoice)
        measured = (PREFETCH_VARIANTS[0],) if layout.measure_prefetch and not layout.rest_from_points else ()
        log(f"  {tets:>9} tets: " + ", ".join(f"{name} {statistics.median(rates[name]):.1f}" for name in variants)
            + f" (default: {' or '.join((default,) + measured)}{', the faster measured' if measured else ''})")
        for name, before in zip(PREFETCH_VARIANTS, (None,) + PREFETCH_VARIANTS):
            rows.append(row("prefetch", name, tets, "softsim", threads, statistics.median(rates[name]),
                            None if before is None else median_ratio(rates, name, before), before or "",
                            note="the default at this size" if name == default
                            else "measured against the default" if name in measured else ""))
    return rows


def models(target, seconds, repeats, threads):
    """Each material model against StVK on the same beam."""
    runners = {name: Softsim(prepared_beam(target, name)) for name in MODELS}
    rates = interleaved(runners, seconds, repeats)
    rows = []
    for name in MODELS:
        ratio = median_ratio(rates, "stvk", name)
        log(f"  {name}: {statistics.median(rates[name]):.1f} (stvk / {name} = {ratio:.2f})")
        rows.append(row("models", name, runners[name].tet_count, "softsim", threads, statistics.median(rates[name]),
                        ratio, "stvk / model"))
    return rows


FEATURES = {
    "bare": {},
    "ground": {"ground": {"height": -1.0, "stiffness": 1e6, "friction": 0.3}},
    "damping": {"damping": 0.5},
    "ground + damping": {"ground": {"height": -1.0, "stiffness": 1e6, "friction": 0.3}, "damping": 0.5},
    "traction": {"tractions": [{"min": [0.999, -1, -1], "max": [1.001, 1, 1], "traction": [0, 0, -1e3]}]},
}


def features(target, seconds, repeats, threads):
    """The step's cost with each optional feature, against the bare scene (the ground lies below the
    beam: its contact test runs every step, no vertex touches it)."""
    runners = {name: Softsim(prepared_beam(target, **extra)) for name, extra in FEATURES.items()}
    rates = interleaved(runners, seconds, repeats)
    rows = []
    for name in FEATURES:
        ratio = median_ratio(rates, name, "bare")
        rounds = sorted(x / y for x, y in zip(rates[name], rates["bare"]))
        spread = f"rounds {rounds[0]:.3f}-{rounds[-1]:.3f}" if name != "bare" else ""   # a shared host's noise
        log(f"  {name}: {statistics.median(rates[name]):.1f} ({ratio:.3f} of bare{'; ' + spread if spread else ''})")
        rows.append(row("features", name, runners[name].tet_count, "softsim", threads, statistics.median(rates[name]),
                        ratio, "bare", note=spread))
    return rows


def overhead(target, frames, threads, interval=0.001):
    """Time outside the kernels in ``simulate`` (guard, energy, output) at a frame ``interval`` [s]:
    the whole run against the time spent inside its ``step`` calls (timed by wrapping ``step``),
    and the share of it the guard's checks take (``FrameGuard.check`` and ``recheck_step``, wrapped
    the same way): the rest is the frames' output (HDF5) and the loop itself."""
    from softsim import simulation
    from softsim.integrators.guard import FrameGuard

    prepared = prepared_beam(target, output={"frame_interval": interval, "fields": []},
                             time={"duration": interval * frames})
    steps = prepared.plan.total_steps
    spent = {"step": 0.0, "guard": 0.0}

    def timed(function, key):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[key] += time.perf_counter() - start
        return wrapper

    plain = (simulation.step, FrameGuard.check, FrameGuard.recheck_step)
    outside, guard, rates = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        simulation.simulate(prepared, os.path.join(tmp, "warm.h5"))        # compile the guard and the writer
        simulation.step = timed(plain[0], "step")
        FrameGuard.check = timed(plain[1], "guard")
        FrameGuard.recheck_step = timed(plain[2], "guard")
        try:
            for k in range(3):
                spent.update(step=0.0, guard=0.0)
                start = time.perf_counter()
                simulation.simulate(prepared, os.path.join(tmp, f"run{k}.h5"))
                wall = time.perf_counter() - start
                outside.append(1.0 - spent["step"] / wall)
                guard.append(spent["guard"] / wall)
                rates.append(prepared.model.tet_count * steps / wall / 1e6)
        finally:
            simulation.step, FrameGuard.check, FrameGuard.recheck_step = plain
    ms = f"{interval * 1e3:g} ms"
    log(f"  {frames} frames of {ms}, {steps} steps: {statistics.median(outside):.1%} of the run outside the step "
        f"loop, the guard {statistics.median(guard):.1%}")
    note = f"{frames} frames every {ms} ({steps // frames} steps each)"
    return [row("overhead", f"outside kernels, frames every {ms}", prepared.model.tet_count, "softsim", threads,
                statistics.median(rates), statistics.median(outside), "share of wall time",
                note=f"{note}: guard checks, frame writes (HDF5)"),
            row("overhead", f"guard, frames every {ms}", prepared.model.tet_count, "softsim", threads,
                statistics.median(rates), statistics.median(guard), "share of wall time",
                note=f"{note}: the stable step's rechecks every {RECHECK_STEPS} steps and the frame checks")]


def _probe(args, env=None):
    out = subprocess.run([sys.executable, "-m", "benchmarks.probe", *map(str, args)], cwd=ROOT, capture_output=True,
                         text=True, env={**os.environ, **(env or {})})
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "probe failed")
    return json.loads(out.stdout.strip().splitlines()[-1])


def memory(target, threads):
    """Peak RSS of a fresh process that prepares and steps the beam, and what holds it."""
    result = _probe(["memory", target])
    tets = result["tets"]
    rows = [row("memory", "peak RSS", tets, "softsim", threads, ratio=result["peak_rss"] / tets, ratio_to="bytes per tet",
                note=f"peak {result['peak_rss'] / 2**20:.0f} MiB; after imports {result['baseline_rss'] / 2**20:.0f} MiB; "
                     f"peak while preparing {result['peak_after_prepare'] / 2**20:.0f} MiB")]
    total = sum(result["arrays"].values())
    rows.append(row("memory", "all arrays of the run", tets, "softsim", ratio=total / tets, ratio_to="bytes per tet",
                    note="model + block layout + state + work buffer + the mesh in the user's order"))
    rows.append(row("memory", "arrays the step touches", tets, "softsim", ratio=result["step_arrays"] / tets,
                    ratio_to="bytes per tet", note=", ".join(result["step_array_names"])))
    for name, nbytes in sorted(result["arrays"].items(), key=lambda kv: -kv[1]):
        if nbytes / tets >= 0.5:
            rows.append(row("memory", name, tets, "softsim", ratio=nbytes / tets, ratio_to="bytes per tet"))
    log(f"  {tets} tets: peak RSS {result['peak_rss'] / tets:.0f} B/tet")
    return rows


def startup(target):
    """Seconds to the first step in a fresh process: with an empty JIT cache, then with it warm."""
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        env = {"NUMBA_CACHE_DIR": cache}
        for case in ("cold (compiles)", "warm (on-disk cache)"):
            r = _probe(["startup", target], env)
            rows.append(row("startup", case, target, "softsim", rate=None, ratio=r["total_s"], ratio_to="seconds",
                            note=f"import {r['import_s']:.2f} s, prepare {r['prepare_s']:.2f} s, "
                                 f"first step {r['first_step_s']:.2f} s"))
            log(f"  {case}: {r['total_s']:.1f} s (first step {r['first_step_s']:.2f} s)")
    return rows


def threading_layers(target, seconds, rounds):
    """softsim under each loadable Numba threading layer, one process per layer, alternating."""
    rates = {}
    notes = {}
    for _ in range(rounds):
        for layer in ("omp", "tbb", "workqueue"):
            if layer in notes:
                continue
            try:
                r = _probe(["layer", target, seconds], {"NUMBA_THREADING_LAYER": layer})
            except RuntimeError as exc:
                notes[layer] = f"not available: {exc}"
                continue
            rates.setdefault(layer, []).extend(r["rates"])
    rows = []
    for layer in ("omp", "tbb", "workqueue"):
        if layer in rates:
            log(f"  {layer}: {statistics.median(rates[layer]):.1f}")
            rows.append(row("threading layer", layer, target, "softsim", rate=statistics.median(rates[layer]),
                            note=f"{len(rates[layer])} timings in {rounds} alternating processes"))
        else:
            rows.append(row("threading layer", layer, target, "softsim", note=notes.get(layer, "")))
    return rows


# The lane loops read two arrays (the block's rest rows and the scratch buffer), so LLVM checks at
# run time that they do not overlap and keeps a scalar copy of the loop for when they do: about
# as many scalar instructions as packed ones, never run.
SIMD_NOTE = "; the scalar count includes the loop's copy for overlapping arrays, never run"


def simd():
    """Whether each model's lane loop compiled to packed SIMD arithmetic (and which width)."""
    with tempfile.TemporaryDirectory() as cache:
        result = _probe(["asm"], {"NUMBA_CACHE_DIR": cache})
    rows = []
    for name, counts in result.items():
        total = sum(counts.values())
        text = ", ".join(f"{v} {k}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
        log(f"  {name}: {text}")
        if name.startswith(("gather", "scatter")):       # a block's memory moves (probe.memory_moves)
            vector = sum(v for k, v in counts.items() if k != "store scalar")
            rows.append(row("simd", f"{name} stores", runner="softsim", ratio=vector / max(total, 1),
                            ratio_to="vector share of stores", note=f"{text} instructions in the compiled code"))
            continue
        packed = sum(v for k, v in counts.items() if "packed" in k)
        rows.append(row("simd", f"{name} lane loop", runner="softsim", ratio=packed / max(total, 1),
                        ratio_to="packed share of arithmetic", note=text + SIMD_NOTE))
    return rows




def precision(target, large, seconds, repeats, threads):
    """float32 against float64: each model with a float32 step on the beam of ``target`` tets, StVK
    also at ``large`` tets; with the difference of the positions after ``CHECK_STEPS`` steps."""
    rows = []
    from softsim.config.schema import FLOAT32_MODELS

    for size, names in ((target, FLOAT32_MODELS), (large, ("stvk",))):
        for name in names:
            runners = {p: Softsim(prepared_beam(size, name, precision=p)) for p in ("float64", "float32")}
            for sim in runners.values():
                sim.run(CHECK_STEPS)
            x64, x32 = runners["float64"].positions(), runners["float32"].positions()
            moved = float(np.abs(x64 - runners["float64"].model.rest_points).max())
            difference = float(np.abs(x32 - x64).max())
            rates = interleaved(runners, seconds, repeats)
            ratio = median_ratio(rates, "float32", "float64")
            tets = runners["float64"].tet_count
            log(f"  {name} {tets} tets: float32 / float64 = {ratio:.2f}; positions differ by {difference:.1e} m "
                f"of {moved:.1e} m")
            rows.append(row("precision", f"{name} float64", tets, "softsim", threads,
                            statistics.median(rates["float64"])))
            rows.append(row("precision", f"{name} float32", tets, "softsim", threads,
                            statistics.median(rates["float32"]), ratio, "float64",
                            note=f"after {CHECK_STEPS} steps max abs(x32 - x64) = {difference:.1e} m, "
                                 f"{difference / moved:.1e} of the largest displacement"))
    return rows
