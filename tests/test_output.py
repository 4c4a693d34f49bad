"""The run's output files: HDF5 layout, XDMF read by VTK, user vertex order, failed and interrupted runs."""

import subprocess
import sys

import h5py
import meshio
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonDataModel import VTK_TETRA, vtkCompositeDataSet, vtkUnstructuredGrid
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

import softsim.io.hdf5
from softsim.io.hdf5 import frames_written, read_resume_state
import softsim.simulation
from softsim import __version__
from softsim.cli.main import cli
from softsim.config import SceneLoader, load_scene, parse_scene
from softsim.mesh.generate import structured_box

# A 0.3 x 0.1 x 0.1 m bar of 6 x 2 x 2 hex cells = 120 tets, 63 vertices, clamped at x = 0,
# sagging under gravity; 4 frames (t = 0, 1, 2, 3 ms).
SCENE = """\
mesh:
  shape: box
  size: [0.3, 0.1, 0.1]
  origin: [0.0, -0.05, -0.05]
  element_size: 0.05
  structured: true
material:
  model: stvk
  youngs_modulus: 1e6
  poissons_ratio: 0.3
  density: 1000.0
fixed:
  - {min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}
time:
  duration: 0.003
output:
  path: out.h5
  frame_interval: 0.001
"""
NODES, TETS, FRAMES = 63, 120, 4


def write_scene(folder, text=SCENE, extra="", name="scene.yaml"):
    path = folder / name
    path.write_text(text + extra)
    return path


def run_cli(*args):
    """``softsim <args>`` through click's CliRunner; fails the test on a non-zero exit."""
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 0, (result.output, result.exception)
    return result


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """One CLI run of SCENE with every optional field: (scene path, h5 path)."""
    folder = tmp_path_factory.mktemp("full")
    scene = write_scene(folder, extra="  fields: [velocities, energy]\n")
    out = folder / "run.h5"
    run_cli("run", scene, "-o", out)
    return scene, out


# ---------------------------------------------------------------------------------------------
# Layout


def test_layout_shapes_and_dtypes(full_run):
    _, out = full_run
    with h5py.File(out) as f:
        assert f["mesh/points"].shape == (NODES, 3)
        assert f["mesh/tets"].shape == (TETS, 4)
        assert np.issubdtype(f["mesh/tets"].dtype, np.integer)
        assert f["mesh/fixed"].shape == (NODES,) and f["mesh/fixed"].dtype == np.bool_
        assert f["frames/time"].shape == (FRAMES,)
        assert f["frames/points"].shape == (FRAMES, NODES, 3)
        assert f["frames/velocities"].shape == (FRAMES, NODES, 3)
        assert set(f["frames/energy"]) == {"kinetic", "elastic", "gravity"}
        for term in ("kinetic", "elastic", "gravity"):
            assert f["frames/energy"][term].shape == (FRAMES,)
        for slot in ("a", "b"):
            assert f[f"state/{slot}/positions"].shape == (NODES, 3)
            assert f[f"state/{slot}/velocities"].shape == (NODES, 3)


def test_mesh_group_holds_the_rest_mesh(full_run):
    _, out = full_run
    with h5py.File(out) as f:
        points, tets, fixed = f["mesh/points"][:], f["mesh/tets"][:], f["mesh/fixed"][:]
    assert points.min(axis=0) == pytest.approx([0.0, -0.05, -0.05])
    assert points.max(axis=0) == pytest.approx([0.3, 0.05, 0.05])
    assert sorted(np.unique(tets)) == list(range(NODES))
    X = points[tets]
    assert (np.linalg.det(X[:, 1:] - X[:, :1]) > 0).all()      # positively oriented
    np.testing.assert_array_equal(fixed, np.abs(points[:, 0]) < 1e-9)   # the clamped face x = 0
    assert fixed.sum() == 9


