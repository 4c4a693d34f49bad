"""Meshing, reading and checking tetrahedral meshes; locality renumbering; the quality summary.

Geometric expectations (volumes, areas, angles) are computed here from the shapes' formulas.
"""

import dataclasses
import logging
import math
import re
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest

from softsim.errors import MeshError
from softsim.mesh import build_mesh, checked_mesh
from softsim.mesh.checks import PACKED_FACE_KEY_LIMIT, boundary_faces, face_groups
from softsim.mesh.generate import structured_box
from softsim.model import build_model, initial_state
from softsim.simulation import prepare, simulate, step

EDGES = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
FACES = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]   # face k is opposite corner k


def volumes(points, tets):
    """Signed volumes det[x1-x0, x2-x0, x3-x0] / 6, computed independently of softsim."""
    X = points[tets]
    return np.einsum("ij,ij->i", np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), X[:, 3] - X[:, 0]) / 6.0


def edge_lengths(points, tets):
    """Lengths of the distinct edges of the mesh."""
    pairs = np.unique(np.sort(np.concatenate([tets[:, list(e)] for e in EDGES]), axis=1), axis=0)
    return np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)


def triangle_areas(points, faces):
    p = points[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def faces_with_opposite(tets):
    """Every face as a sorted triple, with the tet and its fourth (opposite) vertex."""
    keys, owners, opposite = [], [], []
    for k, face in enumerate(FACES):
        keys.append(np.sort(tets[:, face], axis=1))
        owners.append(np.arange(len(tets)))
        opposite.append(tets[:, k])
    return np.concatenate(keys), np.concatenate(owners), np.concatenate(opposite)


def assert_conforming(points, tets):
    """Each face is shared by one tet (boundary) or two tets lying on opposite sides of it."""
    keys, owners, opposite = faces_with_opposite(tets)
    unique, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    assert counts.max() <= 2
    for f in np.flatnonzero(counts == 2):
        a, b = np.flatnonzero(inverse == f)
        p0, p1, p2 = points[unique[f]]
        normal = np.cross(p1 - p0, p2 - p0)
        side_a = np.dot(points[opposite[a]] - p0, normal)
        side_b = np.dot(points[opposite[b]] - p0, normal)
        assert side_a * side_b < 0, f"tets {owners[a]}, {owners[b]} on the same side of a face"
    return unique[counts == 1]


# ---------------------------------------------------------------------------------------------
# structured_box


@pytest.mark.parametrize("size, origin, h", [
    ((0.3, 0.2, 0.1), (0.0, 0.0, 0.0), 0.1),
    ((0.4, 0.3, 0.25), (-1.0, 2.0, 0.5), 0.1),       # 0.25 / 0.1 rounds to 2 cells of 0.125
    ((0.1, 0.1, 0.1), (0.0, 0.0, 0.0), 0.5),          # one cell
])
def test_structured_box_is_a_positive_conforming_filling_of_the_box(size, origin, h):
    points, tets = structured_box(size, origin, h)
    size, origin = np.asarray(size), np.asarray(origin)
    cells = np.maximum(1, np.rint(size / h).astype(int))
    assert len(points) == np.prod(cells + 1)
    assert len(tets) == 5 * np.prod(cells)
    V = volumes(points, tets)
    assert (V > 0).all()
    assert V.sum() == pytest.approx(np.prod(size), rel=1e-12)
    np.testing.assert_allclose(points.min(axis=0), origin, atol=1e-15)
    np.testing.assert_allclose(points.max(axis=0), origin + size, rtol=1e-15)

    boundary = assert_conforming(points, tets)
    surface = 2 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2])
    assert triangle_areas(points, boundary).sum() == pytest.approx(surface, rel=1e-12)
    # softsim's own boundary extraction agrees, and winds every face outward.
    outward = boundary_faces(tets)
    assert len(outward) == len(boundary)
    assert triangle_areas(points, outward).sum() == pytest.approx(surface, rel=1e-12)
    p = points[outward]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    centre = origin + size / 2
    assert (np.einsum("ij,ij->i", normals, p.mean(axis=1) - centre) > 0).all()
    # Every boundary face lies in a face plane of the box.
    on_plane = [(np.abs(p[:, :, d] - origin[d]) < 1e-12).all(axis=1)
                | (np.abs(p[:, :, d] - origin[d] - size[d]) < 1e-12).all(axis=1) for d in range(3)]
    assert np.logical_or.reduce(on_plane).all()


