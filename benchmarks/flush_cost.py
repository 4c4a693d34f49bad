"""What crash safety costs: the writer's per-frame flush, measured.

1. Writer alone: ``append_frame`` of a mesh with n vertices (positions, velocities and the resume
   state), with the per-frame ``flush`` and with it skipped, in interleaved rounds; median
   milliseconds per frame.
2. Whole run: the example cantilever (``configs/cantilever.yaml``, its own frame interval) with
   and without the flush, interleaved; median wall time and the share of it spent writing frames.

    python benchmarks/flush_cost.py [--rounds 5] [--frames 200]
"""

import argparse
import contextlib
import statistics
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from softsim.config import load_scene
from softsim.io import hdf5
from softsim.simulation import prepare, simulate

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def flushing(enabled):
    """Skip ``h5py.File.flush`` (what the writer would cost without crash safety) unless enabled."""
    original = h5py.File.flush
    if not enabled:
        h5py.File.flush = lambda self: None
    try:
        yield
    finally:
        h5py.File.flush = original


@contextlib.contextmanager
def timed_frames(totals):
    """Add the wall time spent in ``RunWriter.append_frame`` to ``totals['write']``."""
    original = hdf5.RunWriter.append_frame

    def append_frame(self, *args, **kwargs):
        started = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            totals["write"] += time.perf_counter() - started

    hdf5.RunWriter.append_frame = append_frame
    try:
        yield
    finally:
        hdf5.RunWriter.append_frame = original


def writer_ms_per_frame(folder, node_count, frames, flush):
    rng = np.random.default_rng(0)
    points = rng.random((node_count, 3))
    tets = np.zeros((1, 4), np.int64)
    with flushing(flush):
        with hdf5.RunWriter(folder / "w.h5", points, tets, np.zeros(node_count, bool), "", 1e-3, frames,
                            fields=("velocities",), xdmf=False, frames=frames,
                            resume_template={"guard_substeps": 1}) as writer:
            started = time.perf_counter()
            for k in range(frames):
                writer.append_frame(k * 1e-3, k, points, points, resume_state={"guard_substeps": 1})
            return 1e3 * (time.perf_counter() - started) / frames


def whole_run(folder, flush):
    scene = load_scene(ROOT / "configs" / "cantilever.yaml")
    prepared = prepare(scene)
    totals = {"write": 0.0}
    with flushing(flush), timed_frames(totals):
        summary = simulate(prepared, folder / "run.h5")
    return summary.wall_time_s, totals["write"] / summary.wall_time_s


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print("writer alone: ms per frame (median), with / without the per-frame flush")
        for n in (1_000, 20_000, 200_000):
            times = {True: [], False: []}
            for _ in range(args.rounds):
                for flush in (True, False):
                    times[flush].append(writer_ms_per_frame(folder, n, args.frames, flush))
            with_flush, without = statistics.median(times[True]), statistics.median(times[False])
            print(f"  {n:>7} vertices ({n * 48 / 1e6:.2f} MB/frame): {with_flush:.3f} / {without:.3f} ms, "
                  f"flush adds {with_flush - without:+.3f} ms ({with_flush / without:.2f}x)")
        whole_run(folder, True)        # compile once, outside the timings
        walls, shares = {True: [], False: []}, {True: [], False: []}
        for _ in range(args.rounds):
            for flush in (True, False):
                wall, share = whole_run(folder, flush)
                walls[flush].append(wall)
                shares[flush].append(share)
        print("configs/cantilever.yaml (frame every 0.01 s): median wall, share of it writing frames")
        for flush in (True, False):
            print(f"  {'with' if flush else 'without'} flush: {statistics.median(walls[flush]):.3f} s, "
                  f"{100 * statistics.median(shares[flush]):.1f} % writing")
        print(f"  ratio with / without: {statistics.median(walls[True]) / statistics.median(walls[False]):.3f}")


if __name__ == "__main__":
    main()