def test_root_attributes(full_run):
    scene, out = full_run
    with h5py.File(out) as f:
        attrs = dict(f.attrs)
        steps = int(attrs["steps"])
    assert attrs["status"] == "complete"
    assert attrs["status_reason"] == ""
    assert attrs["softsim_version"] == __version__
    assert float(attrs["dt"]) > 0 and steps >= FRAMES - 1
    assert steps * float(attrs["dt"]) == pytest.approx(0.003)
    assert float(attrs["wall_time_s"]) > 0
    stored = parse_scene(yaml.load(attrs["config"], Loader=SceneLoader))
    expected = load_scene(scene)
    assert stored.output.path == str(out)     # -o is what the run really wrote to
    assert expected.model_copy(update={"output": expected.output.model_copy(update={"path": str(out)})}) == stored
    assert stored.material == expected.material and stored.fixed == expected.fixed
    assert stored.output.fields == ("velocities", "energy")


def test_frames_times_and_motion(full_run):
    _, out = full_run
    with h5py.File(out) as f:
        time, points, dt = f["frames/time"][:], f["frames/points"][:], float(f.attrs["dt"])
        velocities, fixed = f["frames/velocities"][:], f["mesh/fixed"][:]
        energy = {term: f["frames/energy"][term][:] for term in ("kinetic", "elastic", "gravity")}
    np.testing.assert_allclose(time, [0.0, 0.001, 0.002, 0.003], rtol=0, atol=1e-12)
    # frames/time holds the true time: a whole number of steps
    np.testing.assert_allclose(time / dt, np.round(time / dt), rtol=0, atol=1e-9)
    assert np.isfinite(points).all() and np.isfinite(velocities).all()
    free = ~fixed
    assert (points[-1, free, 2] < points[0, free, 2]).all()        # falls under gravity
    assert (velocities[-1, free, 2] < 0).all()
    np.testing.assert_array_equal(points[:, fixed], np.broadcast_to(points[0, fixed], points[:, fixed].shape))
    np.testing.assert_array_equal(velocities[:, fixed], 0.0)
    assert energy["kinetic"][0] == 0.0 and energy["elastic"][0] == pytest.approx(0.0, abs=1e-12)
    assert (energy["kinetic"][1:] > 0).all()
    assert energy["gravity"][-1] < energy["gravity"][0]
    for values in energy.values():
        assert np.isfinite(values).all()


def test_frame0_is_the_rest_state(full_run):
    _, out = full_run
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["frames/points"][0], f["mesh/points"][:])
        np.testing.assert_array_equal(f["frames/velocities"][0], 0.0)
        assert f["frames/time"][0] == 0.0


def test_state_is_the_last_frame(full_run):
    _, out = full_run
    with h5py.File(out) as f:
        state = read_resume_state(f)
        np.testing.assert_array_equal(state["positions"], f["frames/points"][-1])
        np.testing.assert_array_equal(state["velocities"], f["frames/velocities"][-1])
        assert state["time"] == f["frames/time"][-1]
        assert state["step"] == f.attrs["steps"]
        assert state["frames"] == frames_written(f) == f["frames/time"].shape[0]
        # the other slot holds the frame before, also intact
        headers = {slot: f[f"state/{slot}/header"][()] for slot in ("a", "b")}
        other = min(headers, key=lambda slot: headers[slot]["frames"])
        assert headers[other]["frames"] == state["frames"] - 1
        np.testing.assert_array_equal(f[f"state/{other}/positions"][...], f["frames/points"][-2])


def test_frame0_is_the_initial_deformation_and_velocity(tmp_path):
    free = SCENE.replace("fixed:\n  - {min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}\n", "")
    assert free != SCENE
    scene = write_scene(tmp_path, free, "  fields: [velocities]\n"
                        "initial_deformation: {matrix: [[1.1, 0.2, 0], [0, 0.9, 0], [0, 0, 1]], translation: [0.5, 0, 1]}\n"
                        "initial_velocity: [1.0, 2.0, 3.0]\n")
    out = tmp_path / "out.h5"
    run_cli("run", scene, "-o", out)
    A = np.array([[1.1, 0.2, 0], [0, 0.9, 0], [0, 0, 1]])
    with h5py.File(out) as f:
        rest = f["mesh/points"][:]
        assert not f["mesh/fixed"][:].any()
        np.testing.assert_allclose(f["frames/points"][0], rest @ A.T + [0.5, 0, 1], rtol=0, atol=1e-15)
        np.testing.assert_array_equal(f["frames/velocities"][0], np.broadcast_to([1.0, 2.0, 3.0], (NODES, 3)))