def test_structured_box_alternates_the_split_between_neighbouring_cells():
    """The 5-tet split of a cube: 4 corner tets (1/6 of the cell each) around one central regular
    tet (1/3) whose corners are every other cube corner.  Neighbouring cells use the two opposite
    sets of alternate corners (mirrored splits), like a 3D checkerboard."""
    h = 0.1
    points, tets = structured_box((0.3, 0.3, 0.2), (0.0, 0.0, 0.0), h)
    V = volumes(points, tets)
    centroid = points[tets].mean(axis=1)
    cell_of_tet = np.floor(centroid / h + 1e-9).astype(int)
    local_parity = {}     # which set of alternate corners (by local corner parity) the central tet uses
    for cell in {tuple(c) for c in cell_of_tet}:
        mine = (cell_of_tet == cell).all(axis=1)
        assert mine.sum() == 5
        np.testing.assert_allclose(np.sort(V[mine]), [h**3 / 6] * 4 + [h**3 / 3], rtol=1e-10)
        central = tets[mine][np.argmax(V[mine])]
        local = np.rint(points[central] / h).astype(int) - np.array(cell)   # corners as 0/1 offsets
        assert ((local == 0) | (local == 1)).all()
        parities = local.sum(axis=1) % 2
        assert len(set(parities)) == 1           # alternate corners of the cube
        local_parity[cell] = parities[0]
    assert len(local_parity) == 3 * 3 * 2
    # Mirrored neighbours: across every shared cell face the split flips.
    pairs = 0
    for cell, parity in local_parity.items():
        for d in range(3):
            neighbour = tuple(c + (k == d) for k, c in enumerate(cell))
            if neighbour in local_parity:
                assert local_parity[neighbour] != parity, (cell, neighbour)
                pairs += 1
    assert pairs == 2 * 3 * 2 + 3 * 2 * 2 + 3 * 3 * 1


# ---------------------------------------------------------------------------------------------
# gmsh primitives


@pytest.mark.parametrize("spec, exact_volume, on_surface", [
    ({"shape": "box", "size": [0.3, 0.2, 0.15], "origin": [1.0, 2.0, 3.0], "element_size": 0.04},
     0.3 * 0.2 * 0.15,
     lambda p: np.logical_or.reduce([np.isclose(p[:, d], lo, atol=1e-12) | np.isclose(p[:, d], hi, atol=1e-12)
                                     for d, (lo, hi) in enumerate([(1.0, 1.3), (2.0, 2.2), (3.0, 3.15)])])),
    ({"shape": "cylinder", "radius": 0.1, "length": 0.4, "axis": "y", "origin": [1.0, 2.0, 3.0],
      "element_size": 0.04},
     math.pi * 0.1**2 * 0.4,
     lambda p: np.isclose(np.hypot(p[:, 0] - 1.0, p[:, 2] - 3.0), 0.1, atol=1e-12)
     | np.isclose(p[:, 1], 2.0, atol=1e-12) | np.isclose(p[:, 1], 2.4, atol=1e-12)),
    ({"shape": "sphere", "radius": 0.1, "origin": [1.0, 2.0, 3.0], "element_size": 0.04},
     4.0 / 3.0 * math.pi * 0.1**3,
     lambda p: np.isclose(np.linalg.norm(p - [1.0, 2.0, 3.0], axis=1), 0.1, atol=1e-12)),
])
def test_gmsh_primitives(scene, spec, exact_volume, on_surface):
    mesh = build_mesh(_scene_with_mesh(scene, spec).mesh)
    h = spec["element_size"]
    V = volumes(mesh.points, mesh.tets)
    assert (V > 0).all()
    total = V.sum()
    if spec["shape"] == "box":
        assert total == pytest.approx(exact_volume, rel=1e-12)
    else:   # flat facets inscribed in the curved surface: a little less than the exact volume
        assert 0.94 * exact_volume < total < exact_volume
    lengths = edge_lengths(mesh.points, mesh.tets)
    assert 0.7 * h < np.median(lengths) < 1.3 * h
    assert 0.2 * h < lengths.min() and lengths.max() < 2.5 * h
    boundary_vertices = np.unique(boundary_faces(mesh.tets))
    assert on_surface(mesh.points[boundary_vertices]).all()
    if spec["shape"] == "sphere":
        assert (np.linalg.norm(mesh.points - [1.0, 2.0, 3.0], axis=1) <= 0.1 * (1 + 1e-12)).all()


