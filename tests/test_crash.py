"""Crash safety, proven by killing runs: SIGKILL at chosen points inside the writer (the
``SOFTSIM_CRASH_AT`` hook) and at random moments, then open what is left.

Every kill must leave either no output file or one that opens with plain ``h5py.File(path)``,
whose ``frames/*`` datasets all have the same length, holding every frame completed before the
kill (``frames_written``), all finite, with ``status`` not ``complete``; its XDMF (if written yet) opens in
VTK's XDMF reader (ParaView's); and ``softsim run --resume`` finishes it into the same frames,
bit for bit, as a run that was never killed.
"""

import os
import random
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np
import pytest

from softsim.io.hdf5 import frames_written, read_resume_state

SCENE = """\
mesh: {shape: box, size: [0.2, 0.05, 0.05], element_size: 0.025, structured: true}
material: {model: stvk, youngs_modulus: 1.0e6, poissons_ratio: 0.3, density: 1000.0}
fixed: [{min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}]
time: {duration: 0.4}
output: {frame_interval: 0.002, fields: [velocities, energy]}
"""
FRAMES = 201       # 0.4 s / 0.002 s + the initial frame

# (hook point, frame): the frames completed before the kill are those before `frame`, plus
# `frame` itself once it has been flushed.
FRAME_POINTS = ["frame_start", "after_points", "after_velocities", "after_energy", "after_time",
                "before_flush", "before_commit", "after_flush"]
HOOKS = ([(point, 0) for point in FRAME_POINTS] + [(point, 7) for point in FRAME_POINTS]
         + [("before_xdmf", 0), ("before_rename", None), ("finish_before_status", None),
            ("finish_after_flush", None)])
RANDOM_KILLS = int(os.environ.get("SOFTSIM_RANDOM_KILLS", "10"))
ENV = {**os.environ, "NUMBA_NUM_THREADS": "1"}