def test_without_fields_nothing_extra_is_written(tmp_path):
    out = tmp_path / "out.h5"
    run_cli("run", write_scene(tmp_path), "-o", out)
    with h5py.File(out) as f:
        assert set(f["frames"]) == {"time", "points"}
        assert f["frames/points"].shape == (FRAMES, NODES, 3)
        # state/ always holds what a resume needs: positions, velocities and the guard's memory
        state = set(f["state/a"])
        assert {"positions", "velocities"} <= state
        assert all(name.startswith("guard_") for name in state - {"positions", "velocities", "scalars", "header"})
        assert f.attrs["status"] == "complete"
    assert "velocity" not in out.with_suffix(".xdmf").read_text()


# ---------------------------------------------------------------------------------------------
# XDMF, read by the reader ParaView uses


def _vtk_grid(reader, t, messages):
    reader.UpdateTimeStep(t)
    output = reader.GetOutputDataObject(0)
    assert not messages, messages
    if isinstance(output, vtkCompositeDataSet):
        blocks = vtkCompositeDataSet.GetDataSets(output)
        assert len(blocks) == 1
        output = blocks[0]
    assert isinstance(output, vtkUnstructuredGrid)
    return output


def test_xdmf_reads_every_frame_in_vtk(full_run):
    _, out = full_run
    xdmf = out.with_suffix(".xdmf")
    assert xdmf.is_file()
    reader, messages = vtkXdmfReader(), []
    for event in ("ErrorEvent", "WarningEvent"):
        reader.AddObserver(event, lambda obj, ev: messages.append(ev))
    reader.SetFileName(str(xdmf))
    reader.UpdateInformation()
    times = np.array(reader.GetOutputInformation(0).Get(vtkStreamingDemandDrivenPipeline.TIME_STEPS()))
    with h5py.File(out) as f:
        np.testing.assert_array_equal(times, f["frames/time"][:])
        tets = f["mesh/tets"][:]
        for i in [0, 3, 1, 2]:    # out of order, as when scrubbing in ParaView
            grid = _vtk_grid(reader, f["frames/time"][i], messages)
            np.testing.assert_array_equal(vtk_to_numpy(grid.GetPoints().GetData()), f["frames/points"][i])
            np.testing.assert_array_equal(
                vtk_to_numpy(grid.GetPointData().GetArray("velocity")), f["frames/velocities"][i])
            assert grid.GetNumberOfCells() == TETS
            assert {grid.GetCellType(c) for c in range(TETS)} == {VTK_TETRA}
            np.testing.assert_array_equal(vtk_to_numpy(grid.GetCells().GetConnectivityArray()), tets.ravel())
        assert not np.array_equal(f["frames/points"][0], f["frames/points"][-1])


# ---------------------------------------------------------------------------------------------
# The user's vertex order