def test_a_mesh_file_gone_after_the_scene_loaded_is_one_line(scene, tmp_path):
    points, tets = small_mesh()
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(points, [("tetra", tets)]))
    spec = file_scene(scene, tmp_path / "m.vtu").mesh
    (tmp_path / "m.vtu").unlink()
    with pytest.raises(MeshError, match=r"^mesh.file = '.*m\.vtu': cannot be read \(No such file or directory\)$"):
        build_mesh(spec)


@pytest.mark.parametrize("spec, expected", [
    ({"shape": "cylinder", "radius": 0.01, "length": 0.3, "axis": "x", "origin": [0, 0, 0], "element_size": 0.05},
     r"mesh.element_size = 0.05: gmsh cannot mesh the cylinder of radius 0.01 m and length 0.3 m at origin "
     r"\[0, 0, 0\] m with it \(.+\); use an element_size below its smallest dimension, 0.02 m$"),
    ({"shape": "box", "size": [1, 1, 1], "origin": [1e20, 0, 0], "element_size": 0.5},
     r"mesh: gmsh cannot build the box of size \[1, 1, 1\] m at origin \[1e\+20, 0, 0\] m \(.+\)$"),
])
def test_what_gmsh_cannot_mesh_is_one_line_naming_the_keys(scene, spec, expected):
    with pytest.raises(MeshError, match=expected) as refused:
        build_mesh(_scene_with_mesh(scene, spec).mesh)
    assert "\n" not in str(refused.value)


def _scene_with_mesh(scene, spec, **overrides):
    """A scene whose ``mesh`` section is exactly ``spec`` (the factory's base keys removed)."""
    cleared = {key: None for key in ("size", "element_size", "structured", "origin")}
    return scene(mesh={**cleared, **spec}, **overrides)


# ---------------------------------------------------------------------------------------------
# Reading files


def file_scene(scene, name, **overrides):
    return _scene_with_mesh(scene, {"shape": "file", "file": str(name)}, **overrides)


def small_mesh():
    """A 2 x 1 x 1 structured box: 12 vertices, 10 positive tets."""
    return structured_box((0.2, 0.1, 0.1), (0.0, 0.0, 0.0), 0.1)


def warning_texts(caplog, tmp_path):
    """softsim's logged warnings, with the test's folder (digits in its name) cut out."""
    return [r.getMessage().replace(str(tmp_path), "<tmp>") for r in caplog.records
            if r.levelno == logging.WARNING and r.name.startswith("softsim")]


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_reading_a_file_keeps_vertices_and_tets(scene, tmp_path, suffix):
    points, tets = small_mesh()
    path = tmp_path / f"body{suffix}"
    meshio.write(path, meshio.Mesh(points, [("triangle", boundary_faces(tets)), ("tetra", tets)]))
    mesh = build_mesh(file_scene(scene, path.name).mesh)
    np.testing.assert_array_equal(mesh.points, points)
    np.testing.assert_array_equal(mesh.tets, tets)
    assert str(path) in mesh.source


def test_reversed_tets_are_reoriented_and_counted(scene, tmp_path, caplog):
    points, tets = small_mesh()
    flipped = tets.copy()
    reversed_ids = [0, 3, 7]
    flipped[reversed_ids] = flipped[reversed_ids][:, [1, 0, 2, 3]]
    assert (volumes(points, flipped)[reversed_ids] < 0).all()
    meshio.write(tmp_path / "flipped.vtu", meshio.Mesh(points, [("tetra", flipped)]))
    with caplog.at_level(logging.WARNING, logger="softsim"):
        mesh = build_mesh(file_scene(scene, "flipped.vtu").mesh)
    assert (volumes(mesh.points, mesh.tets) > 0).all()
    np.testing.assert_array_equal(np.sort(mesh.tets, axis=1), np.sort(tets, axis=1))   # same tets
    np.testing.assert_array_equal(mesh.tets[[1, 2, 4, 5, 6, 8, 9]], tets[[1, 2, 4, 5, 6, 8, 9]])
    warnings = warning_texts(caplog, tmp_path)
    assert any("orient" in w and re.search(r"\b3\b", w) for w in warnings), warnings


