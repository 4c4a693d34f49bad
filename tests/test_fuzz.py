"""The front door under fire: random and mutated scene files either run or are refused with one
line naming what is wrong; nothing raises an unhandled exception.

Quick in CI (``SOFTSIM_FUZZ_EXAMPLES``, default 150 examples); e.g. ``SOFTSIM_FUZZ_EXAMPLES=2000``
for a long run.
"""

import math
import os

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softsim.config import load_scene
from softsim.errors import SoftsimError
from softsim.simulation import prepare, simulate

EXAMPLES = int(os.environ.get("SOFTSIM_FUZZ_EXAMPLES", "150"))
# Runs bigger than this (tets x steps) are prepared but not simulated, to keep the test quick.
MAX_WORK = 2e6

BASE = {
    "mesh": {"shape": "box", "size": [0.2, 0.1, 0.1], "origin": [0.0, 0.0, 0.0], "element_size": 0.05,
             "structured": True},
    "material": {"model": "stvk", "youngs_modulus": 1.0e6, "poissons_ratio": 0.3, "density": 1000.0},
    "damping": 0.5,
    "gravity": [0.0, 0.0, -9.81],
    "fixed": [{"min": [-1.0e-6, -1, -1], "max": [1.0e-6, 1, 1], "axes": ["x", "y"], "velocity": [0, 0, 0]}],
    "tractions": [{"min": [0.199, -1, -1], "max": [0.201, 1, 1], "traction": [1.0e3, 0, 0]}],
    "initial_deformation": {"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [0, 0, 0]},
    "initial_velocity": [0, 0, 0],
    "angular_velocity": [0, 0, 0],
    "ground": {"height": -0.1, "stiffness": 1.0e6, "friction": 0.3},
    "time": {"duration": 0.003, "dt": "auto", "dt_policy": "substep"},
    "output": {"frame_interval": 0.001, "fields": ["velocities", "energy"]},
}

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, 0.5, -1.0, 2.0, 1e-9, 1e9]),
    st.integers(min_value=-10**6, max_value=10**6),
)
values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8),
              st.sampled_from(["auto", "exact", "box", "file", "x", "neohookean", "velocities"])),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(st.text(max_size=6), children, max_size=3)),
    max_leaves=6,
)


def leaf_paths(node, prefix=()):
    """Every path (tuple of keys / indices) into ``node``, containers included."""
    yield prefix
    if isinstance(node, dict):
        for key, child in node.items():
            yield from leaf_paths(child, prefix + (key,))
    elif isinstance(node, list):
        for i, child in enumerate(node):
            yield from leaf_paths(child, prefix + (i,))


PATHS = [p for p in leaf_paths(BASE) if p]


@st.composite
def mutated_scenes(draw):
    scene = yaml.safe_load(yaml.safe_dump(BASE))
    for _ in range(draw(st.integers(min_value=1, max_value=3))):
        path = draw(st.sampled_from(PATHS))
        parent = scene
        try:
            for key in path[:-1]:
                parent = parent[key]
            action = draw(st.sampled_from(["replace", "replace", "delete", "unknown"]))
            if action == "replace":
                parent[path[-1]] = draw(values)
            elif action == "delete":
                del parent[path[-1]]
            elif isinstance(parent, dict):
                parent[draw(st.text(min_size=1, max_size=8))] = draw(values)
        except (KeyError, IndexError, TypeError):
            pass      # an earlier mutation changed the shape under this path
    return scene


def run_front_door(tmp_path, document):
    """load -> prepare -> (small enough) simulate; returns 'ran', 'prepared' or the error line."""
    path = tmp_path / "scene.yaml"
    path.write_text(document)
    try:
        scene = load_scene(path)
        prepared = prepare(scene)
        if prepared.model.tet_count * prepared.plan.total_steps * prepared.substeps > MAX_WORK:
            return "prepared"
        simulate(prepared, tmp_path / "out.h5")
        return "ran"
    except SoftsimError as exc:
        message = str(exc)
        assert message and "\n" not in message and "Traceback" not in message, message
        return message


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(scene=mutated_scenes())
def test_mutated_scenes_run_or_are_refused_in_one_line(tmp_path, scene):
    outcome = run_front_door(tmp_path, yaml.safe_dump(scene, allow_unicode=True))
    if outcome == "ran":
        import h5py

        with h5py.File(tmp_path / "out.h5") as f:
            assert f.attrs["status"] == "complete"
            assert np.isfinite(f["frames/points"][...]).all()


@settings(max_examples=max(20, EXAMPLES // 5), deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(document=st.one_of(st.text(max_size=60), values.map(lambda v: yaml.safe_dump(v))))
def test_arbitrary_documents_are_refused_in_one_line(tmp_path, document):
    outcome = run_front_door(tmp_path, document)
    assert outcome not in ("ran", "prepared")


def test_the_unmutated_base_scene_runs(tmp_path):
    assert run_front_door(tmp_path, yaml.safe_dump(BASE)) == "ran"