def test_output_keeps_the_vertex_order_of_a_mesh_file(tmp_path):
    points, tets = structured_box([0.3, 0.1, 0.1], [0.0, -0.05, -0.05], 0.05)
    rng = np.random.default_rng(7)
    perm = rng.permutation(len(points))          # file vertex j is structured vertex perm[j]
    file_points = points[perm]
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm))
    file_tets = inverse[tets][rng.permutation(len(tets))]
    meshio.write(tmp_path / "shuffled.vtu", meshio.Mesh(file_points, [("tetra", file_tets)]))
    text = SCENE.replace("  shape: box\n  size: [0.3, 0.1, 0.1]\n  origin: [0.0, -0.05, -0.05]\n"
                         "  element_size: 0.05\n  structured: true\n", "  shape: file\n  file: shuffled.vtu\n")
    scene = write_scene(tmp_path, text, "  fields: [velocities]\n")

    # The test means something only if the solver really renumbers the vertices internally.
    model = softsim.simulation.prepare(load_scene(scene)).model
    assert not np.array_equal(model.vertex_order, np.arange(len(points)))

    out = tmp_path / "out.h5"
    run_cli("run", scene, "-o", out)
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["mesh/points"][:], file_points)
        np.testing.assert_array_equal(f["frames/points"][0], file_points)
        np.testing.assert_array_equal(f["mesh/tets"][:], file_tets)   # positively wound already
        fixed = f["mesh/fixed"][:]
        np.testing.assert_array_equal(fixed, np.abs(file_points[:, 0]) < 1e-9)
        last, velocities = f["frames/points"][-1], f["frames/velocities"][-1]
    # held vertices stay put and free ones fall: positions and the fixed mask share one order
    np.testing.assert_array_equal(last[fixed], file_points[fixed])
    np.testing.assert_array_equal(velocities[fixed], 0.0)
    assert (last[~fixed, 2] < file_points[~fixed, 2]).all()


# ---------------------------------------------------------------------------------------------
# Runs that stop early


def _stepping_until(monkeypatch, calls_ok, exception):
    """Make ``softsim.simulation.step`` raise ``exception`` on call ``calls_ok + 1``."""
    real_step = softsim.simulation.step
    calls = []

    def step(*args, **kwargs):
        calls.append(1)
        if len(calls) > calls_ok:
            raise exception
        return real_step(*args, **kwargs)

    monkeypatch.setattr(softsim.simulation, "step", step)


def _prepared(tmp_path, fields="[velocities, energy]"):
    return softsim.simulation.prepare(load_scene(write_scene(tmp_path, extra=f"  fields: {fields}\n")))


def _assert_consistent_frames(f, count):
    assert f["frames/time"].shape == (count,)
    assert f["frames/points"].shape == (count, NODES, 3)
    for name in ("frames/velocities", "frames/energy/kinetic", "frames/energy/elastic", "frames/energy/gravity"):
        if name in f:
            assert f[name].shape[0] == count, name
    assert np.isfinite(f["frames/points"][:]).all()
    state = read_resume_state(f)
    np.testing.assert_array_equal(state["positions"], f["frames/points"][count - 1])
    assert state["time"] == f["frames/time"][count - 1]


def test_failed_run_keeps_its_frames(tmp_path, monkeypatch):
    prepared = _prepared(tmp_path)
    _stepping_until(monkeypatch, 2, RuntimeError("solver exploded"))
    out = tmp_path / "out.h5"
    with pytest.raises(RuntimeError, match="solver exploded"):
        softsim.simulation.simulate(prepared, out)
    with h5py.File(out) as f:     # plain open, no repair step
        assert f.attrs["status"] == "failed"
        assert "solver exploded" in f.attrs["status_reason"]
        assert "RuntimeError" in f.attrs["status_reason"]
        _assert_consistent_frames(f, 3)    # frame 0 and the frames after the 2 good steps
        np.testing.assert_allclose(f["frames/time"][:], [0.0, 0.001, 0.002], atol=1e-12)
        assert read_resume_state(f)["step"] == round(0.002 / f.attrs["dt"])
    assert out.with_suffix(".xdmf").read_text().count("<Time ") == 3


def test_interrupted_run_is_marked_interrupted(tmp_path, monkeypatch):
    prepared = _prepared(tmp_path)
    _stepping_until(monkeypatch, 1, KeyboardInterrupt())
    out = tmp_path / "out.h5"
    with pytest.raises(KeyboardInterrupt):
        softsim.simulation.simulate(prepared, out)
    with h5py.File(out) as f:
        assert f.attrs["status"] == "interrupted"
        assert f.attrs["status_reason"]
        _assert_consistent_frames(f, 2)


