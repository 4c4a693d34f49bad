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


# --- Meshes under fire: mutated tetrahedral meshes and non-meshes given as `shape: file`. ---

MESH_FORMATS = [("msh", "gmsh22"), ("vtu", "vtu"), ("vtk", "vtk"), ("mesh", "medit")]


def base_mesh():
    from softsim.mesh.generate import structured_box

    return structured_box((0.2, 0.1, 0.1), (0.0, 0.0, 0.0), 0.05)


@st.composite
def mutated_meshes(draw):
    """(points, cell blocks) of a small box mesh after 1-3 random mutations."""
    points, tets = (np.array(a) for a in base_mesh())
    blocks = {}
    for _ in range(draw(st.integers(min_value=1, max_value=3))):
        n, m = len(points), len(tets)
        kind = draw(st.sampled_from(["duplicate", "unreferenced", "flat", "inverted", "repeated_index",
                                     "out_of_range", "non_finite", "scale", "mixed", "empty", "duplicate_tet"]))
        picks = draw(st.lists(st.integers(0, max(m - 1, 0)), min_size=1, max_size=4)) if m else []
        if m and (tets.min() < 0 or tets.max() >= n):
            continue       # an earlier mutation broke the indices: nothing more to build on them
        if kind == "duplicate" and m:        # split vertices: copies that some tets use instead
            for t in picks:
                corner = draw(st.integers(0, 3))
                points = np.vstack([points, points[tets[t, corner]]])
                tets[t, corner] = len(points) - 1
        elif kind == "unreferenced":
            extra = draw(st.integers(1, 5))
            points = np.vstack([points, np.full((extra, 3), draw(st.sampled_from([0.0, 1.0, -3.0, 1e6])))])
        elif kind == "flat" and m:           # a corner moved onto the plane of the other three
            for t in picks:
                a, b, c, _ = tets[t]
                points = np.vstack([points, (points[a] + points[b] + points[c]) / 3.0])
                tets[t, 3] = len(points) - 1
        elif kind == "inverted" and m:
            tets[picks, 0], tets[picks, 1] = tets[picks, 1].copy(), tets[picks, 0].copy()
        elif kind == "repeated_index" and m:
            tets[picks, 1] = tets[picks, 0]
        elif kind == "out_of_range" and m:
            tets[picks[0], draw(st.integers(0, 3))] = draw(st.sampled_from([n, n + 7, -1, 2**31 - 1]))
        elif kind == "non_finite":
            points[draw(st.integers(0, n - 1)), draw(st.integers(0, 2))] = draw(st.sampled_from([np.nan, np.inf]))
        elif kind == "scale":
            points = points * draw(st.sampled_from([1e-12, 1e-6, 1e6, 1e12]))
        elif kind == "mixed" and m:          # other cell types beside the tets
            cell_type = draw(st.sampled_from(["triangle", "line", "vertex", "hexahedron"]))
            width = {"triangle": 3, "line": 2, "vertex": 1, "hexahedron": 8}[cell_type]
            blocks[cell_type] = np.array([np.arange(width) % n for _ in range(draw(st.integers(1, 3)))])
        elif kind == "empty":
            tets = tets[:0]
        elif kind == "duplicate_tet" and m:
            tets = np.vstack([tets, tets[picks]])
    blocks["tetra"] = tets
    return points, blocks


def write_mesh(path, points, blocks, file_format):
    """The mesh file, or None when meshio itself cannot write it (then there is nothing to test)."""
    import meshio

    cells = [(name, np.asarray(cells, dtype=np.int64)) for name, cells in blocks.items() if len(cells)]
    try:
        meshio.write(path, meshio.Mesh(points, cells), file_format=file_format)
    except Exception:
        return None
    return path


def mesh_scene(mesh_name):
    scene = yaml.safe_load(yaml.safe_dump(BASE))
    scene["mesh"] = {"shape": "file", "file": mesh_name}
    return yaml.safe_dump(scene)


@settings(max_examples=max(20, EXAMPLES // 3), deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(mesh=mutated_meshes(), form=st.sampled_from(MESH_FORMATS))
def test_mutated_meshes_run_or_are_refused_in_one_line(tmp_path, mesh, form):
    extension, file_format = form
    name = f"mesh.{extension}"
    if write_mesh(tmp_path / name, *mesh, file_format) is None:
        return
    outcome = run_front_door(tmp_path, mesh_scene(name))
    if outcome == "ran":
        import h5py

        with h5py.File(tmp_path / "out.h5") as f:
            assert f.attrs["status"] == "complete"
            assert f["mesh/points"].shape[0] == len(mesh[0])   # every vertex kept, in the user's order


@settings(max_examples=max(20, EXAMPLES // 5), deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=st.one_of(st.binary(max_size=200), st.text(max_size=200).map(str.encode)),
       form=st.sampled_from(MESH_FORMATS), truncate=st.booleans())
def test_files_that_are_not_meshes_are_refused_in_one_line(tmp_path, content, form, truncate):
    extension, file_format = form
    name = f"mesh.{extension}"
    if truncate:       # a real mesh file cut short
        points, tets = base_mesh()
        write_mesh(tmp_path / name, np.asarray(points), {"tetra": np.asarray(tets)}, file_format)
        data = (tmp_path / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) * (1 + len(content) % 9) // 10])
    else:
        (tmp_path / name).write_bytes(content)
    outcome = run_front_door(tmp_path, mesh_scene(name))
    assert outcome not in ("ran", "prepared")
