"""The atomic counters of ``kernels.sync`` and the choice of ``advance``'s schedule
(``integrators.symplectic_euler.PartSchedule``)."""

import hashlib
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
from numba import prange

from softsim.integrators.symplectic_euler import LONG_WAIT_SHARE, SEPARATE_CALLS, PartSchedule
from softsim.kernels.jit import njit, njit_parallel
from softsim.kernels.sync import compare_exchange, fetch_add, load_acquire, spin_pause, yield_thread


@njit_parallel
def _take_in_parallel(counters, chunks, takes):
    """Each of ``chunks`` chunks takes ``takes`` numbers from ``counters[0]``; returns them all."""
    taken = np.empty(chunks * takes, dtype=np.int64)
    for chunk in prange(chunks):
        for k in range(takes):
            taken[chunk * takes + k] = fetch_add(counters, 0, 1)
    return taken


@njit
def _old_values(counters, adds):
    seen = np.empty(adds, dtype=np.int64)
    for k in range(adds):
        seen[k] = fetch_add(counters, 0, 3)
        spin_pause()
    yield_thread()
    return seen, load_acquire(counters, 0)


def test_fetch_add_returns_the_value_before_and_load_acquire_the_value_now():
    counters = np.array([5] + [0] * 15, dtype=np.int64)
    seen, now = _old_values(counters, 4)
    assert seen.tolist() == [5, 8, 11, 14]
    assert now == 17 == counters[0]


def test_threads_taking_numbers_at_once_each_get_their_own():
    """Two threads taking numbers from one counter at once get every number once: the count of
    parts done that each thread adds to (a plain read and write would lose some)."""
    counters = np.zeros(16, dtype=np.int64)
    chunks, takes = max(2, numba.get_num_threads()), 200_000
    taken = _take_in_parallel(counters, chunks, takes)
    assert np.array_equal(np.sort(taken), np.arange(chunks * takes))
    assert counters[0] == chunks * takes


@njit_parallel
def _claim_in_parallel(claims, chunks):
    """Each of ``chunks`` chunks tries to raise every claim from 0 to 1; returns (chunks, claims)
    ones where a chunk won."""
    won = np.zeros((chunks, claims.size), dtype=np.int64)
    for chunk in prange(chunks):
        for k in range(claims.size):
            if compare_exchange(claims, k, 0, 1):
                won[chunk, k] = 1
    return won


def test_compare_exchange_sets_only_what_holds_the_expected_value_and_one_thread_wins_each():
    counters = np.array([3, 7], dtype=np.int64)
    assert not _exchange(counters, 0, 4, 9) and counters.tolist() == [3, 7]
    assert _exchange(counters, 1, 7, 8) and counters.tolist() == [3, 8]
    claims = np.zeros(200_000, dtype=np.int64)
    won = _claim_in_parallel(claims, max(2, numba.get_num_threads()))
    assert (claims == 1).all() and (won.sum(axis=0) == 1).all()      # a plain compare and store lets two win


@njit
def _exchange(counters, index, expected, value):
    return compare_exchange(counters, index, expected, value)


def test_a_call_with_many_long_waits_sends_the_next_calls_to_a_region_per_colour():
    schedule = PartSchedule()
    assert schedule.one_region()
    schedule.record(True, int(LONG_WAIT_SHARE * 800), 800)        # as many as allowed: stays
    assert schedule.one_region()
    schedule.record(True, int(LONG_WAIT_SHARE * 800) + 1, 800)
    for _ in range(SEPARATE_CALLS):
        assert not schedule.one_region()
        schedule.record(False, 0, 800)
    assert schedule.one_region()                                  # then tried again


def test_each_thread_owns_a_run_of_consecutive_parts_with_as_many_of_each_colour():
    """``part_owner``: 8 slab parts (two colours, even and odd slabs) on 2 threads: slabs 0-3 and
    4-7, two of each colour per thread, so one boundary between slabs crosses from core to core."""
    from softsim.integrators.symplectic_euler import part_owner

    owners = [part_owner(p, 8, 2) for p in range(8)]
    assert owners == [0, 0, 0, 0, 1, 1, 1, 1]
    assert [part_owner(p, 8, 1) for p in range(8)] == [0] * 8
    assert [part_owner(p, 8, 4) for p in range(8)] == [0, 0, 1, 1, 2, 2, 3, 3]


