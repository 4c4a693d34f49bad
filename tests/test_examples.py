"""Every example scene in configs/ validates, runs (shortened) and leaves files h5py and VTK open."""

from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

from softsim.cli.main import cli
from softsim.config import load_scene
from softsim.mesh import build_mesh

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
# Scenes only: sweep files (*_sweep.yaml) are tested in test_sweep.py.
EXAMPLES = sorted(p for p in CONFIGS.glob("*.yaml") if not p.stem.endswith("_sweep"))
# Frames each shortened run writes after frame 0.
FRAMES_RUN = 2


def test_the_examples_exist():
    assert {p.stem for p in EXAMPLES} >= {"cantilever", "bouncing_cube", "twisted_bar"}


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_loads_and_meshes(path):
    scene = load_scene(path)
    assert scene.output.path == f"{path.stem}.h5"
    assert {"velocities", "energy"} <= set(scene.output.fields)
    mesh = build_mesh(scene.mesh)
    assert 100 <= mesh.tet_count <= 50_000     # "each runs in seconds"


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    interval = load_scene(path).output.frame_interval
    out = tmp_path / f"{path.stem}.h5"
    result = CliRunner().invoke(cli, ["run", str(path), "-o", str(out),
                                      "--set", f"time.duration={FRAMES_RUN * interval!r}"])
    assert result.exit_code == 0, (result.output, result.exception)
    assert "tet-steps/s" in result.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name, out.with_suffix(".xdmf").name]

    with h5py.File(out) as f:
        assert f.attrs["status"] == "complete"
        k = FRAMES_RUN + 1
        assert f["frames/time"].shape == (k,)
        np.testing.assert_allclose(f["frames/time"][:], np.arange(k) * interval, rtol=1e-9, atol=1e-12)
        n = f["mesh/points"].shape[0]
        assert f["frames/points"].shape == (k, n, 3)
        arrays = {name: f[name][:] for name in
                  ("frames/points", "frames/velocities", "frames/energy/kinetic", "frames/energy/elastic",
                   "frames/energy/gravity", "state/a/positions", "state/a/velocities",
                   "state/b/positions", "state/b/velocities")}
        for name, values in arrays.items():
            assert np.isfinite(values).all(), name
        points = arrays["frames/points"]
        np.testing.assert_array_equal(points[0], f["mesh/points"][:])   # identity initial deformation
        assert not np.array_equal(points[0], points[-1])               # something happens
        # No blow-up: the body stays within a metre of where it started over a few frames.
        assert np.abs(points - points[0]).max() < 1.0
        times, last = f["frames/time"][:], points[-1]

    reader, messages = vtkXdmfReader(), []
    for event in ("ErrorEvent", "WarningEvent"):
        reader.AddObserver(event, lambda obj, ev: messages.append(ev))
    reader.SetFileName(str(out.with_suffix(".xdmf")))
    reader.UpdateInformation()
    steps = reader.GetOutputInformation(0).Get(vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    np.testing.assert_array_equal(np.array(steps), times)
    reader.UpdateTimeStep(times[-1])
    grid = reader.GetOutputDataObject(0)
    if isinstance(grid, vtkCompositeDataSet):
        (grid,) = vtkCompositeDataSet.GetDataSets(grid)
    assert not messages, messages
    np.testing.assert_array_equal(vtk_to_numpy(grid.GetPoints().GetData()), last)