def test_unreferenced_vertices_are_kept_massless_and_held(scene, tmp_path, caplog):
    """A user's vertex numbers stay valid: stray vertices stay in the mesh, get no mass, and are
    held where they start, while the rest of the body moves."""
    points, tets = small_mesh()
    # Two stray vertices: one before all the others, one in the middle.
    stray = np.array([[5.0, 5.0, 5.0], [-3.0, 0.0, 0.0]])
    with_stray = np.concatenate([stray[:1], points[:6], stray[1:], points[6:]])
    index = np.concatenate([np.arange(1, 7), np.arange(8, 14)])      # old vertex -> new position
    meshio.write(tmp_path / "stray.vtu", meshio.Mesh(with_stray, [("tetra", index[tets])]))
    with caplog.at_level(logging.WARNING, logger="softsim"):
        s = file_scene(scene, "stray.vtu")
        mesh = build_mesh(s.mesh)
    np.testing.assert_array_equal(mesh.points, with_stray)
    np.testing.assert_array_equal(mesh.tets, index[tets])
    warnings = warning_texts(caplog, tmp_path)
    assert any("no tetrahedron" in w and re.search(r"\b2\b", w) for w in warnings), warnings

    model = build_model(s, mesh)
    mass = model.to_user_order(model.mass)
    assert (mass[[0, 7]] == 0.0).all() and (np.delete(mass, [0, 7]) > 0.0).all()
    assert model.mass.sum() == pytest.approx(s.material.density * volumes(points, tets).sum())
    assert not model.to_user_order(model.fixed)[[0, 7]].any()     # not reported as user-fixed
    state = initial_state(s, model)
    corner = np.empty((model.tet_count, 4, 3))
    step(model, state, 1e-5, 10, 0.0, corner)            # falls under gravity
    x = model.to_user_order(state.x)
    np.testing.assert_array_equal(x[[0, 7]], with_stray[[0, 7]])
    body = np.delete(np.arange(14), [0, 7])
    assert np.isfinite(x).all() and (x[body, 2] < with_stray[body, 2]).all()


def _mesh_error(scene, tmp_path, name, mesh=None, text=None):
    """The MeshError message from building a scene on file ``name`` (a meshio mesh or raw text),
    checked to be one line naming mesh.file and the file; returned with the folder cut out (the
    folder's name is the test's name, which must not satisfy the caller's checks)."""
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    else:
        meshio.write(path, mesh)
    with pytest.raises(MeshError) as info:
        build_mesh(file_scene(scene, name).mesh)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("mesh.file")
    assert str(path) in message
    return message.replace(str(path), "<file>")


def test_tangled_mesh_is_refused(scene, tmp_path):
    """Tets 0 and 1 share face (0, 1, 2) and both lie above it (z > 0): they overlap."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1.0], [0.3, 0.3, 0.5]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [0, 1, 2, 4]])
    assert (volumes(points, tets) > 0).all()
    message = _mesh_error(scene, tmp_path, "tangled.vtu", meshio.Mesh(points, [("tetra", tets)]))
    assert "tangled" in message
    # The same pair with one tet below the face is a valid mesh.
    points[4, 2] = -0.5
    meshio.write(tmp_path / "fine.vtu", meshio.Mesh(points, [("tetra", tets)]))
    assert build_mesh(file_scene(scene, "fine.vtu").mesh).tet_count == 2


def test_face_shared_by_three_tets_is_refused(scene, tmp_path):
    """Tets 0 (above) and 1 (below) are fine; tet 2 (above) overlaps tet 0 on face (0, 1, 2)."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1.0], [0.3, 0.3, -0.5],
                       [0.1, 0.1, 2.0]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [0, 2, 1, 4], [0, 1, 2, 5]])
    assert "tangled" in _mesh_error(scene, tmp_path, "three.vtu", meshio.Mesh(points, [("tetra", tets)]))


