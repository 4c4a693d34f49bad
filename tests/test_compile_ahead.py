"""Compiling kernels in a helper process (``kernels.compile_ahead``): the helper fills Numba's
disk cache with what this process then loads instead of compiling, for the very argument types
a run calls the guard and the step with; and a helper that fails costs nothing but its time."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from softsim.integrators import guard, symplectic_euler
from softsim.kernels import blocked, compile_ahead
from softsim.simulation import prepare, run_calls, simulate

from recorded_calls import recording

# A fresh process with a cache of its own (Numba reads NUMBA_CACHE_DIR as it loads): submits
# ``kinetic_energy`` of float32 arrays and ``elastic_energy`` of one StVK tet stretched by 1.1
# along x, its model id a compile-time constant (as the step's), which nothing else compiles in
# that cache; waits for each before calling it, and prints what it saw.  FATE: "wait" for the
# helper, "kill" it first, or "shared": hand them to ``compile_shared`` instead of ``submit``.
PROBE = textwrap.dedent("""
    import numpy as np
    from numba.core import event
    from softsim.kernels import compile_ahead
    from softsim.kernels.energy import elastic_energy, kinetic_energy
    from softsim.kernels.jit import CompileTimeConstant
    from softsim.materials.models import MODEL_IDS

    v = np.arange(12, dtype=np.float32).reshape(4, 3)
    mass = np.full(4, 2.0, dtype=np.float32)
    x = np.array([[0.0, 0, 0], [1.1, 0, 0], [0, 1, 0], [0, 0, 1]])
    tet = (x, np.array([[0, 1, 2, 3]]), np.eye(3)[None], np.array([1 / 6]), CompileTimeConstant(MODEL_IDS["stvk"]),
           1.0, 1.0)
    calls = [(kinetic_energy, (v, mass)), (elastic_energy, tet)]
    cached = [compile_ahead.is_compiled_or_cached(f, compile_ahead.argument_types(f, a)) for f, a in calls]
    handed = (compile_ahead.compile_shared if "{fate}" == "shared" else compile_ahead.submit)(calls)
    in_this_process = [compile_ahead.argument_types(f, a) in f.overloads for f, a in calls]
    if "{fate}" == "kill" and handed:
        compile_ahead._helper.process.kill()
    compiled_here, energies = [], []
    for f, arguments in calls:
        compile_ahead.wait(f)
        cached.append(compile_ahead.is_compiled_or_cached(f, compile_ahead.argument_types(f, arguments)))
        with event.install_listener("numba:compile", event.TimingListener()) as listener:
            energies.append(f(*arguments))
        compiled_here.append(listener.done)
    print(repr((cached, handed, compiled_here, energies, compile_ahead._helper is None, in_this_process)))
