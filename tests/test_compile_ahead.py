"""Compiling the step in a helper process (``kernels.compile_ahead``): the helper fills Numba's
disk cache with what this process then loads instead of compiling, for the very argument types
the step calls with; and a helper that fails costs nothing but its time."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from softsim.integrators import symplectic_euler
from softsim.integrators.symplectic_euler import advance_driver, work_buffer
from softsim.kernels import blocked, compile_ahead
from softsim.model import initial_state
from softsim.simulation import prepare, step, step_calls

# A fresh process with a cache of its own (Numba reads NUMBA_CACHE_DIR as it loads): submits
# ``kinetic_energy`` for float32 arrays, which nothing else compiles, then calls it and prints
# what it saw.  HELPER_FATE: "wait" for the helper, or "kill" it first.
PROBE = textwrap.dedent("""
    import numpy as np
    from numba.core import event
    from softsim.kernels import blocked, compile_ahead
    from softsim.kernels.energy import kinetic_energy

    v = np.arange(12, dtype=np.float32).reshape(4, 3)
    mass = np.full(4, 2.0, dtype=np.float32)
    signature = compile_ahead.argument_types(kinetic_energy, (v, mass))
    cached_before = compile_ahead.is_compiled_or_cached(kinetic_energy, signature)
    handed = compile_ahead.submit([(kinetic_energy, (v, mass))])
    if "{fate}" == "kill" and handed:
        compile_ahead._helper.process.kill()
    compile_ahead.wait()
    cached_after = compile_ahead.is_compiled_or_cached(kinetic_energy, signature)
    with event.install_listener("numba:compile", event.TimingListener()) as listener:
        energy = kinetic_energy(v, mass)
    print(cached_before, handed, cached_after, listener.done, energy)
""")


def run_probe(tmp_path, fate="wait", switch="1"):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), compile_ahead.ENVIRONMENT_SWITCH: switch}
    out = subprocess.run([sys.executable, "-c", PROBE.format(fate=fate)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    cached_before, handed, cached_after, compiled_here, energy = out.stdout.split()
    return cached_before == "True", int(handed), cached_after == "True", compiled_here == "True", float(energy)


EXPECTED_ENERGY = 0.5 * 2.0 * float(np.sum(np.arange(12.0) ** 2))


@pytest.mark.skipif(compile_ahead.available_cores() < 2, reason="no helper starts on one core")
def test_the_helper_fills_the_cache_and_this_process_compiles_nothing(tmp_path):
    cached_before, handed, cached_after, compiled_here, energy = run_probe(tmp_path)
    assert not cached_before and handed == 1 and cached_after
    assert not compiled_here
    assert energy == EXPECTED_ENERGY


def test_switched_off_no_helper_starts_and_this_process_compiles(tmp_path):
    cached_before, handed, cached_after, compiled_here, energy = run_probe(tmp_path, switch="0")
    assert not cached_before and handed == 0 and not cached_after
    assert compiled_here
    assert energy == EXPECTED_ENERGY


@pytest.mark.skipif(compile_ahead.available_cores() < 2, reason="no helper starts on one core")
def test_a_helper_that_dies_leaves_this_process_to_compile(tmp_path):
    _, handed, _, compiled_here, energy = run_probe(tmp_path, fate="kill")
    assert handed == 1
    assert compiled_here
    assert energy == EXPECTED_ENERGY


@pytest.mark.parametrize("overrides", [
    {},
    "prefetch measured",
    {"precision": "float32", "damping": 1.0, "ground": {"height": -0.01},
     "material": {"model": "neohookean"}},
    {"tractions": [{"min": [0.2 - 1e-6, -1, -1], "max": [1, 1, 1], "traction": [0.0, 0.0, -100.0]}],
     "fixed": [{"min": [-1, -1, -1], "max": [1e-6, 1, 1], "velocity": [0.0, 0.0, 0.1]}]},
])
def test_the_step_calls_compiled_ahead_are_the_calls_the_step_makes(scene, monkeypatch, overrides):
    """The helper compiles the step for the argument types of ``step_calls``: the types the step
    then calls its driver with (else the helper's work would be lost)."""
    made = []

    def recording_driver(*arguments):
        driver, driver_arguments = advance_driver(*arguments)
        made.append((driver, compile_ahead.argument_types(driver, driver_arguments)))
        return driver, driver_arguments

    if overrides == "prefetch measured":     # as a large mesh's step: timed with prefetches and without
        monkeypatch.setattr(blocked, "PREFETCH_FROM_BYTES", 0)
        overrides = {}
    prepared = prepare(scene(**overrides))
    model = prepared.model
    assert model.blocks.measure_prefetch == (blocked.PREFETCH_FROM_BYTES == 0)
    ahead = [(driver, compile_ahead.argument_types(driver, arguments))
             for driver, arguments in step_calls(prepared.scene, model)]
    monkeypatch.setattr(symplectic_euler, "advance_driver", recording_driver)
    state = initial_state(prepared.scene, model)
    step(model, state, prepared.plan.dt, 2, prepared.scene.damping, work_buffer(model))
    assert len(made) == len(ahead) == (2 if model.blocks.measure_prefetch else 1)
    assert set(made) == set(ahead)