def test_degenerate_tet_is_refused(scene, tmp_path):
    """A valid mesh plus one flat tet (four coplanar vertices of its own, touching nothing else)."""
    points, tets = small_mesh()
    flat_points = np.array([[1.0, 0, 0], [1.1, 0, 0], [1.0, 0.1, 0], [1.05, 0.05, 0.0]])
    flat = np.arange(len(points), len(points) + 4)[None, :]
    mesh = meshio.Mesh(np.concatenate([points, flat_points]), [("tetra", np.concatenate([tets, flat]))])
    message = _mesh_error(scene, tmp_path, "flat.vtu", mesh)
    assert "degenerate" in message and "allowed" in message


@pytest.mark.parametrize("case", ["no tets", "not a mesh", "hexahedra"])
def test_unusable_files_get_one_line_errors_naming_mesh_file(scene, tmp_path, case):
    points, tets = small_mesh()
    if case == "no tets":
        message = _mesh_error(scene, tmp_path, "surface.vtu",
                              meshio.Mesh(points, [("triangle", boundary_faces(tets))]))
        assert "tetrahedra" in message
    elif case == "not a mesh":
        message = _mesh_error(scene, tmp_path, "notes.msh", text="these are my notes, not a mesh\n")
        assert "mesh" in message.replace("mesh.file", "")
    else:
        hexahedron = np.array([[0, 1, 3, 2, 6, 7, 9, 8]])
        message = _mesh_error(scene, tmp_path, "mixed.vtu",
                              meshio.Mesh(points, [("tetra", tets), ("hexahedron", hexahedron)]))
        assert "hexahedron" in message


# ---------------------------------------------------------------------------------------------
# Renumbering for locality


def shuffled_box(cells=4, seed=3):
    """A cells^3 structured box of 0.1 m cells, its vertices and tets numbered at random."""
    points, tets = structured_box((0.1 * cells,) * 3, (0.0, 0.0, 0.0), 0.1)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(points))               # new vertex k is old vertex order[k]
    new_index = np.empty_like(order)
    new_index[order] = np.arange(len(order))
    tets = new_index[tets][rng.permutation(len(tets))]
    return points[order], tets


def mean_index_gap(tets):
    """Mean |i - j| over the edges of every tet."""
    return np.mean([np.abs(tets[:, a] - tets[:, b]).mean() for a, b in EDGES])


def test_renumbering_keeps_the_users_order_and_improves_locality(scene):
    points, tets = shuffled_box(cells=8)
    mesh = checked_mesh(points, tets, "shuffled")
    model = build_model(scene(), mesh)
    # The user's order comes back exactly.
    np.testing.assert_array_equal(model.to_user_order(model.rest_points), mesh.points)
    np.testing.assert_array_equal(model.from_user_order(mesh.points), model.rest_points)
    # Internally the same tets (same winding), only renumbered and reordered.
    in_user_numbers = model.vertex_order[model.tets]
    as_rows = lambda t: t[np.lexsort(t.T[::-1])]      # noqa: E731
    np.testing.assert_array_equal(as_rows(in_user_numbers), as_rows(mesh.tets))
    assert (volumes(model.rest_points, model.tets) > 0).all()
    # Locality: vertices of a tet get close numbers (a random numbering averages n / 3; a
    # space-filling curve or RCM gets ~ n^(2/3)), and tets are stored in order of their vertices.
    assert mean_index_gap(model.tets) < 0.25 * mean_index_gap(mesh.tets)
    first_vertex = model.tets.min(axis=1)
    assert (np.diff(first_vertex) >= 0).all()


@pytest.mark.parametrize("shuffled", [True, False])
def test_the_model_takes_the_boundary_the_mesh_check_found_renumbered(scene, shuffled):
    """The boundary faces found when the mesh was checked, renumbered with the tets, are the model's:
    the same faces, in the same order, with the same tets, as finding them again on its tets."""
    points, tets = shuffled_box(cells=8) if shuffled else structured_box((0.3, 0.1, 0.1), (0, 0, 0), 0.05)
    mesh = checked_mesh(points, tets, "box")
    assert mesh.boundary_slots is not None
    model = build_model(scene(), mesh)
    faces, face_tets = boundary_faces(model.tets, with_tets=True)
    np.testing.assert_array_equal(model.boundary_faces, faces)
    again = build_model(scene(), dataclasses.replace(mesh, boundary_slots=None))     # found on the model's tets
    np.testing.assert_array_equal(again.boundary_faces, faces)
    np.testing.assert_array_equal(again.boundary_area, model.boundary_area)
    # each part's faces (the ground's contact areas) come from the faces' tets
    np.testing.assert_array_equal(again.part_face_offsets, model.part_face_offsets)
    np.testing.assert_array_equal(again.part_faces, model.part_faces)
    assert again.part_faces.shape == (len(face_tets), 3)