""")


def run_probe(tmp_path, fate="wait", switch="1"):
    """``(cached, handed, compiled_here, energies, helper_gone, in_this_process)``: whether each
    kernel was in the cache before the submit and after its wait (4 values), how many the helper
    took (``compile_shared``: how many it and this process took), whether this process compiled
    each when called, each's value, whether the helper is gone after the last wait, and whether
    each was compiled in this process right after the submit."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), compile_ahead.ENVIRONMENT_SWITCH: switch}
    out = subprocess.run([sys.executable, "-c", PROBE.format(fate=fate)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return eval(out.stdout)


# 1/2 m |v|^2 over the probe's four vertices; V0 (mu E:E + lam/2 tr(E)^2) with E_xx = (1.1^2 - 1) / 2
EXPECTED_ENERGIES = [0.5 * 2.0 * float(np.sum(np.arange(12.0) ** 2)), (0.105 ** 2 + 0.5 * 0.105 ** 2) / 6]


@pytest.mark.skipif(compile_ahead.available_cores() < 2, reason="no helper starts on one core")
def test_the_helper_fills_the_cache_and_this_process_compiles_nothing(tmp_path):
    cached, handed, compiled_here, energies, helper_gone, in_this_process = run_probe(tmp_path)
    assert cached == [False, False, True, True] and handed == 2 and in_this_process == [False, False]
    assert compiled_here == [False, False]
    assert energies == pytest.approx(EXPECTED_ENERGIES, rel=1e-12) and helper_gone


def test_switched_off_no_helper_starts_and_this_process_compiles(tmp_path):
    cached, handed, compiled_here, energies, helper_gone, _ = run_probe(tmp_path, switch="0")
    assert cached == [False, False, False, False] and handed == 0
    assert compiled_here == [True, True]
    assert energies == pytest.approx(EXPECTED_ENERGIES, rel=1e-12) and helper_gone


@pytest.mark.skipif(compile_ahead.available_cores() < 2, reason="no helper starts on one core")
def test_a_helper_that_dies_leaves_this_process_to_compile(tmp_path):
    _, handed, compiled_here, energies, helper_gone, _ = run_probe(tmp_path, fate="kill")
    assert handed == 2
    assert compiled_here == [True, True]
    assert energies == pytest.approx(EXPECTED_ENERGIES, rel=1e-12) and helper_gone


@pytest.mark.skipif(compile_ahead.available_cores() < 2, reason="no helper starts on one core")
def test_compiling_shared_the_helper_takes_the_first_and_this_process_the_last(tmp_path):
    cached, handed, compiled_here, energies, helper_gone, in_this_process = run_probe(tmp_path, fate="shared")
    assert handed == 2 and in_this_process == [False, True]
    assert cached == [False, False, True, True] and compiled_here == [False, False]
    assert energies == pytest.approx(EXPECTED_ENERGIES, rel=1e-12) and helper_gone


def test_switched_off_nothing_is_compiled_shared(tmp_path):
    cached, handed, compiled_here, _, _, in_this_process = run_probe(tmp_path, fate="shared", switch="0")
    assert handed == 0 and in_this_process == [False, False] and compiled_here == [True, True]


@pytest.mark.parametrize("overrides", [
    {},
    "prefetch measured",
    {"precision": "float32", "damping": 1.0, "ground": {"height": -0.01},
     "material": {"model": "neohookean"}},
    {"tractions": [{"min": [0.2 - 1e-6, -1, -1], "max": [1, 1, 1], "traction": [0.0, 0.0, -100.0]}],
     "fixed": [{"min": [-1, -1, -1], "max": [1e-6, 1, 1], "velocity": [0.0, 0.0, 0.1]}]},
])
def test_the_calls_compiled_ahead_are_the_calls_the_run_makes(scene, tmp_path, monkeypatch, overrides):
    """The helper compiles the guard's measure and the step for the argument types of
    ``run_calls``: the types a run then calls them with (else the helper's work would be lost)."""
    made = set()

    if overrides == "prefetch measured":     # as a large mesh's step: timed with prefetches and without
        monkeypatch.setattr(blocked, "PREFETCH_FROM_BYTES", 0)
        overrides = {}
    prepared = prepare(scene(time={"duration": 0.02}, **overrides))
    model = prepared.model
    assert model.blocks.measure_prefetch == (blocked.PREFETCH_FROM_BYTES == 0)
    ahead = [(kernel, compile_ahead.argument_types(kernel, arguments))
             for kernel, arguments in run_calls(prepared.scene, model)]
    monkeypatch.setattr(symplectic_euler, "advance_driver", recording(symplectic_euler.advance_driver, made))
    monkeypatch.setattr(guard, "element_measure_call", recording(guard.element_measure_call, made))
    assert simulate(prepared, tmp_path / "run.h5").status == "complete"
    assert len(ahead) == (3 if model.blocks.measure_prefetch else 2)
    assert made == set(ahead)


def test_the_benchmarks_compile_ahead_the_steps_their_runners_take(monkeypatch):
    """``benchmarks.timing.interleaved`` hands ``compile_shared`` its softsim runners' step calls
    (``Softsim.step_calls``) before it times them: the calls those runners then make, here a float64
    and a float32 beam as the suite's precision section times them."""
    from benchmarks import timing
    from benchmarks.beam import Softsim, prepared_beam

    made, ahead = set(), []

    def record_shared(calls):
        ahead.extend((kernel, compile_ahead.argument_types(kernel, arguments)) for kernel, arguments in calls)
        return 0

    runners = {p: Softsim(prepared_beam(1_000, precision=p)) for p in ("float64", "float32")}
    monkeypatch.setattr(compile_ahead, "compile_shared", record_shared)
    monkeypatch.setattr(symplectic_euler, "advance_driver", recording(symplectic_euler.advance_driver, made))
    rates = timing.interleaved(runners, 0.001, 1)
    assert all(rate[0] > 0.0 for rate in rates.values())
    assert len(ahead) == 2 and ahead[0] != ahead[1]
    assert made == set(ahead)
