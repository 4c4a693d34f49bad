"""The XDMF sidecar, read back with vtkXdmfReader (the reader ParaView uses for .xdmf)."""

import os

import h5py
import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonDataModel import VTK_TETRA, vtkCompositeDataSet, vtkUnstructuredGrid
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

from softsim.io.xdmf import write_xdmf

N_FRAMES = 4
REST = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float64)
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]], dtype=np.int64)
TIMES = np.array([0.0, 0.1, 0.25, 1.0 / 3.0])


def _frame_points(i):
    return REST * (1.0 + 0.5 * i) + np.array([0.1 * i, -0.2 * i, 0.3 * i])


def _frame_velocities(i):
    return np.arange(REST.size, dtype=np.float64).reshape(REST.shape) * 10.0 + i


def _frame_stress(i):
    return np.array([1.0 + i, -2.0 * i - 0.5])


def _frame_F(i):
    """A (m, 3, 3) deliberately non-symmetric tensor per tet, to catch transposes."""
    return np.arange(len(TETS) * 9, dtype=np.float64).reshape(len(TETS), 3, 3) + 100.0 * i


def _frame_force(i):
    return np.arange(len(TETS) * 3, dtype=np.float64).reshape(len(TETS), 3) - 7.0 * i


def _make_h5(path, n_frames):
    """A run file in the HDF5 writer's layout, frames appended into resizable chunked datasets."""
    n, m = len(REST), len(TETS)
    with h5py.File(path, "w") as f:
        f["mesh/points"] = REST
        f["mesh/tets"] = TETS
        time = f.create_dataset("frames/time", (0,), maxshape=(None,), dtype="f8", chunks=(64,))
        pts = f.create_dataset("frames/points", (0, n, 3), maxshape=(None, n, 3), dtype="f8",
                               chunks=(1, n, 3))
        vel = f.create_dataset("frames/velocities", (0, n, 3), maxshape=(None, n, 3),
                               dtype="f8", chunks=(1, n, 3))
        stress = f.create_dataset("frames/stress", (0, m), maxshape=(None, m), dtype="f8",
                                  chunks=(1, m))
        F = f.create_dataset("frames/F", (0, m, 3, 3), maxshape=(None, m, 3, 3), dtype="f8",
                             chunks=(1, m, 3, 3))
        force = f.create_dataset("frames/force", (0, m, 3), maxshape=(None, m, 3), dtype="f8",
                                 chunks=(1, m, 3))
        for i in range(n_frames):
            for ds in (time, pts, vel, stress, F, force):
                ds.resize(i + 1, axis=0)
            time[i] = TIMES[i]
            pts[i] = _frame_points(i)
            vel[i] = _frame_velocities(i)
            stress[i] = _frame_stress(i)
            F[i] = _frame_F(i)
            force[i] = _frame_force(i)


def _write(tmp_path, n_frames, n_stored=None):
    """Write a run with `n_stored` frames in the HDF5 file and the first `n_frames` in the XDMF."""
    h5_path, xdmf_path = tmp_path / "out.h5", tmp_path / "out.xdmf"
    _make_h5(h5_path, n_stored or n_frames)
    write_xdmf(xdmf_path, h5_path, len(REST), len(TETS), TIMES[:n_frames],
               point_fields=[("velocity", "frames/velocities")],
               cell_fields=[("stress", "frames/stress", ()), ("F", "frames/F", (3, 3)),
                            ("force", "frames/force", (3,))])
    return xdmf_path


class _Reader:
    """vtkXdmfReader driven the way ParaView drives it; any VTK error or warning fails the test."""

    def __init__(self, xdmf_path):
        self.reader = vtkXdmfReader()
        self.messages = []
        for event in ("ErrorEvent", "WarningEvent"):
            self.reader.AddObserver(event, lambda obj, ev: self.messages.append(ev))
        self.reader.SetFileName(str(xdmf_path))
        self.reader.UpdateInformation()

    def time_steps(self):
        key = vtkStreamingDemandDrivenPipeline.TIME_STEPS()
        return np.array(self.reader.GetOutputInformation(0).Get(key))

    def frame(self, t):
        self.reader.UpdateTimeStep(t)
        output = self.reader.GetOutputDataObject(0)
        assert not self.messages, self.messages
        # A temporal collection of single grids comes out as the grid; be ready for a composite.
        if isinstance(output, vtkCompositeDataSet):
            blocks = vtkCompositeDataSet.GetDataSets(output)
            assert len(blocks) == 1
            output = blocks[0]
        assert isinstance(output, vtkUnstructuredGrid)
        cells = output.GetCells()
        return {
            "points": vtk_to_numpy(output.GetPoints().GetData()).copy(),
            "types": [output.GetCellType(c) for c in range(output.GetNumberOfCells())],
            "conn": vtk_to_numpy(cells.GetConnectivityArray()).copy(),
            "offsets": vtk_to_numpy(cells.GetOffsetsArray()).copy(),
            "velocity": vtk_to_numpy(output.GetPointData().GetArray("velocity")).copy(),
            "stress": vtk_to_numpy(output.GetCellData().GetArray("stress")).copy(),
            "F": vtk_to_numpy(output.GetCellData().GetArray("F")).copy(),
            "force": vtk_to_numpy(output.GetCellData().GetArray("force")).copy(),
        }


