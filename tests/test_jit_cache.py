"""Numba's on-disk cache: a second process runs the step loop without recompiling it."""

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import numpy as np
    from softsim.config import parse_scene
    from softsim.integrators.symplectic_euler import advance
    from softsim.model import initial_state
    from softsim.simulation import prepare, step

    scene = parse_scene({
        "mesh": {"shape": "box", "size": [1, 1, 1], "element_size": 0.5, "structured": True},
        "material": {"model": "stvk", "youngs_modulus": 1e5, "poissons_ratio": 0.3, "density": 1000},
    })
    prepared = prepare(scene)
    state = initial_state(scene, prepared.model)
    step(prepared.model, state, prepared.plan.dt, 3, 0.0, np.empty((prepared.model.tet_count, 4, 3)))
    print(sum(advance.stats.cache_hits.values()), sum(advance.stats.cache_misses.values()))
""")


def _hits_and_misses():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True).stdout
    hits, misses = map(int, out.split()[-2:])
    return hits, misses


def test_second_process_loads_the_step_loop_from_cache():
    _hits_and_misses()                      # compiles (or already cached by an earlier run)
    hits, misses = _hits_and_misses()
    assert (hits, misses) == (1, 0)