def test_output_file_uses_the_users_vertex_numbers(scene, tmp_path):
    """A shuffled file mesh, stretched at t = 0: frame 0 is A X + b in the file's vertex order."""
    points, tets = shuffled_box()
    meshio.write(tmp_path / "shuffled.vtu", meshio.Mesh(points, [("tetra", tets)]))
    A = np.array([[1.1, 0.0, 0.0], [0.05, 1.0, 0.0], [0.0, 0.0, 0.9]])
    b = np.array([0.0, 0.0, 1.0])
    s = file_scene(scene, "shuffled.vtu", time={"duration": 0.002},
                   initial_deformation={"matrix": A.tolist(), "translation": b.tolist()})
    simulate(prepare(s), tmp_path / "out.h5")
    with h5py.File(tmp_path / "out.h5", "r") as f:
        np.testing.assert_array_equal(f["mesh/points"][:], points)
        np.testing.assert_array_equal(f["mesh/tets"][:], tets)
        np.testing.assert_allclose(f["frames/points"][0], points @ A.T + b, rtol=0, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Quality summary


def test_quality_summary_of_a_structured_cube_grid(scene):
    """Cubic cells of edge a split into 5 tets:
    - corner tets (trirectangular at a cube corner): right dihedral angles along the three cube
      edges, and arccos(1/sqrt 3) = 54.74 deg between each cube face and the diagonal face;
      altitudes a (onto the cube faces) and a / sqrt 3 (corner to the plane x + y + z = a);
    - the central regular tet of edge a sqrt 2: dihedral arccos(1/3) = 70.53 deg, altitude
      a sqrt 2 sqrt(2/3) = 2a / sqrt 3.
    So the range is arccos(1/sqrt 3) .. 90 deg and the smallest altitude a / sqrt 3."""
    a = 0.05
    mesh = build_mesh(scene(mesh={"size": [0.2, 0.1, 0.15], "element_size": a, "structured": True}).mesh)
    q = mesh.quality()
    assert q["tets"] == 5 * 4 * 2 * 3
    assert q["vertices"] == 5 * 3 * 4
    assert q["min_dihedral_deg"] == pytest.approx(math.degrees(math.acos(1 / math.sqrt(3))), abs=1e-9)
    assert q["max_dihedral_deg"] == pytest.approx(90.0, abs=1e-9)
    assert q["min_altitude_m"] == pytest.approx(a / math.sqrt(3), rel=1e-12)


@pytest.mark.parametrize("offset", [0, PACKED_FACE_KEY_LIMIT])
def test_face_groups_number_the_distinct_triples_as_unique_does(offset):
    """``face_groups`` on sorted triples with repeats, indices small enough to pack into one key
    (offset 0) and too large (the lexicographic sort): the same grouping and counts as
    ``np.unique(axis=0)``, up to the numbering of the groups."""
    rng = np.random.default_rng(3)
    triples = np.sort(rng.integers(0, 40, size=(5000, 3)), axis=1) + offset
    triples[::7, 2] = triples[::7, 1]                     # some repeated vertices too
    inverse, counts = face_groups(triples[:, 0].copy(), triples[:, 1].copy(), triples[:, 2].copy())
    _, unique_inverse, unique_counts = np.unique(triples, axis=0, return_inverse=True, return_counts=True)
    unique_inverse = unique_inverse.ravel()
    assert counts.sum() == len(triples) and sorted(counts) == sorted(unique_counts)
    pairs = set(zip(inverse.tolist(), unique_inverse.tolist()))
    assert len(pairs) == len(counts) == len(unique_counts)    # one group of each for the other's
    assert np.array_equal(counts[inverse], unique_counts[unique_inverse])


def test_quality_summary_matches_numpy_on_a_distorted_mesh():
    """The compiled pass (``kernels.tet_shape``) against NumPy on a randomly distorted box: the
    dihedral range from ``dihedral_angles``, the altitude from 3 V / largest face area."""
    from softsim.mesh.quality import dihedral_angles, face_normals, quality_summary

    points, tets = structured_box((4.0, 3.0, 2.0), (0.0, 0.0, 0.0), 1.0)
    points = points + 0.15 * np.random.default_rng(5).normal(size=points.shape)
    summary = quality_summary(points, tets)
    angles = dihedral_angles(points, tets)
    X = points[tets]
    volume = np.abs(np.linalg.det(X[:, 1:] - X[:, :1])) / 6.0
    altitude = 3.0 * volume / np.linalg.norm(face_normals(points, tets), axis=2).max(axis=1)
    assert summary["tets"] == len(tets) and summary["vertices"] == len(points)
    assert summary["min_dihedral_deg"] == pytest.approx(angles.min(), rel=1e-12)
    assert summary["max_dihedral_deg"] == pytest.approx(angles.max(), rel=1e-12)
    assert summary["min_altitude_m"] == pytest.approx(altitude.min(), rel=1e-12)
    assert 0.0 < angles.min() < 70.5 < angles.max() < 180.0            # distorted: not the regular tet's


def test_a_tet_shrunk_to_a_point_has_altitude_zero():
    """As in the NumPy version the stability operator used: 3 V / max(area, 1e-300), not NaN."""
    from softsim.kernels.tet_shape import tet_shapes

    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [2.0, 2.0, 2.0]])
    tets = np.array([[0, 1, 2, 3], [4, 4, 4, 4]])
    altitude = tet_shapes(x, tets)[0]
    assert altitude[0] == pytest.approx(1.0 / np.sqrt(3.0), rel=1e-14) and altitude[1] == 0.0


