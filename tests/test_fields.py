"""Per-frame output fields: the kernel against a naive NumPy formula and analytic answers, and the
fields a run writes (user order, only when asked for, only at frame times, in the XDMF).

Expected values come from ``tests/naive.py`` and continuum mechanics, never from softsim's output.
"""

import h5py
import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

import naive
import softsim.kernels.fields
from softsim.io.fields import FIELDS, TET_FIELDS, VERTEX_FIELDS
from softsim.kernels.fields import TET_FIELD_SHAPES, tet_fields
from softsim.kernels.rest_state import rest_state
from softsim.materials.lame import lame_parameters
from softsim.materials.models import MODEL_IDS, model_lame_parameters
from softsim.mesh.generate import structured_box
from softsim.simulation import prepare, simulate

MODELS = tuple(MODEL_IDS)
E_PA = 1.0e6
NU = 0.3
ALL_FIELDS = ["velocities", "energy", "displacement", "speed", *TET_FIELDS]


def naive_fields(model, x, X, tets, lam, mu):
    """The per-tet fields from the notes' definitions, one tet at a time with np.linalg."""
    out = {name: [] for name in TET_FIELDS}
    for F in naive.deformation_gradients(x, X, tets):
        J = np.linalg.det(F)
        P = naive.pk1(model, F, lam, mu)
        if model == "linear":
            strain, sigma = 0.5 * (F + F.T) - np.eye(3), P
        else:
            strain, sigma = 0.5 * (F.T @ F - np.eye(3)), P @ F.T / J
        p = -np.trace(sigma) / 3.0
        s1, s2, s3 = np.linalg.eigvalsh(0.5 * (sigma + sigma.T))   # principal stresses
        out["strain"].append(strain)
        out["stress"].append(sigma)
        out["pressure"].append(p)
        out["deviatoric_stress"].append(sigma + p * np.eye(3))
        out["von_mises"].append(np.sqrt(0.5 * ((s1 - s2) ** 2 + (s2 - s3) ** 2 + (s3 - s1) ** 2)))
        out["J"].append(J)
    return {name: np.array(values) for name, values in out.items()}


def box():
    """A 0.4 x 0.2 x 0.2 m structured box of 2 x 1 x 1 hex cells (10 tets)."""
    points, tets = structured_box((0.4, 0.2, 0.2), (0.0, 0.0, 0.0), 0.2)
    Dm_inv, _ = rest_state(points, tets)
    return points, tets, Dm_inv


def kernel(model, x, points, tets, Dm_inv, names=TET_FIELDS):
    lam, mu = model_lame_parameters(model, E_PA, NU)
    return tet_fields(np.ascontiguousarray(x), tets, Dm_inv, MODEL_IDS[model], lam, mu, names)


# ---------------------------------------------------------------------------------------------
# the kernel


@pytest.mark.parametrize("model", MODELS)
def test_kernel_matches_the_naive_formulas_on_a_random_deformation(model):
    points, tets, Dm_inv = box()
    rng = np.random.default_rng(7)
    x = points @ np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.15], [0.05, 0.0, 1.05]]).T
    x += 0.02 * rng.standard_normal(x.shape)
    lam, mu = model_lame_parameters(model, E_PA, NU)
    expected = naive_fields(model, x, points, tets, lam, mu)
    got = kernel(model, x, points, tets, Dm_inv)
    assert set(got) == set(TET_FIELDS)
    for name in TET_FIELDS:
        assert got[name].shape == (len(tets), *TET_FIELD_SHAPES[name])
        scale = 1.0 if name in ("strain", "J") else E_PA
        np.testing.assert_allclose(got[name], expected[name], rtol=1e-9, atol=1e-9 * scale, err_msg=name)


def test_only_the_fields_asked_for_are_returned_and_none_means_no_kernel(monkeypatch):
    points, tets, Dm_inv = box()
    assert set(kernel("stvk", points, points, tets, Dm_inv, ["von_mises", "speed"])) == {"von_mises"}
    monkeypatch.setattr(softsim.kernels.fields, "tet_fields_kernel", lambda *a: pytest.fail("kernel ran"))
    assert kernel("stvk", points, points, tets, Dm_inv, ["velocities", "energy", "displacement"]) == {}


