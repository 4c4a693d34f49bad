"""Shared fixtures: a factory for small, valid scenes built through the real schema.

``scene(**overrides)`` returns a validated ``softsim.config.Scene`` for a tiny structured cube
(0.2 m, 2 x 2 x 2 hex cells = 40 tets, soft rubber-like stvk) with every other key at the schema's
default.  Keyword arguments are section names; a mapping is merged into that section (nested
mappings recursively), anything else replaces it, and ``None`` removes the key so the schema's
default applies again::

    scene(material={"model": "linear"}, gravity=[0, 0, 0], ground={"height": 0.0})
    scene(mesh={"size": [1.0, 0.2, 0.2]}, time={"dt": 1e-4})

Relative ``mesh.file`` paths are resolved against the test's ``tmp_path``.
"""

import copy
import os

import pytest

# The tests run in two worker processes on two cores: a helper compiling a run's kernels beside
# each (``kernels.compile_ahead``) would find no idle core.  Its own tests switch it on.
os.environ.setdefault("SOFTSIM_COMPILE_AHEAD", "0")

from softsim.config import parse_scene  # noqa: E402  (after the switch, before softsim is imported)

BASE_SCENE = {
    "mesh": {"shape": "box", "size": [0.2, 0.2, 0.2], "element_size": 0.1, "structured": True},
    "material": {"model": "stvk", "youngs_modulus": 1.0e5, "poissons_ratio": 0.3, "density": 1000.0},
}


def merge(base, overrides):
    """``base`` (a dict) with ``overrides`` merged in: mappings recursively, ``None`` deletes."""
    result = copy.deepcopy(base)
    for key, value in overrides.items():
        if value is None:
            result.pop(key, None)
        elif isinstance(value, dict) and isinstance(result.get(key), dict):
            result[key] = merge(result[key], value)
        else:
            result[key] = copy.deepcopy(value)
    return result


def scene_dict(**overrides):
    """The raw scene mapping of ``BASE_SCENE`` with ``overrides`` merged in (see module doc)."""
    return merge(BASE_SCENE, overrides)


@pytest.fixture
def scene(tmp_path):
    """Factory ``scene(**overrides) -> Scene`` (validated by ``parse_scene``, base dir ``tmp_path``)."""

    def make(**overrides):
        return parse_scene(scene_dict(**overrides), base_dir=tmp_path)

    return make


@pytest.fixture(autouse=True)
def no_written_file_holds_non_finite_values(request):
    """After every test that used ``tmp_path``: every HDF5 file under it holds only finite numbers,
    in its frames written so far (a killed run's file has rows allocated for every planned frame:
    reading them all took 12 s after a test that killed a run planned for a million frames)."""
    yield
    tmp = request.node.funcargs.get("tmp_path")
    if tmp is None:
        return
    import h5py
    import numpy as np

    from softsim.io.hdf5 import frames_written

    def check(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind == "f" and obj.size:
            data = obj[:frames] if frames is not None and name.startswith("frames/") else obj[...]
            assert np.isfinite(data).all(), f"{path}:{name} holds non-finite values"

    for path in tmp.rglob("*.h5"):
        try:
            f = h5py.File(path, "r")
        except OSError:
            continue   # a test's deliberately broken or foreign file
        with f:
            try:
                frames = frames_written(f) if "frames" in f else None
            except (KeyError, OSError, ValueError):
                frames = None                     # not a run file softsim can read: every row
            f.visititems(check)


def pytest_collection_modifyitems(config, items):
    """Tests marked ``slow`` (pyproject's marker) run only with SOFTSIM_SLOW=1: more variants of a
    check that CI runs in one or two, each compiling a step of its own."""
    if os.environ.get("SOFTSIM_SLOW"):
        return
    skip = pytest.mark.skip(reason="slow: set SOFTSIM_SLOW=1")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