def test_compiled_volumes_and_edge_lengths_match_numpy():
    """``kernels.tet_shape.signed_volumes`` and ``mean_edge_lengths`` against NumPy's determinant
    and norms on random tets, both orientations."""
    from softsim.kernels.tet_shape import mean_edge_lengths, signed_volumes

    rng = np.random.default_rng(11)
    x = rng.normal(size=(400, 3))
    tets = rng.permutation(400).reshape(100, 4)
    X = x[tets]
    volume = np.linalg.det(X[:, 1:] - X[:, :1]) / 6.0
    edges = sum(np.linalg.norm(X[:, a] - X[:, b], axis=1) for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)))
    assert (volume > 0).any() and (volume < 0).any()
    np.testing.assert_allclose(signed_volumes(x, tets), volume, rtol=1e-12, atol=0)
    np.testing.assert_allclose(mean_edge_lengths(x, tets), edges / 6.0, rtol=1e-14, atol=0)


def test_input_clash_finds_an_xdmf_files_data_file(tmp_path):
    """``with_data_file`` / ``input_clash``: an XDMF file (any case of .xdmf, .xmf) comes with the
    ``.h5`` beside it; other formats alone; the same file by another path is the same file."""
    from softsim.io.files import input_clash, with_data_file

    assert with_data_file(tmp_path / "a.XMF") == [tmp_path / "a.XMF", tmp_path / "a.h5"]
    assert with_data_file("a.vtu") == [Path("a.vtu")]
    scene, mesh_file = tmp_path / "s.yaml", tmp_path / "m.xdmf"
    assert input_clash([tmp_path / "out.h5", tmp_path / "out.xdmf"], [scene, mesh_file, None]) is None
    assert input_clash([tmp_path / "sub" / ".." / "m.h5"], [scene, mesh_file]) == (
        tmp_path / "sub" / ".." / "m.h5", tmp_path / "m.h5", mesh_file)
    assert input_clash(["x.vtu", tmp_path / "s.yaml"], [scene, ""]) == (tmp_path / "s.yaml", scene, scene)