@pytest.mark.parametrize("model", MODELS)
def test_rest_and_rigid_motion_give_no_stress(model):
    points, tets, Dm_inv = box()
    got = kernel(model, points + [1.0, -2.0, 3.0], points, tets, Dm_inv)
    np.testing.assert_allclose(got["strain"], 0.0, atol=1e-12)
    for name in ("stress", "pressure", "deviatoric_stress", "von_mises"):
        np.testing.assert_allclose(got[name], 0.0, atol=1e-12 * E_PA, err_msg=name)
    np.testing.assert_allclose(got["J"], 1.0, rtol=1e-12)
    if model != "linear":                     # the rotation-invariant models see no stress when turned
        c, s = np.cos(0.7), np.sin(0.7)
        rotated = points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        got = kernel(model, rotated, points, tets, Dm_inv)
        np.testing.assert_allclose(got["strain"], 0.0, atol=1e-12)
        for name in ("stress", "von_mises"):
            np.testing.assert_allclose(got[name], 0.0, atol=1e-9 * E_PA, err_msg=name)


def test_linear_uniaxial_stress_of_a_bar():
    """x = diag(1 + e, 1 - nu e, 1 - nu e) X: sigma = E e e_x e_x, p = -E e / 3, von Mises = E |e|."""
    points, tets, Dm_inv = box()
    for e in (1e-3, -2e-3):
        x = points * [1.0 + e, 1.0 - NU * e, 1.0 - NU * e]
        got = kernel("linear", x, points, tets, Dm_inv)
        expected = np.zeros((3, 3))
        expected[0, 0] = E_PA * e
        np.testing.assert_allclose(got["stress"], np.broadcast_to(expected, got["stress"].shape), atol=1e-6)
        np.testing.assert_allclose(got["pressure"], -E_PA * e / 3.0, rtol=1e-9)
        assert np.all(np.sign(got["pressure"]) == -np.sign(e))      # positive in compression
        np.testing.assert_allclose(got["von_mises"], E_PA * abs(e), rtol=1e-9)
        np.testing.assert_allclose(got["strain"][:, 0, 0], e, rtol=1e-9)
        np.testing.assert_allclose(got["J"], (1 + e) * (1 - NU * e) ** 2, rtol=1e-12)


@pytest.mark.parametrize("a", [1.2, 0.8])
def test_stvk_stretch_along_a_bar_is_the_models_cauchy_stress(a):
    """F = diag(a, 1, 1): S = lam tr(E) I + 2 mu E with E_xx = (a^2 - 1)/2, sigma = F S F^T / a."""
    points, tets, Dm_inv = box()
    got = kernel("stvk", points * [a, 1.0, 1.0], points, tets, Dm_inv)
    lam, mu = lame_parameters(E_PA, NU)
    Exx = 0.5 * (a * a - 1.0)
    sxx, syy = a * (lam + 2.0 * mu) * Exx, lam * Exx / a
    np.testing.assert_allclose(got["stress"][:, 0, 0], sxx, rtol=1e-9)
    np.testing.assert_allclose(got["stress"][:, 1, 1], syy, rtol=1e-9)
    np.testing.assert_allclose(got["strain"][:, 0, 0], Exx, rtol=1e-9)
    np.testing.assert_allclose(got["pressure"], -(sxx + 2.0 * syy) / 3.0, rtol=1e-9)
    assert np.all(got["pressure"] < 0) if a > 1 else np.all(got["pressure"] > 0)
    np.testing.assert_allclose(got["von_mises"], abs(sxx - syy), rtol=1e-9)   # uniaxial + equal lateral
    np.testing.assert_allclose(got["J"], a, rtol=1e-12)