@pytest.mark.parametrize("point", ["frame_start", "after_points", "after_velocities", "after_energy",
                                   "after_time", "before_flush", "before_commit"])
def test_interrupt_while_a_frame_is_written_leaves_equal_lengths(tmp_path, monkeypatch, point):
    """Ctrl-C between the datasets of one frame: the half-written frame must not be left behind."""
    prepared = _prepared(tmp_path)

    def interrupt_at(name, frame=None):
        if name == point and frame == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(softsim.io.hdf5, "crash_point", interrupt_at)
    out = tmp_path / "out.h5"
    with pytest.raises(KeyboardInterrupt):
        softsim.simulation.simulate(prepared, out)
    with h5py.File(out) as f:
        assert f.attrs["status"] == "interrupted"
        _assert_consistent_frames(f, 2)


def test_cli_exits_non_zero_when_the_run_fails(tmp_path, monkeypatch):
    scene = write_scene(tmp_path)
    out = tmp_path / "out.h5"
    _stepping_until(monkeypatch, 1, RuntimeError("boom"))
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(out)])
    assert result.exit_code != 0
    with h5py.File(out) as f:
        assert f.attrs["status"] == "failed"
        assert f["frames/time"].shape == (2,)


def test_cli_exits_non_zero_when_interrupted(tmp_path, monkeypatch):
    scene = write_scene(tmp_path)
    out = tmp_path / "out.h5"
    _stepping_until(monkeypatch, 2, KeyboardInterrupt())
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(out)])
    assert result.exit_code == 130
    assert "interrupted" in result.stderr
    assert "Traceback" not in result.output
    with h5py.File(out) as f:
        assert f.attrs["status"] == "interrupted"
        assert f["frames/time"].shape == (3,)


def test_frames_written_counts_a_file_of_the_earlier_layout(tmp_path):
    """A file written before the checksummed headers (``state/`` holding plain datasets, frames
    appended): ``frames_written`` counts its ``frames/time`` rows."""
    path = tmp_path / "old.h5"
    with h5py.File(path, "w") as f:
        f["frames/time"] = np.arange(4) * 1e-3
        f["frames/points"] = np.zeros((4, 3000, 3))
        f["state/positions"] = np.zeros((3000, 3))
        f["state/velocities"] = np.zeros((3000, 3))
    with h5py.File(path) as f:
        assert frames_written(f) == 4


# Run in a child: where the lock is left held, the parent would wait on it at its own exit.
_READ_THEN_ANOTHER_THREAD = """
import sys, threading, h5py
from softsim.io.hdf5 import read_resume_state
with h5py.File(sys.argv[1], "r") as f:
    try:
        read_resume_state(f)
    except OSError as exc:
        kept = exc                      # the traceback outlives the call, as in a caller that reports it
    else:
        sys.exit("read_resume_state did not raise")
    done = threading.Event()
    threading.Thread(target=lambda: (h5py.File(sys.argv[2], "r").close(), done.set()), daemon=True).start()
    print("other thread done" if done.wait(10) else "other thread waited", flush=True)
    import os; os._exit(0)          # not a normal exit, which could wait on the lock the other thread waits for
"""


def test_a_read_that_fails_half_way_leaves_h5py_to_other_threads(full_run, tmp_path_factory):
    """``read_resume_state`` on a slot whose data cannot be read raises OSError; while that
    exception (and its traceback) lives, another thread must still get through h5py.  h5py's
    ``group.items()`` iterator holds h5py's global lock between members, so iterating a slot with
    it left the lock held: the next h5py call of any other thread (a Dask worker's event loop
    freeing an h5py object, say) waited as long as the traceback lived."""
    path = tmp_path_factory.mktemp("unreadable") / "unreadable.h5"    # outside tmp_path: unreadable on purpose
    path.write_bytes(full_run[1].read_bytes())
    with h5py.File(path, "a") as f:
        for slot in f["state"]:
            positions = f["state"][slot]["positions"]
            shape, dtype = positions.shape, positions.dtype
            del f["state"][slot]["positions"]
            f["state"][slot].create_dataset("positions", shape, dtype,
                                            external=[(str(path.parent / "missing.bin"), 0, h5py.h5f.UNLIMITED)])
    child = subprocess.run([sys.executable, "-c", _READ_THEN_ANOTHER_THREAD, str(path), str(full_run[1])],
                           capture_output=True, text=True, timeout=120)
    assert child.stdout.strip() == "other thread done", (child.stdout, child.stderr)