def _prepared_beam():
    """A small StVK beam pinned at one end, moving down (2,500 tets: 8 slab parts, 2 colours)."""
    from softsim import simulation
    from softsim.config import parse_scene

    scene = {"mesh": {"shape": "box", "size": [1.0, 0.25, 0.25], "element_size": 0.05, "structured": True},
             "material": {"model": "stvk", "youngs_modulus": 1e6, "poissons_ratio": 0.3, "density": 1000.0},
             "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
             "initial_velocity": [0.0, 0.0, -2.0], "time": {"duration": 1.0}}
    return simulation.prepare(parse_scene(scene))


def _advance_beam(chunks, numba_threads, steps=9):
    """Positions and velocities of a beam advanced by ``steps`` steps in one call of ``advance``
    in one region of ``chunks`` chunks run on ``numba_threads`` threads; and its long waits."""
    from softsim.integrators.symplectic_euler import advance, step_arguments, work_buffer
    from softsim.model import initial_state

    prepared = _prepared_beam()
    model = prepared.model
    assert model.blocks.part_offsets.shape[0] - 1 >= 8 and model.blocks.colour_count == 2    # 8 on up to 4 threads
    state = initial_state(prepared.scene, model)
    blocks, colour_offsets, scatter, offsets, slots, vertex_forces, corner = step_arguments(model, work_buffer(model))
    before = numba.get_num_threads()
    numba.set_num_threads(numba_threads)
    try:
        long_waits = advance(state.x, None, state.v, 0, steps, prepared.plan.dt, blocks, colour_offsets, scatter,
                             model.material_id, model.lam, model.mu, offsets, slots, vertex_forces, corner,
                             model.inv_mass, tuple(float(g) for g in model.gravity), None, model.held,
                             state.held_start, model.held_velocity, None, None, None, chunks, True)
    finally:
        numba.set_num_threads(before)
    return state.x, state.v, long_waits