def test_von_mises_of_pure_shear_is_sqrt3_tau_with_no_pressure():
    """Linear, F = I + g e_x e_y: sigma_xy = sigma_yx = mu g = tau, von Mises sqrt(3) tau, p = 0."""
    points, tets, Dm_inv = box()
    g = 1e-3
    got = kernel("linear", points + g * points[:, [1]] * [1.0, 0.0, 0.0], points, tets, Dm_inv)
    _, mu = lame_parameters(E_PA, NU)
    np.testing.assert_allclose(got["stress"][:, 0, 1], mu * g, rtol=1e-9)
    np.testing.assert_allclose(got["stress"][:, 1, 0], mu * g, rtol=1e-9)
    np.testing.assert_allclose(got["pressure"], 0.0, atol=1e-6)
    np.testing.assert_allclose(got["von_mises"], np.sqrt(3.0) * mu * g, rtol=1e-9)
    np.testing.assert_allclose(got["deviatoric_stress"], got["stress"], atol=1e-6)


@pytest.mark.parametrize("model", ["corotated", "neohookean"])
def test_uniform_compression_is_pure_pressure(model):
    points, tets, Dm_inv = box()
    got = kernel(model, 0.9 * points, points, tets, Dm_inv)
    assert np.all(got["pressure"] > 0.01 * E_PA)
    np.testing.assert_allclose(got["von_mises"], 0.0, atol=1e-6 * E_PA)
    np.testing.assert_allclose(got["deviatoric_stress"], 0.0, atol=1e-6 * E_PA)
    np.testing.assert_allclose(np.trace(got["deviatoric_stress"], axis1=1, axis2=2), 0.0, atol=1e-6)
    np.testing.assert_allclose(got["J"], 0.9 ** 3, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# what a run writes


def test_field_registry_matches_the_schema_and_the_kernel():
    from softsim.config.schema import OUTPUT_FIELDS

    assert set(OUTPUT_FIELDS) == set(FIELDS)
    assert TET_FIELDS == tuple(TET_FIELD_SHAPES)
    assert all(FIELDS[name].shape == TET_FIELD_SHAPES[name] for name in TET_FIELDS)
    assert all(FIELDS[name].unit for name in FIELDS)


@pytest.fixture(scope="module")
def fields_run(tmp_path_factory):
    """A gmsh-meshed (irregularly numbered) stvk cube squashed and thrown, every field, 3 frames."""
    from softsim.config import parse_scene
    from conftest import scene_dict

    folder = tmp_path_factory.mktemp("fields")
    scene = parse_scene(scene_dict(
        mesh={"structured": False, "element_size": 0.08},
        initial_deformation={"matrix": [[0.95, 0.05, 0], [0, 1.03, 0], [0, 0, 1.0]]},
        initial_velocity=[0.3, 0.0, 0.5], gravity=[0, 0, -9.81],
        time={"duration": 0.004}, output={"frame_interval": 0.002, "fields": ALL_FIELDS}), base_dir=folder)
    path = folder / "out.h5"
    simulate(prepare(scene), path)
    return scene, path


def test_run_writes_every_field_in_the_users_vertex_and_tet_order(fields_run):
    scene, path = fields_run
    lam, mu = model_lame_parameters("stvk", scene.material.youngs_modulus, scene.material.poissons_ratio)
    with h5py.File(path) as f:
        X, tets = f["mesh/points"][:], f["mesh/tets"][:]
        k, n, m = f["frames/time"].shape[0], len(X), len(tets)
        assert k == 3
        for name in ALL_FIELDS:
            spec = FIELDS[name]
            for dataset in spec.datasets:
                count = {"vertex": (n,), "tet": (m,), "frame": ()}[spec.location]
                assert f["frames"][dataset].shape == (k, *count, *spec.shape), name
        for i in range(k):
            x, v = f["frames/points"][i], f["frames/velocities"][i]
            expected = naive_fields("stvk", x, X, tets, lam, mu)
            for name in TET_FIELDS:
                np.testing.assert_allclose(f["frames"][name][i], expected[name], rtol=1e-8,
                                           atol=1e-8 * (1.0 if name in ("strain", "J") else scene.material.youngs_modulus),
                                           err_msg=f"{name}, frame {i}")
            np.testing.assert_allclose(f["frames/displacement"][i], x - X, atol=1e-15)
            np.testing.assert_allclose(f["frames/speed"][i], np.linalg.norm(v, axis=1), rtol=1e-12)
        # Frame 0 is the affine initial deformation: the same stress in every tet, J = det A.
        assert f["frames/von_mises"][0].min() > 0.01 * scene.material.youngs_modulus
        np.testing.assert_allclose(f["frames/J"][0], 0.95 * 1.03, rtol=1e-12)
        assert np.ptp(f["frames/von_mises"][-1]) > 0          # later, waves make it non-uniform


def test_a_scene_without_fields_writes_no_field_datasets_and_runs_no_field_kernel(scene, tmp_path, monkeypatch):
    monkeypatch.setattr(softsim.kernels.fields, "tet_fields_kernel", lambda *a: pytest.fail("field kernel ran"))
    path = tmp_path / "plain.h5"
    simulate(prepare(scene(time={"duration": 0.002}, output={"frame_interval": 0.001})), path)
    with h5py.File(path) as f:
        assert sorted(f["frames"]) == ["points", "time"]
    text = path.with_suffix(".xdmf").read_text()
    assert "<Attribute" not in text


def test_field_kernel_runs_once_per_frame_not_per_step(scene, tmp_path, monkeypatch):
    calls = []
    real = softsim.kernels.fields.tet_fields_kernel
    monkeypatch.setattr(softsim.kernels.fields, "tet_fields_kernel", lambda *a: calls.append(1) or real(*a))
    prepared = prepare(scene(time={"duration": 0.004, "dt": 2.5e-4},
                             output={"frame_interval": 0.002, "fields": ["J"]}))
    assert prepared.plan.total_steps > 3
    simulate(prepared, tmp_path / "j.h5")
    assert len(calls) == 3


def test_xdmf_shows_the_fields_to_vtk_xdmf_reader(fields_run):
    _, path = fields_run
    reader, messages = vtkXdmfReader(), []
    for event in ("ErrorEvent", "WarningEvent"):
        reader.AddObserver(event, lambda obj, ev: messages.append(ev))
    reader.SetFileName(str(path.with_suffix(".xdmf")))
    reader.UpdateInformation()
    with h5py.File(path) as f:
        t = f["frames/time"][2]
        reader.UpdateTimeStep(t)
        grid = reader.GetOutputDataObject(0)
        if isinstance(grid, vtkCompositeDataSet):
            (grid,) = vtkCompositeDataSet.GetDataSets(grid)
        assert not messages, messages
        for name in TET_FIELDS:
            array = grid.GetCellData().GetArray(name)
            assert array is not None, name
            assert array.GetNumberOfComponents() == int(np.prod(FIELDS[name].shape, dtype=int))
            np.testing.assert_array_equal(vtk_to_numpy(array).reshape(f["frames"][name][2].shape),
                                          f["frames"][name][2], err_msg=name)
        for name in VERTEX_FIELDS:
            array = grid.GetPointData().GetArray(FIELDS[name].xdmf_name)
            assert array is not None, name
            np.testing.assert_array_equal(vtk_to_numpy(array).reshape(f["frames"][name][2].shape),
                                          f["frames"][name][2], err_msg=name)


def test_a_resumed_run_continues_every_field(scene, tmp_path):
    """Stopped after 2 frames and resumed, the field datasets hold the same frames, bit for bit,
    as a run that never stopped."""
    s = scene(time={"duration": 0.004, "dt": 5e-4}, output={"frame_interval": 0.001, "fields": ALL_FIELDS})
    simulate(prepare(s), tmp_path / "whole.h5")
    calls = []
    stopped = simulate(prepare(s), tmp_path / "part.h5", should_stop=lambda: calls.append(1) or len(calls) >= 2)
    assert stopped.status == "interrupted"
    simulate(prepare(s), tmp_path / "part.h5", resume=True)
    with h5py.File(tmp_path / "whole.h5") as a, h5py.File(tmp_path / "part.h5") as b:
        assert a["frames/time"].shape == b["frames/time"].shape == (5,)
        for name in ALL_FIELDS:
            for dataset in FIELDS[name].datasets:
                np.testing.assert_array_equal(a["frames"][dataset][...], b["frames"][dataset][...], err_msg=dataset)
