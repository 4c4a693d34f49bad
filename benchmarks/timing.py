"""Interleaved timing: every runner is timed in turn, round after round, and the median is kept.

On a shared machine the speed of all runners drifts together; timing them alternately in one
process and comparing medians of ratios taken in the same round keeps the comparison fair.
"""

import statistics
import time

from softsim.kernels import compile_ahead


def calibrate(runner, seconds):
    """Steps that take about ``seconds`` for ``runner`` (after a first call that compiles)."""
    runner.run(1)
    steps, elapsed = 1, 0.0
    while elapsed < 0.05 * seconds:
        steps *= 2
        start = time.perf_counter()
        runner.run(steps)
        elapsed = time.perf_counter() - start
    return max(1, int(steps * seconds / elapsed))


def compile_steps_ahead(runners):
    """Compile the steps of the runners of ``runners`` (name -> runner) that have ``step_calls``
    (softsim's) on both cores, those Numba's cache lacks (``compile_ahead.compile_shared``), and
    wait until all are compiled: their first calls would compile them one after another, on one
    core.  Nothing is timed while the helper compiles."""
    calls = [call for runner in runners.values() if hasattr(runner, "step_calls") for call in runner.step_calls()]
    compile_ahead.compile_shared(calls)
    compile_ahead.wait()


def interleaved(runners, seconds, repeats):
    """``{name: [M tet-steps/s per round]}`` timing each runner of ``runners`` (name -> runner) in turn.

    A runner has ``tet_count`` and ``run(steps)``, and may have ``settle(steps)``, called once after
    its calibration, before the rounds, and ``step_calls()`` (``compile_steps_ahead``); a callable
    entry ``name -> f()`` returning a rate in M/s (the STREAM bound) is called as is.
    """
    compile_steps_ahead(runners)
    steps = {name: calibrate(r, seconds) for name, r in runners.items() if hasattr(r, "run")}
    for name, r in runners.items():
        if hasattr(r, "settle"):
            r.settle(steps[name])
    rates = {name: [] for name in runners}
    for _ in range(repeats):
        for name, r in runners.items():
            if not hasattr(r, "run"):
                rates[name].append(r())
                continue
            start = time.perf_counter()
            r.run(steps[name])
            rates[name].append(r.tet_count * steps[name] / (time.perf_counter() - start) / 1e6)
    return rates


def median_ratio(rates, a, b):
    """Median over rounds of ``rates[a][k] / rates[b][k]`` (ratios of the same round)."""
    return statistics.median(x / y for x, y in zip(rates[a], rates[b]))
