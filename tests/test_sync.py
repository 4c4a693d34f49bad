"""The atomic counters of ``kernels.sync`` and the choice of ``advance``'s schedule
(``integrators.symplectic_euler.PartSchedule``)."""

import numba
import numpy as np
from numba import prange

from softsim.integrators.symplectic_euler import LONG_WAIT_SHARE, SEPARATE_CALLS, PartSchedule
from softsim.kernels.jit import njit, njit_parallel
from softsim.kernels.sync import fetch_add, load_acquire, spin_pause, yield_thread


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
    """Two threads taking numbers from one counter at once get every number once: the count a
    shared counter of parts hands out (a plain read and write would hand some out twice)."""
    counters = np.zeros(16, dtype=np.int64)
    chunks, takes = max(2, numba.get_num_threads()), 200_000
    taken = _take_in_parallel(counters, chunks, takes)
    assert np.array_equal(np.sort(taken), np.arange(chunks * takes))
    assert counters[0] == chunks * takes


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