def _assert_frame(frame, f, i):
    """The grid the reader gave for frame i equals frame i of the HDF5 file `f`."""
    np.testing.assert_array_equal(frame["points"], f["frames/points"][i])
    np.testing.assert_array_equal(frame["types"], [VTK_TETRA] * len(TETS))
    np.testing.assert_array_equal(frame["conn"], TETS.ravel())
    np.testing.assert_array_equal(frame["offsets"], np.arange(len(TETS) + 1) * 4)
    np.testing.assert_array_equal(frame["velocity"], f["frames/velocities"][i])
    np.testing.assert_array_equal(frame["stress"].ravel(), f["frames/stress"][i])
    np.testing.assert_array_equal(frame["F"].reshape(-1, 3, 3), f["frames/F"][i])  # row-major
    np.testing.assert_array_equal(frame["force"], f["frames/force"][i])


def test_every_frame_round_trips_through_vtk_xdmf_reader(tmp_path):
    xdmf_path = _write(tmp_path, N_FRAMES)
    reader = _Reader(xdmf_path)
    with h5py.File(tmp_path / "out.h5", "r") as f:
        np.testing.assert_array_equal(reader.time_steps(), f["frames/time"][:])
        for i, t in enumerate(f["frames/time"][:]):
            _assert_frame(reader.frame(t), f, i)
    # The frames really differ, so a reader stuck on frame 0 would have failed above.
    assert not np.array_equal(_frame_points(0), _frame_points(N_FRAMES - 1))


def test_frames_in_any_order_from_one_reader(tmp_path):
    """Scrubbing back and forth in ParaView reuses one reader; no frame may come from a cache."""
    reader = _Reader(_write(tmp_path, N_FRAMES))
    with h5py.File(tmp_path / "out.h5", "r") as f:
        for i in [3, 0, 2, 2, 1, 3, 0]:
            _assert_frame(reader.frame(TIMES[i]), f, i)


def test_xdmf_may_describe_fewer_frames_than_the_h5_holds(tmp_path):
    """The HDF5 writer may be ahead of (or have over-allocated past) the last XDMF rewrite."""
    reader = _Reader(_write(tmp_path, 2, n_stored=N_FRAMES))
    np.testing.assert_array_equal(reader.time_steps(), TIMES[:2])
    with h5py.File(tmp_path / "out.h5", "r") as f:
        for i in range(2):
            _assert_frame(reader.frame(TIMES[i]), f, i)


def test_reader_sees_a_rerun_into_the_same_files(tmp_path):
    reader = _Reader(_write(tmp_path, N_FRAMES))
    reader.frame(TIMES[1])
    with h5py.File(tmp_path / "out.h5", "a") as f:
        f["frames/points"][...] += 100.0  # a new run, same file names
    reader.reader.Modified()
    with h5py.File(tmp_path / "out.h5", "r") as f:
        _assert_frame(reader.frame(TIMES[1]), f, 1)


def test_times_are_written_with_full_precision(tmp_path):
    xdmf_path = _write(tmp_path, N_FRAMES)
    assert f'Value="{1.0 / 3.0!r}"' in xdmf_path.read_text()


def test_h5_is_referenced_relative_to_the_xdmf(tmp_path):
    xdmf_path = _write(tmp_path, 2)
    text = xdmf_path.read_text()
    assert "out.h5:/frames/points" in text
    assert str(tmp_path) not in text


def test_h5_in_another_directory(tmp_path):
    (tmp_path / "data").mkdir()
    _make_h5(tmp_path / "data" / "run.h5", N_FRAMES)
    xdmf_path = tmp_path / "view" / "run.xdmf"
    xdmf_path.parent.mkdir()
    write_xdmf(xdmf_path, tmp_path / "data" / "run.h5", len(REST), len(TETS), TIMES)
    assert "../data/run.h5:/frames/points" in xdmf_path.read_text()
    reader = _Reader(xdmf_path)
    reader.reader.UpdateTimeStep(TIMES[2])
    points = vtk_to_numpy(reader.reader.GetOutputDataObject(0).GetPoints().GetData())
    np.testing.assert_array_equal(points, _frame_points(2))
    assert not reader.messages, reader.messages


def test_rewrite_is_atomic_and_grows_with_frames(tmp_path):
    _write(tmp_path, 2)
    xdmf_path = _write(tmp_path, N_FRAMES)  # the writer rewrites after each appended frame
    assert sorted(os.listdir(tmp_path)) == ["out.h5", "out.xdmf"]  # no temp file left
    reader = _Reader(xdmf_path)
    np.testing.assert_array_equal(reader.time_steps(), TIMES)
    np.testing.assert_array_equal(reader.frame(TIMES[-1])["points"], _frame_points(N_FRAMES - 1))


def test_replaced_not_rewritten_in_place(tmp_path):
    """A reader holding the old file open keeps reading the old, complete file."""
    xdmf_path = _write(tmp_path, 2)
    with open(xdmf_path) as old:
        _write(tmp_path, N_FRAMES)
        assert old.read().count("<Time ") == 2
    assert xdmf_path.read_text().count("<Time ") == N_FRAMES


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    xdmf_path = _write(tmp_path, 2)
    before = xdmf_path.read_text()
    with pytest.raises(ValueError):
        write_xdmf(xdmf_path, tmp_path / "out.h5", len(REST), len(TETS), TIMES,
                   cell_fields=[("bad", "frames/stress", (2,))])
    assert xdmf_path.read_text() == before
    assert sorted(os.listdir(tmp_path)) == ["out.h5", "out.xdmf"]


def test_failed_replace_leaves_no_temp(tmp_path):
    (tmp_path / "out.xdmf").mkdir()  # os.replace(file, directory) fails
    _make_h5(tmp_path / "out.h5", 2)
    with pytest.raises(OSError):
        write_xdmf(tmp_path / "out.xdmf", tmp_path / "out.h5", len(REST), len(TETS), TIMES[:2])
    assert sorted(os.listdir(tmp_path)) == ["out.h5", "out.xdmf"]