def test_frame_rows_written_through_the_low_level_calls_are_the_values_given(tmp_path):
    """``_LowLevelDataset`` (h5py's low-level writes, its dataspaces made once, for speed) stores
    each value's float64 bits in the row or dataset named, whatever the value's dtype, leaves every
    other row as it was, refuses a value of another shape instead of broadcasting it or a row past
    the end, writes the rows a resize added or kept, and converts the values for a dataset of
    another type."""
    rng = np.random.default_rng(7)
    LowLevel = softsim.io.hdf5._LowLevelDataset
    with h5py.File(tmp_path / "rows.h5", "w") as f:
        rows_dataset = softsim.io.hdf5._frame_dataset(f, "rows", 5, (4, 3))
        rows_dataset[...] = -1.0
        rows = LowLevel(rows_dataset)
        scalars = LowLevel(softsim.io.hdf5._frame_dataset(f, "scalars", 5, ()))
        value = rng.standard_normal((4, 3))
        rows.write_row(2, value)
        rows.write_row(4, value.astype(np.float32))
        scalars.write_row(3, np.array([0.1]))        # a length-1 array for a number
        scalars.write_row(1, 0.25)
        assert rows_dataset[2].tobytes() == value.tobytes()
        assert rows_dataset[4].tobytes() == value.astype(np.float32).astype(np.float64).tobytes()
        assert np.all(rows_dataset[[0, 1, 3]] == -1.0)
        assert f["scalars"][3] == 0.1 and f["scalars"][1] == 0.25
        with pytest.raises(ValueError, match="a row of shape"):
            rows.write_row(0, value.T)
        with pytest.raises(ValueError, match="a row of shape"):
            rows.write_row(0, value[0])
        rows.resize(8)                                # grown: the new rows are written where asked
        rows.write_row(7, 2 * value)
        assert rows_dataset.shape == rows.shape == (8, 4, 3)
        assert rows_dataset[7].tobytes() == (2 * value).tobytes() and rows_dataset[2].tobytes() == value.tobytes()
        rows.resize(3)                                # trimmed
        rows.write_row(1, 3 * value)
        assert rows_dataset.shape == (3, 4, 3) and rows_dataset[1].tobytes() == (3 * value).tobytes()
        with pytest.raises(IndexError, match="row 4 of 3"):           # past the end
            rows.write_row(4, value)
        f.create_dataset("narrow", shape=(3, 2), maxshape=(None, 2), dtype=np.float32, chunks=(1, 2))
        narrow = LowLevel(f["narrow"])                 # another type: HDF5 converts the float64 values
        narrow.write_row(1, [1.5, 2.5])
        assert f["narrow"][1].tolist() == [1.5, 2.5]
        whole = LowLevel(f.create_dataset("whole", data=np.zeros((4, 3))))
        whole.write_whole(value)
        assert f["whole"][...].tobytes() == value.tobytes()
        with pytest.raises(ValueError, match="shape"):
            whole.write_whole(value[:2])
        header = LowLevel(f.create_dataset("header", data=softsim.io.hdf5._header(0, -1, 0.0, 0.0, 0)))
        record = softsim.io.hdf5._header(3, 17, 0.5, 1.25, 99)
        header.write_whole(record)
        assert f["header"][()].tobytes() == record.tobytes()