def softsim(args, cwd, **env):
    return subprocess.Popen([sys.executable, "-m", "softsim.cli.main", *args], cwd=cwd,
                            env={**ENV, **env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def run_to_end(args, cwd, **env):
    process = softsim(args, cwd, **env)
    out, err = process.communicate(timeout=300)
    return process.returncode, err.decode()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A folder with the scene and the uninterrupted reference run (also warms the JIT cache)."""
    folder = tmp_path_factory.mktemp("crash")
    (folder / "scene.yaml").write_text(SCENE)
    code, err = run_to_end(["run", "scene.yaml", "-o", "reference.h5"], folder)
    assert code == 0, err
    return folder


def frame_datasets(f):
    """``{name under frames/: dataset}`` for every frames/* dataset."""
    found = {}

    def add(name, obj):      # returns None: a value would stop visititems
        if isinstance(obj, h5py.Dataset):
            found[name] = obj

    f["frames"].visititems(add)
    assert {"time", "points"} <= found.keys()
    return found


def check_left_file(path, frames_done=None, complete=False):
    """The file a kill left: opens, equal lengths, its complete frames finite, not complete (unless
    the kill came after the final status was on disk). Returns its frame count."""
    with h5py.File(path) as f:                       # plain open: no repair step
        assert (f.attrs["status"] == "complete") == complete
        k = frames_written(f)
        rows = f["frames/time"].shape[0]
        # a running (killed) file has a row for every planned frame; an ended one is trimmed
        assert rows == (FRAMES if f.attrs["status"] == "running" else k)
        for name, dataset in frame_datasets(f).items():
            assert dataset.shape[0] == rows, f"frames/{name} has {dataset.shape[0]} rows, frames/time {rows}"
            assert np.isfinite(dataset[:k]).all(), name
        assert np.all(np.diff(f["frames/time"][:k]) > 0)
        if k:     # the newest intact resume state is the last complete frame
            state = read_resume_state(f)
            assert state is not None and state["frames"] == k
            assert state["time"] == f["frames/time"][k - 1]
            assert np.array_equal(state["positions"], f["frames/points"][k - 1])
        if frames_done is not None:
            assert k == frames_done
    return k


def check_xdmf_opens(h5_path):
    """ParaView's reader opens the XDMF left beside the file and sees no more frames than it holds."""
    vtk = pytest.importorskip("vtkmodules.all")
    xdmf = h5_path.with_suffix(".xdmf")
    if not xdmf.exists():
        return
    reader = vtk.vtkXdmfReader()
    reader.SetFileName(str(xdmf))
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    steps = info.Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()) or ()
    with h5py.File(h5_path) as f:
        k = frames_written(f)
        assert 1 <= len(steps) <= k
        t_last = float(steps[-1])
        info.Set(vtk.vtkStreamingDemandDrivenPipeline.UPDATE_TIME_STEP(), t_last)
        reader.Update()
        grid = reader.GetOutputDataObject(0)
        while not hasattr(grid, "GetPoints"):          # a temporal collection: its only block
            grid = grid.GetBlock(0)
        i = int(np.argmin(abs(f["frames/time"][:k] - t_last)))
        assert grid.GetNumberOfPoints() == f["mesh/points"].shape[0]
        assert grid.GetNumberOfCells() == f["mesh/tets"].shape[0]
        points = np.array([grid.GetPoint(j) for j in range(grid.GetNumberOfPoints())])
        assert np.array_equal(points, f["frames/points"][i])


def check_resume_matches_reference(folder, name):
    code, err = run_to_end(["run", "scene.yaml", "-o", name, "--resume"], folder)
    assert code == 0, err
    with h5py.File(folder / name) as resumed, h5py.File(folder / "reference.h5") as reference:
        assert resumed.attrs["status"] == "complete"
        ours, theirs = frame_datasets(resumed), frame_datasets(reference)
        assert ours.keys() == theirs.keys()
        for key in theirs:
            assert np.array_equal(ours[key][...], theirs[key][...]), key


@pytest.mark.parametrize("resumed", [False, True])
def test_a_frame_writes_raw_data_first_and_its_header_last(tmp_path, monkeypatch, resumed):
    """Why a kill cannot tear the file: between start and end, a frame changes no HDF5 metadata.
    The bytes that change on disk are, first, its rows and the older state slot (flushed), then
    only that slot's 48-byte header; the file keeps its length.  The same after a resume (the
    interrupted file was trimmed and compacted, and is extended again)."""
    from softsim.io import hdf5

    n, m, path = 50, 30, tmp_path / "w.h5"
    rng = np.random.default_rng(0)
    template = {"guard_J_seen": np.zeros(m), "guard_substeps": 1, "guard_held_work": 0.0}
    writer = hdf5.RunWriter(path, rng.random((n, 3)), rng.integers(0, n, (m, 4)), np.zeros(n, bool), "", 1e-3, 100,
                            fields=("velocities", "energy", "stress", "J"), frames=100, resume_template=template)
    snapshots = {}

    def snapshot(name, frame=None):
        if frame == 3 and name in ("before_commit", "after_flush"):
            snapshots[name] = np.frombuffer(path.read_bytes(), np.uint8)

    monkeypatch.setattr(hdf5, "crash_point", snapshot)

    def frame(k):
        writer.append_frame(k * 1e-3, k, rng.random((n, 3)), rng.random((n, 3)),
                            {"kinetic": 1.0, "elastic": 2.0, "gravity": 3.0},
                            {"guard_J_seen": rng.random(m), "guard_substeps": 2, "guard_held_work": 0.5},
                            {"stress": rng.random((m, 3, 3)), "J": rng.random(m)})

    for k in range(3):
        frame(k)
    if resumed:
        writer.finish("interrupted")
        with h5py.File(path) as f:
            assert f["frames/points"].shape[0] == 3
        writer, state = hdf5.RunWriter.reopen(path, ("velocities", "energy", "stress", "J"), frames=100)
        assert state["frames"] == 3 and state["guard_substeps"] == 2
    before = np.frombuffer(path.read_bytes(), np.uint8)
    frame(3)
    f = writer.file
    slot = f["state/b"]                     # frames 0, 1, 2 went to slots a, b, a
    allowed = np.zeros(before.size, bool)
    for dataset in [f["frames/time"], f["frames/points"], f["frames/velocities"], f["frames/stress"],
                    f["frames/J"], *(f["frames/energy"][term] for term in f["frames/energy"])]:
        info = dataset.id.get_chunk_info_by_coord((3 // dataset.chunks[0] * dataset.chunks[0],) + (0,) * (dataset.ndim - 1))
        allowed[info.byte_offset:info.byte_offset + info.size] = True
    for name in slot:                      # by name: h5py's items() holds its lock between members
        dataset = slot[name]
        if name != "header":
            allowed[dataset.id.get_offset():dataset.id.get_offset() + dataset.id.get_storage_size()] = True
    header = np.zeros(before.size, bool)
    header[slot["header"].id.get_offset():slot["header"].id.get_offset() + hdf5.HEADER_DTYPE.itemsize] = True
    data_phase, header_phase = snapshots["before_commit"], snapshots["after_flush"]
    assert before.size == data_phase.size == header_phase.size
    changed = before != data_phase
    assert changed.any() and not (changed & ~allowed).any(), "a frame's data flush changed bytes outside its rows"
    changed = data_phase != header_phase
    assert changed.any() and not (changed & ~header).any(), "the commit changed more than the header"
    assert frames_written(f) == 4
    writer.finish("complete")


def expected_frames(point, frame):
    if point in ("finish_before_status", "finish_after_flush"):
        return FRAMES
    if point in ("before_xdmf", "after_flush"):
        return frame + 1
    return frame


def kill_at_hook(folder, point, frame):
    name = f"hook-{point}-{frame}.h5"
    code, err = run_to_end(["run", "scene.yaml", "-o", name], folder,
                           SOFTSIM_CRASH_AT=point if frame is None else f"{point}:{frame}")
    assert code == -signal.SIGKILL, f"{point}:{frame} did not kill the run (exit {code}): {err}"
    return name


def test_a_kill_at_every_writer_point_leaves_a_readable_file_that_resumes(workdir):
    with ThreadPoolExecutor(2) as pool:
        names = list(pool.map(lambda hook: kill_at_hook(workdir, *hook), HOOKS))
    for (point, frame), name in zip(HOOKS, names):
        path = workdir / name
        if point == "before_rename":
            # Killed before the file had its layout: nothing under the output name, and
            # only the hidden partial file is left behind.
            assert not path.exists()
            assert list(workdir.glob(f".{name}.partial-*"))
            continue
        check_left_file(path, expected_frames(point, frame), complete=point == "finish_after_flush")
        check_xdmf_opens(path)
    # Resume every kill that left a frame and no final status; a file with no frame yet is refused.
    resumable = [name for (point, frame), name in zip(HOOKS, names)
                 if frame or point == "finish_before_status"]
    code, err = run_to_end(["run", "scene.yaml", "-o", "hook-frame_start-0.h5", "--resume"], workdir)
    assert code != 0 and "no complete frame" in err and "Traceback" not in err
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda name: check_resume_matches_reference(workdir, name), resumable))


def file_span(folder, name):
    """Run the scene to its end as ``kill_at_random`` starts one, and return the seconds its
    frames took (the file's ``wall_time_s``: from making the file to the last frame), measured now,
    on the machine as loaded now.  The process lives on for a while after (the finish, the
    interpreter's exit): a span taken from outside, to the process's end, sent most kills there."""
    code, err = run_to_end(["run", "scene.yaml", "-o", name], folder)
    assert code == 0, err
    with h5py.File(folder / name) as f:
        return float(f.attrs["wall_time_s"])


def kill_at_random(folder, seed, span):
    """Start a run and SIGKILL it at a random moment of its life (start-up included); span [s]:
    about how long its frames take (``file_span``)."""
    name = f"random-{seed}.h5"
    rng = random.Random(seed)
    process = softsim(["run", "scene.yaml", "-o", name], folder)
    started = time.monotonic()
    # Most kills land while frames are written: wait for the file, then a random part of its life.
    if rng.random() < 0.8:
        while not (folder / name).exists() and process.poll() is None and time.monotonic() - started < 120:
            time.sleep(0.001)
        time.sleep(rng.uniform(0.1, 0.9) * span)
    else:       # during start-up: before the output file exists, or while it is being made
        time.sleep(rng.uniform(0.0, 1.0))
    process.send_signal(signal.SIGKILL)
    process.communicate()
    return name, process.returncode


def check_killed_run(path, code):
    """Check what a random kill left (``kill_at_random``); return the frames in the file (``FRAMES``
    if the run finished, 0 if it left none or no file)."""
    if code == 0:          # finished before the kill: a complete file
        with h5py.File(path) as f:
            assert f.attrs["status"] == "complete"
        return FRAMES
    assert code == -signal.SIGKILL
    if not path.exists():
        return 0
    with h5py.File(path) as f:      # killed after the final status was on disk: complete
        complete = f.attrs["status"] == "complete"
    frames = check_left_file(path, FRAMES if complete else None, complete=complete)
    check_xdmf_opens(path)
    return frames


@pytest.mark.skipif(RANDOM_KILLS == 0, reason="SOFTSIM_RANDOM_KILLS=0")
def test_kills_at_random_moments_leave_readable_files(workdir):
    """Every file a random kill leaves is checked, and as many kills as half a round, counted over
    up to three rounds, must fall while frames are written (0 < frames < FRAMES).  Each round first
    times the frames of two whole runs on the machine as loaded then, the shorter counting (the
    other test worker comes and goes: a time taken earlier, as the reference run's, missed the
    frames on a busy machine)."""
    rounds = []
    for round_ in range(3):
        seeds = range(round_ * RANDOM_KILLS, (round_ + 1) * RANDOM_KILLS)
        with ThreadPoolExecutor(2) as pool:      # two at a time, as the kills run
            span = min(pool.map(lambda k: file_span(workdir, f"span-{round_}-{k}.h5"), range(2)))
            outcomes = list(pool.map(lambda seed: kill_at_random(workdir, seed, span), seeds))
        frames = [check_killed_run(workdir / name, code) for name, code in outcomes]
        rounds.append((round(span, 3), frames))
        if sum(0 < n < FRAMES for _, kept in rounds for n in kept) >= RANDOM_KILLS // 2:
            break
    else:
        pytest.fail(f"the random kills missed the frame-writing phase: (span [s], frames left) per round {rounds}")


def test_a_full_disk_stops_the_run_in_one_line_and_keeps_the_frames(workdir, monkeypatch):
    """The disk fills up during the run (free space shrinks with every frame): the run stops
    before the frame that would not fit, with one line; the file keeps the frames before and
    says ``failed``."""
    from softsim.config import load_scene
    from softsim.errors import SimulationError
    from softsim.io import hdf5
    from softsim.simulation import prepare, simulate

    free = iter(np.linspace(20e6, 0.0, 21))
    monkeypatch.setattr(hdf5, "free_bytes", lambda path: next(free))
    with pytest.raises(SimulationError) as error:
        simulate(prepare(load_scene(workdir / "scene.yaml")), workdir / "full.h5")
    message = str(error.value)
    assert "disk is full" in message and "frames before it are kept" in message and "\n" not in message
    with h5py.File(workdir / "full.h5") as f:
        assert f.attrs["status"] == "failed" and "disk is full" in f.attrs["status_reason"]
    frames = check_left_file(workdir / "full.h5", complete=False)
    assert 1 <= frames < FRAMES