def test_chunks_run_one_after_the_other_take_every_part_without_waiting():
    """The one region cannot deadlock when the pool runs its chunks one after the other: on one
    thread, the first of two chunks runs its own parts, then takes the other chunk's (nobody has
    claimed them), and never waits; the second finds every part taken.  The same bits as one
    chunk, and as two chunks side by side.  (In a process of its own with a time limit: a
    deadlock would spin for ever.)"""
    script = ("import sys, hashlib; sys.path.insert(0, sys.argv[1]); import test_sync; "
              "x, v, waits = test_sync._advance_beam(chunks=2, numba_threads=1); "
              "print(waits, hashlib.sha256(x.tobytes() + v.tobytes()).hexdigest())")
    done = subprocess.run([sys.executable, "-c", script, str(Path(__file__).parent)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    x1, v1, waits1 = _advance_beam(chunks=1, numba_threads=1)
    assert done.stdout.split() == ["0", hashlib.sha256(x1.tobytes() + v1.tobytes()).hexdigest()]
    assert waits1 == 0
    if numba.config.NUMBA_NUM_THREADS >= 2:
        x2, v2, _ = _advance_beam(chunks=2, numba_threads=2)
        assert x1.tobytes() == x2.tobytes() and v1.tobytes() == v2.tobytes()


def test_the_prefetch_trial_alternates_and_keeps_the_faster_for_a_while():
    """Calls of alternating lengths (a run's 32 steps, then a frame's remainder) fall to both ways
    (with, without, without, with, ...); the first call of each is not timed (here it compiles:
    1000 s, which would turn the choice); calls of no step do not count; the faster per step
    over the timed calls is kept for ``KEEP_CALLS`` calls, then a new trial begins."""
    from softsim.integrators.symplectic_euler import KEEP_CALLS, TRIAL_CALLS, PrefetchChoice

    for faster in (True, False):
        choice = PrefetchChoice()
        for trial in range(2):
            ways, lengths = [], []
            for call in range(2 * (1 + TRIAL_CALLS)):
                prefetch = choice.prefetch_next()
                choice.record(prefetch, 5.0, 0)                   # no step: not counted
                steps = 32 if call % 2 == 0 else 8
                ways.append(prefetch)
                lengths.append((prefetch, steps))
                per_step = 1.0 if prefetch == faster else 1.1
                compiling = 1000.0 if call < 2 and prefetch == faster else 0.0
                choice.record(prefetch, per_step * steps + compiling, steps)
            assert ways == [True, False, False, True] * ((1 + TRIAL_CALLS) // 2)
            assert {(True, 32), (True, 8), (False, 32), (False, 8)} <= set(lengths[2:])
            for _ in range(KEEP_CALLS):
                assert choice.prefetch_next() == faster
                choice.record(faster, 1.0, 1)
        assert choice.prefetch_next() is True                       # the next trial begins


def test_a_measured_prefetch_runs_both_ways_with_the_same_bits(monkeypatch):
    """A layout whose prefetches the run measures (forced onto a small beam) steps with them and
    without, call by call, and reaches the same bits as a layout that always fetches ahead."""
    import dataclasses

    from softsim import simulation
    from softsim.integrators.symplectic_euler import TRIAL_CALLS, work_buffer
    from softsim.kernels.blocked import PREFETCH_BLOCKS_AHEAD, prefetching
    from softsim.model import initial_state

    prepared = _prepared_beam()
    model = prepared.model
    assert not model.blocks.measure_prefetch                          # a small mesh: no prefetches
    always = prefetching(model.blocks, model.node_count, PREFETCH_BLOCKS_AHEAD)
    measured = dataclasses.replace(always, measure_prefetch=True)
    ways = []
    original = simulation.step_arguments
    monkeypatch.setattr(simulation, "step_arguments",
                        lambda m, work, prefetch=True: ways.append(prefetch) or original(m, work, prefetch))
    results = []
    calls = 2 * (1 + TRIAL_CALLS)
    for layout in (always, measured):
        m = dataclasses.replace(model, blocks=layout)
        state, work = initial_state(prepared.scene, m), work_buffer(m)
        for call in range(calls):
            simulation.step(m, state, prepared.plan.dt, 3, 0.0, work)
            # the trial runs from the first call to the last of its calls, and only where measured
            assert simulation.prefetch_trial_running(m) == (layout is measured and call < calls - 1)
        results.append(state.x.tobytes() + state.v.tobytes())
    # the measured layout's first call first compiles the way without prefetches (a call of no step)
    assert ways[:calls] == [True] * calls
    assert ways[calls:] == [False] + [True, False, False, True] * ((1 + TRIAL_CALLS) // 2)
    assert results[0] == results[1]
    unprefetched = original(dataclasses.replace(model, blocks=measured), work, False)[0]
    assert unprefetched[7] is None and unprefetched[9].size == 0          # no rest data, no vertex rows fetched
    assert all(c.kept_calls_left > 0 for c in simulation.PREFETCH_CHOICES[measured].values())   # a way chosen
    # the first call compiles both ways for a measured layout, so the timed calls that follow (a
    # speed sample, a benchmark's calibration) compile nothing; it takes its one step, no more
    for layout, expected in ((measured, [False, True]), (always, [True])):
        m = dataclasses.replace(model, blocks=dataclasses.replace(layout))     # a layout of its own: a new trial
        ways.clear()
        state = initial_state(prepared.scene, m)
        simulation.step(m, state, prepared.plan.dt, 1, 0.0, work_buffer(m))
        assert ways == expected and state.step == 1


def test_a_prefetch_trial_is_asked_after_by_thread_count(monkeypatch):
    """``prefetch_trial_running(model, threads)`` answers for the calls made on ``threads`` threads
    alone (each thread count's step times its prefetches apart): a benchmark timing the step on
    one thread and on two ends each trial with calls on its own thread count."""
    from softsim import simulation
    from softsim.integrators.symplectic_euler import PrefetchChoice, step_threads
    from softsim.kernels.jit import threading_layer

    model = _prepared_beam().model
    one, two = (step_threads(model.tet_count, n, threading_layer()) for n in (1, 2))
    assert (one, two) == (1, 2)
    kept = PrefetchChoice()
    kept.kept_calls_left = 1                            # its trial over, a way kept
    monkeypatch.setitem(simulation.PREFETCH_CHOICES, model.blocks, {one: PrefetchChoice(), two: kept})
    assert simulation.prefetch_trial_running(model, 1)
    assert not simulation.prefetch_trial_running(model, 2)
    assert simulation.prefetch_trial_running(model)
    monkeypatch.setitem(simulation.PREFETCH_CHOICES, model.blocks, {two: kept})
    assert not simulation.prefetch_trial_running(model, 1)     # no call on one thread yet
    assert not simulation.prefetch_trial_running(model)