def test_a_mesh_files_hash_covers_the_hdf5_files_an_xdmf_mesh_names(tmp_path):
    """What a reader gets: the file's bytes, and an XDMF file's named HDF5 files (any name)."""
    import hashlib

    from softsim.io.files import content_sha256, read_files

    points, tets = small_mesh()
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(points, [("tetra", tets)]))
    assert content_sha256(tmp_path / "m.vtu") == hashlib.sha256((tmp_path / "m.vtu").read_bytes()).hexdigest()
    meshio.write(tmp_path / "m.xdmf", meshio.Mesh(points, [("tetra", tets)]))
    (tmp_path / "m.h5").rename(tmp_path / "arrays.h5")
    (tmp_path / "m.xdmf").write_text((tmp_path / "m.xdmf").read_text().replace("m.h5:", "arrays.h5:"))
    assert read_files(tmp_path / "m.xdmf") == [tmp_path / "m.xdmf", tmp_path / "arrays.h5"]
    before = content_sha256(tmp_path / "m.xdmf")
    with h5py.File(tmp_path / "arrays.h5", "a") as f:
        f["data0"][0, 0] += 1e-3
    assert content_sha256(tmp_path / "m.xdmf") != before
    (tmp_path / "elsewhere").mkdir()                  # a link: its data beside the file it points to, as meshio
    (tmp_path / "elsewhere" / "link.xdmf").symlink_to(tmp_path / "m.xdmf")
    assert read_files(tmp_path / "elsewhere" / "link.xdmf")[1:] == [tmp_path / "arrays.h5"]
    (tmp_path / "odd.xdmf").write_bytes(b'<?xml version="1.0" encoding="bogus"?><Xdmf/>')   # unparsable: itself
    assert read_files(tmp_path / "odd.xdmf") == [tmp_path / "odd.xdmf"]
    (tmp_path / "arrays.h5").unlink()
    with pytest.raises(FileNotFoundError):
        content_sha256(tmp_path / "m.xdmf")


def test_check_mesh_output_names_the_data_file_that_would_replace_an_input(tmp_path):
    from softsim.mesh.write import check_mesh_output

    with pytest.raises(MeshError, match=r"^--output = '.*m\.xdmf': its data file '.*m\.h5' is the "
                                        r"scene's own file '.*m\.h5', which meshing reads; choose another"):
        check_mesh_output(tmp_path / "m.xdmf", overwrite=True, inputs=[tmp_path / "m.h5"])
    check_mesh_output(tmp_path / "m.xdmf", overwrite=False, inputs=[tmp_path / "other.h5"])   # nothing there: fine
    check_mesh_output(tmp_path / "m.1.VTU")
    for name, shown in (("m.foo", "'.foo'"), ("mesh", "'(none)'")):      # refused before meshing
        with pytest.raises(MeshError, match=rf"^--output = '.*{name}': meshio writes no format by the extension "
                                            rf"{re.escape(shown)}; use one like \.vtu"):
            check_mesh_output(tmp_path / name)
    for name, form in (("m.stl", "stl"), ("m.OBJ", "obj"), ("m.ply", "ply"), ("m.off", "off")):
        with pytest.raises(MeshError, match=rf"^--output = '.*{name}': {form} holds surfaces only, not tetrahedra"):
            check_mesh_output(tmp_path / name)
    check_mesh_output(tmp_path / "m.vol.gz")


def test_a_large_gmsh_mesh_is_announced_before_gmsh_starts(monkeypatch, caplog):
    """gmsh says nothing while it meshes (minutes for a few million tets): softsim says it starts."""
    import softsim.mesh as mesh_module
    from softsim.config.schema import Mesh

    spec = Mesh(shape="sphere", radius=0.1, element_size=0.05)
    monkeypatch.setattr(mesh_module, "ANNOUNCED_MESH_TETS", mesh_module.estimated_tet_count(spec))
    with caplog.at_level(logging.INFO, logger="softsim"):
        build_mesh(spec)
    assert re.search(r"mesh.element_size = 0.05: gmsh is meshing about [0-9.e-]+ million tetrahedra, which takes "
                     r"minutes", caplog.text), caplog.text
    caplog.clear()
    monkeypatch.setattr(mesh_module, "ANNOUNCED_MESH_TETS", mesh_module.estimated_tet_count(spec) + 1)
    with caplog.at_level(logging.INFO, logger="softsim"):
        build_mesh(spec)
    assert "gmsh is meshing" not in caplog.text
