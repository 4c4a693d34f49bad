"""Clean stops and output safety: SIGTERM / Ctrl-C end a run after a whole frame with status
``interrupted`` and exit code 130; an existing output file is never silently overwritten."""

import hashlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest
from click.testing import CliRunner

from softsim.cli.main import cli
from softsim.errors import SimulationError
from softsim.io.hdf5 import RunWriter, check_writable, frames_written, read_resume_state

SCENE = """\
mesh: {shape: box, size: [0.3, 0.1, 0.1], element_size: 0.05, structured: true}
material: {model: stvk, youngs_modulus: 1.0e6, poissons_ratio: 0.3, density: 1000.0}
fixed: [{min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}]
time: {duration: DURATION}
output: {path: out.h5, frame_interval: 0.001, fields: [velocities]}
"""


def write_scene(folder, duration):
    path = Path(folder) / "scene.yaml"
    path.write_text(SCENE.replace("DURATION", str(duration)))
    return path


def frame_count(path):
    """Frames written so far, read without locking while the run is writing (0 if not readable yet)."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return frames_written(f)
    except (OSError, KeyError):
        return 0


def start_long_run(folder, frames, env=None):
    """``(process, scene, out)``: ``softsim run`` of a scene far longer than a test waits, in a
    process of its own writing ``folder/out.h5``, once it has written ``frames`` frames.
    env: variables to set in that process's environment."""
    scene = write_scene(folder, 1000.0)
    out = Path(folder) / "out.h5"
    process = subprocess.Popen([sys.executable, "-m", "softsim.cli.main", "run", str(scene), "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, **(env or {})})
    deadline = time.monotonic() + 120             # room for a first JIT compilation
    while frame_count(out) < frames:
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"no {frames} frames written in time: {process.communicate()}")
        time.sleep(0.05)
    return process, scene, out


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_the_run_after_a_whole_frame(tmp_path, sig):
    process, scene, out = start_long_run(tmp_path, 3)
    try:
        os.kill(process.pid, sig)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert "interrupted at t = " in stderr.splitlines()[-1]
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "interrupted"
        assert "stopped on request at t = " in f.attrs["status_reason"]
        k = f["frames/time"].shape[0]
        assert k >= 3
        assert f["frames/points"].shape[0] == k and f["frames/velocities"].shape[0] == k
        assert f["frames/time"][-1] < 1000.0
        state = read_resume_state(f)
        assert state["step"] > 0 and state["time"] == f["frames/time"][-1] and state["frames"] == k
        planned = int(f.attrs["steps"])
    # the summary line counts the steps done, not the planned ones
    assert stdout.startswith(f"{out}: {state['step']} of {planned} steps, "), stdout


@pytest.mark.parametrize("hdf5_locking", ["TRUE", "FALSE"])
def test_a_file_another_run_is_writing_is_refused_even_with_overwrite(tmp_path, monkeypatch, hdf5_locking):
    """Two runs into one file: the second would replace the file under the first, both would report
    success and the first's frames would be lost.  HDF5 holds a lock on a file it writes, and where
    its locking is off (``HDF5_USE_FILE_LOCKING=FALSE``, common on clusters) the run holds one.
    ``softsim mesh -o out.xdmf`` would write the run's file too (meshio puts an XDMF file's data in
    ``out.h5``)."""
    monkeypatch.chdir(tmp_path)
    process, scene, _ = start_long_run(tmp_path, 1, env={"HDF5_USE_FILE_LOCKING": hdf5_locking})
    try:
        runner = CliRunner()
        for command, message in (
                (["run", "-o", "out.h5", "--overwrite"], "output.path = 'out.h5': another run is writing this file now"),
                (["run", "-o", "out.h5", "--resume"], "--resume: another run is writing 'out.h5' now"),
                (["mesh", "-o", "out.xdmf", "--overwrite"], "--output = 'out.xdmf': another run is writing 'out.h5' now")):
            # a short second run: one that went ahead would end soon and fail the test, not hang it
            second = runner.invoke(cli, [command[0], str(scene), *command[1:], "--set", "time.duration=0.002"])
            assert second.exit_code == 1, second.output
            assert second.stderr.strip().splitlines()[-1].startswith(f"Error: {message}"), second.stderr
        assert process.poll() is None                 # the first run goes on
    finally:
        process.kill()
        process.communicate()


def two_tets():
    """``(points, tets, fixed)`` of a mesh small enough to give RunWriter directly."""
    return np.random.default_rng(0).random((8, 3)), np.array([[0, 1, 2, 3], [4, 5, 6, 7]]), np.zeros(8, bool)


@pytest.mark.parametrize("hdf5_locking", ["TRUE", "FALSE"])
@pytest.mark.parametrize("existing", [False, True], ids=["new-file", "over-a-complete-file"])
def test_two_runs_started_together_on_one_output_cannot_both_write_it(tmp_path, monkeypatch, hdf5_locking,
                                                                        existing):
    """Both runs pass ``check_writable`` before either has made its file; the second's rename then
    replaced the first's file, whose frames went on into a file no longer on disk.  Now the second
    is refused at its rename, leaving nothing behind, and the first's file is the one on disk."""
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", hdf5_locking)
    out = tmp_path / "out.h5"
    points, tets, fixed = two_tets()
    if existing:
        with RunWriter(out, points, tets, fixed, "earlier", 1e-3, 10):
            pass
    check_writable(out, overwrite=True)                       # the first run's check
    check_writable(out, overwrite=True)                       # the second run's, before the first's file exists
    with RunWriter(out, points, tets, fixed, "first", 1e-3, 10) as first:
        with pytest.raises(SimulationError, match=r"^output.path = '.*out.h5': another run is writing this file now"):
            RunWriter(out, points, tets, fixed, "second", 1e-3, 10)
        first.append_frame(0.0, 0, points, np.zeros_like(points), None, {})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5", "out.xdmf"]     # no partial file left
    with h5py.File(out, "r") as f:
        assert f.attrs["config"] == "first" and f.attrs["status"] == "complete" and frames_written(f) == 1


def test_the_checks_and_renames_of_two_runs_do_not_interleave(tmp_path, monkeypatch):
    """The race itself: while the first run renames its file into place, a second (a thread here,
    another process in life) makes its file and checks; it must wait for the first's rename and
    then be refused, not rename its own file first and have it replaced."""
    from softsim.io import hdf5

    out = tmp_path / "out.h5"
    points, tets, fixed = two_tets()
    real_replace, real_flock = os.replace, hdf5.fcntl.flock
    seconds, outcomes = [], []
    second_waits = threading.Event()

    class Fcntl:                     # hdf5's fcntl, telling when the second run waits for the folder
        LOCK_EX, LOCK_SH, LOCK_NB = hdf5.fcntl.LOCK_EX, hdf5.fcntl.LOCK_SH, hdf5.fcntl.LOCK_NB

        @staticmethod
        def flock(fd, operation):
            if seconds and threading.current_thread() is seconds[0] and operation == hdf5.fcntl.LOCK_EX:
                second_waits.set()
            return real_flock(fd, operation)

    def second_run():
        try:
            RunWriter(out, points, tets, fixed, "second", 1e-3, 10).finish("complete")
            outcomes.append("wrote its file")
        except SimulationError as exc:
            outcomes.append(str(exc))

    def first_rename(source, target):
        monkeypatch.setattr(hdf5.os, "replace", real_replace)      # the second run's rename is real
        second = threading.Thread(target=second_run)
        seconds.append(second)
        second.start()
        second_waits.wait(30)                                      # it asked for the folder's lock ...
        second.join(0.2)
        outcomes.append("waited" if second.is_alive() else "went ahead")   # ... and did not get it
        real_replace(source, target)

    monkeypatch.setattr(hdf5, "fcntl", Fcntl)
    monkeypatch.setattr(hdf5.os, "replace", first_rename)
    with RunWriter(out, points, tets, fixed, "first", 1e-3, 10):
        seconds[0].join(30)                                      # the first run still writing
    assert outcomes[0] == "waited", outcomes
    assert len(outcomes) == 2 and "another run is writing this file now" in outcomes[1], outcomes
    with h5py.File(out, "r") as f:
        assert f.attrs["config"] == "first"


def test_a_file_made_after_the_check_is_not_replaced_without_overwrite(tmp_path):
    """A run without --overwrite whose check passed, while another run made the file and ended
    before this one renamed its own into place: the finished file stays."""
    out = tmp_path / "out.h5"
    points, tets, fixed = two_tets()
    check_writable(out, overwrite=False)                         # nothing there yet
    with RunWriter(out, points, tets, fixed, "other", 1e-3, 10):
        pass
    with pytest.raises(SimulationError, match=r"the file exists; pass --overwrite to replace it"):
        RunWriter(out, points, tets, fixed, "this", 1e-3, 10, overwrite=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5", "out.xdmf"]
    with h5py.File(out, "r") as f:
        assert f.attrs["config"] == "other"


@pytest.mark.parametrize("hdf5_locking", ["TRUE", "FALSE"])
def test_a_resume_is_refused_on_a_file_a_new_run_has_just_made(tmp_path, monkeypatch, hdf5_locking):
    """A resume checked before a new run renamed its file into place: it opened that file too,
    and with HDF5's locking off both wrote it."""
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", hdf5_locking)
    out = tmp_path / "out.h5"
    points, tets, fixed = two_tets()
    with RunWriter(out, points, tets, fixed, "new", 1e-3, 10):
        with pytest.raises(SimulationError, match=r"^--resume: another run is writing '.*out.h5' now"):
            RunWriter.reopen(out)


def test_an_existing_output_is_not_overwritten_without_the_flag(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    runner = CliRunner()
    first = runner.invoke(cli, ["run", str(scene)])
    assert first.exit_code == 0, first.output
    before = (tmp_path / "out.h5").stat().st_mtime_ns

    again = runner.invoke(cli, ["run", str(scene)])
    assert again.exit_code != 0
    assert again.stderr.strip().splitlines() == [
        "Error: output.path = 'out.h5': the file exists; pass --overwrite to replace it"]
    assert (tmp_path / "out.h5").stat().st_mtime_ns == before

    replaced = runner.invoke(cli, ["run", str(scene), "--overwrite"])
    assert replaced.exit_code == 0, replaced.output
    with h5py.File(tmp_path / "out.h5") as f:
        assert f.attrs["status"] == "complete"


def test_an_unfinished_run_is_not_overwritten_and_resume_is_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    with h5py.File(tmp_path / "out.h5", "w") as f:
        f.attrs["status"] = "interrupted"
    again = CliRunner().invoke(cli, ["run", str(scene)])
    assert again.exit_code == 1
    assert again.stderr.strip().splitlines() == [
        "Error: output.path = 'out.h5': the file holds an unfinished run (status: interrupted); pass --resume to "
        "continue it or --overwrite to replace it"]


def test_a_failed_run_is_not_overwritten_and_its_reason_is_named(tmp_path, monkeypatch):
    """A run that failed (a blow-up: resuming the same scene fails again) points to --overwrite
    first, and to --resume only for a failure from outside the run."""
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    with h5py.File(tmp_path / "out.h5", "w") as f:
        f.attrs["status"] = "failed"
        f.attrs["status_reason"] = "blew up at t = 0.01 s"
    again = CliRunner().invoke(cli, ["run", str(scene)])
    assert again.exit_code == 1
    assert again.stderr.strip().splitlines() == [
        "Error: output.path = 'out.h5': the file holds a run that failed (blew up at t = 0.01 s); pass --overwrite "
        "to replace it (--resume goes on from its last complete frame: only for a failure from outside the run, "
        "such as a full disk)"]


def test_an_existing_xdmf_is_not_overwritten_without_the_flag(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    (tmp_path / "out.xdmf").write_text("my notes\n")
    runner = CliRunner()
    again = runner.invoke(cli, ["run", str(scene)])
    assert again.exit_code == 1
    assert again.stderr.strip().splitlines() == [
        "Error: output.path = 'out.h5': the XDMF file out.xdmf written beside it exists; pass --overwrite to "
        "replace it"]
    assert (tmp_path / "out.xdmf").read_text() == "my notes\n" and not (tmp_path / "out.h5").exists()
    assert runner.invoke(cli, ["run", str(scene), "--overwrite"]).exit_code == 0
    assert "<Xdmf" in (tmp_path / "out.xdmf").read_text()


@pytest.mark.parametrize("command", ["run", "mesh"])
@pytest.mark.parametrize("mesh_files", [("bar.vtu",), ("bar.xdmf", "bar.h5")])
def test_the_scene_and_its_mesh_file_are_never_written_over(tmp_path, monkeypatch, command, mesh_files):
    """Nor an XDMF mesh's data file (meshio reads ``bar.xdmf``'s arrays from ``bar.h5``), nor the
    mesh through the XDMF file a run writes beside its output (``-o bar.hdf5`` writes ``bar.xdmf``)."""
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    assert runner.invoke(cli, ["mesh", str(write_scene(tmp_path, 0.002)), "-o", mesh_files[0]]).exit_code == 0
    assert sorted(p.name for p in tmp_path.glob("bar.*")) == sorted(mesh_files)
    scene = tmp_path / "file.yaml"
    scene.write_text(SCENE.replace("DURATION", "0.002").replace(
        "{shape: box, size: [0.3, 0.1, 0.1], element_size: 0.05, structured: true}",
        f"{{shape: file, file: {mesh_files[0]}}}"))
    before = {name: (tmp_path / name).read_bytes() for name in ("file.yaml", *mesh_files)}
    outputs = [*before, "bar.hdf5"] if command == "run" and len(mesh_files) == 2 else list(before)
    for name in outputs:
        result = runner.invoke(cli, [command, str(scene), "-o", name, "--overwrite"])
        assert result.exit_code == 1
        assert "the scene's own file" in result.stderr and "choose another" in result.stderr, result.stderr
    assert {name: (tmp_path / name).read_bytes() for name in before} == before


@pytest.mark.parametrize("overwrite", [False, True])
def test_mesh_never_writes_an_xdmf_mesh_over_a_run(tmp_path, monkeypatch, overwrite):
    """meshio writes ``out.xdmf``'s arrays to ``out.h5``: a finished run's file there was replaced
    by the mesh's 22 kB with --overwrite, and the run's results were lost."""
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    runner = CliRunner()
    assert runner.invoke(cli, ["run", str(scene)]).exit_code == 0
    before = (tmp_path / "out.h5").read_bytes()
    result = runner.invoke(cli, ["mesh", str(scene), "-o", "out.xdmf"] + (["--overwrite"] if overwrite else []))
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [
        "Error: --output = 'out.xdmf': meshio writes an XDMF file's data to 'out.h5', which holds a softsim "
        "run's results; choose another output name"]
    assert (tmp_path / "out.h5").read_bytes() == before


@pytest.mark.parametrize("output, existing, message", [
    ("bar.vtu", "bar.vtu", "the file exists"),
    # meshio writes bar.xdmf's arrays into bar.h5: a finished run's file of that name was lost to
    # softsim mesh -o bar.xdmf
    ("bar.xdmf", "bar.h5", "meshio writes an XDMF file's data to 'bar.h5', which exists"),
])
def test_mesh_does_not_overwrite_without_the_flag(tmp_path, monkeypatch, output, existing, message):
    monkeypatch.chdir(tmp_path)
    scene = write_scene(tmp_path, 0.002)
    runner = CliRunner()
    (tmp_path / existing).write_text("mine\n")
    result = runner.invoke(cli, ["mesh", str(scene), "-o", output])
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [
        f"Error: --output = '{output}': {message}; pass --overwrite to replace it"]
    assert (tmp_path / existing).read_text() == "mine\n" and sorted(p.name for p in tmp_path.glob("bar.*")) == [existing]
    assert runner.invoke(cli, ["mesh", str(scene), "-o", output, "--overwrite"]).exit_code == 0
    assert meshio.read(tmp_path / output).cells_dict["tetra"].shape[1] == 4


def _stop_after(frames):
    """A ``should_stop`` that asks for a stop once ``frames`` frames have been written."""
    calls = []

    def should_stop():
        calls.append(1)
        return len(calls) >= frames

    return should_stop


@pytest.mark.parametrize("model, extra", [
    ("stvk", {}),
    # a crushed corotated cube: moving held box, sub-steps from the guard's re-checks, damping
    ("corotated", {"damping": 5.0, "gravity": [0, 0, -9.81],
                   "fixed": [{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]},
                             {"min": [-1, -1, 0.1 - 1e-6], "max": [1, 1, 1], "velocity": [0, 0, -1.0]}]}),
    # float32: the state crosses to float32 and back at every call; a dropped cube on a ground
    ("neohookean", {"precision": "float32", "damping": 2.0, "gravity": [0, 0, -9.81],
                    "initial_velocity": [0, 0, -1.0], "ground": {"height": -0.002}}),
])
def test_resume_continues_bit_for_bit(scene, tmp_path, model, extra):
    """Stopped after 4 frames and resumed, a run writes exactly the frames, bits and all, of the
    run that never stopped; state/ and the guard's decisions (sub-steps) carry over."""
    from softsim.simulation import check_resumable, prepare, simulate

    s = scene(mesh={"size": [0.1, 0.1, 0.1], "element_size": 0.05}, material={"model": model},
              time={"duration": 0.08}, output={"frame_interval": 0.01, "fields": ["velocities", "energy"]},
              **extra)
    whole = simulate(prepare(s), tmp_path / "whole.h5")
    stopped = simulate(prepare(s), tmp_path / "part.h5", should_stop=_stop_after(4))
    assert stopped.status == "interrupted" and stopped.frames == 5
    check_resumable(s, tmp_path / "part.h5")
    resumed = simulate(prepare(s), tmp_path / "part.h5", resume=True)
    assert resumed.status == "complete" and resumed.frames == whole.frames
    with h5py.File(tmp_path / "whole.h5") as a, h5py.File(tmp_path / "part.h5") as b:
        assert b.attrs["status"] == "complete"
        for name in ("frames/time", "frames/points", "frames/velocities"):
            assert (a[name][...] == b[name][...]).all(), name
        state_a, state_b = read_resume_state(a), read_resume_state(b)
        assert set(state_a) == set(state_b)
        for name in set(state_a) - {"wall_time_s"}:     # the guard's numbers too (its re-look threshold, ...)
            assert np.array_equal(state_a[name], state_b[name]), name


def test_resume_refuses_a_mesh_file_whose_content_changed(scene, tmp_path):
    """The scene names a mesh file, not what it holds: a file edited since the run began is
    refused by the check before meshing (its stored SHA-256) and, for a file written without the
    hash, by the writer (the stored mesh against the new one); nothing in the file changes."""
    from softsim.errors import SimulationError
    from softsim.mesh.generate import structured_box
    from softsim.simulation import check_resumable, prepare, simulate

    points, tets = structured_box((0.1, 0.1, 0.1), (0.0, 0.0, 0.0), 0.05)
    mesh_file = tmp_path / "cube.vtu"
    meshio.write(mesh_file, meshio.Mesh(points, [("tetra", tets)]))
    cleared = {key: None for key in ("size", "element_size", "structured", "origin")}
    s = scene(mesh={**cleared, "shape": "file", "file": "cube.vtu"}, time={"duration": 0.05},
              output={"frame_interval": 0.01})
    part = tmp_path / "part.h5"
    simulate(prepare(s), part, should_stop=_stop_after(2))
    with h5py.File(part) as f:
        assert f.attrs["mesh_file_sha256"] == hashlib.sha256(mesh_file.read_bytes()).hexdigest()
    check_resumable(s, part)                                  # unchanged: resumable

    moved = points.copy()
    moved[0, 0] -= 1e-4                                       # one vertex moved by 0.1 mm
    meshio.write(mesh_file, meshio.Mesh(moved, [("tetra", tets)]))
    with pytest.raises(SimulationError, match=r"scene changed .*mesh.file: the content of .*cube.vtu' changed"):
        check_resumable(s, part)
    with h5py.File(part, "a") as f:                           # as if written before the hash was stored
        del f.attrs["mesh_file_sha256"]
    check_resumable(s, part)
    before = part.read_bytes()
    with pytest.raises(SimulationError, match="the mesh differs from the one .* was written with"):
        simulate(prepare(s), part, resume=True)
    assert part.read_bytes() == before
    meshio.write(mesh_file, meshio.Mesh(points, [("tetra", tets)]))      # the mesh it was run with, again
    assert simulate(prepare(s), part, resume=True).status == "complete"
    with h5py.File(part) as f:                                # and the resumed file records the hash
        assert f.attrs["mesh_file_sha256"] == hashlib.sha256(mesh_file.read_bytes()).hexdigest()


def test_resume_refuses_a_changed_scene_a_complete_run_and_a_missing_file(scene, tmp_path):
    from softsim.errors import SimulationError
    from softsim.simulation import check_resumable, prepare, simulate

    s = scene(time={"duration": 0.05}, output={"frame_interval": 0.01})
    with pytest.raises(SimulationError, match="nothing to resume"):
        check_resumable(s, tmp_path / "none.h5")
    simulate(prepare(s), tmp_path / "part.h5", should_stop=_stop_after(2))
    changed = scene(time={"duration": 0.05}, output={"frame_interval": 0.01}, material={"density": 2000.0})
    with pytest.raises(SimulationError, match=r"scene changed .*material.density: 1000.0 -> 2000.0"):
        check_resumable(changed, tmp_path / "part.h5")
    simulate(prepare(s), tmp_path / "part.h5", resume=True)
    with pytest.raises(SimulationError, match="is complete"):
        check_resumable(s, tmp_path / "part.h5")


def test_resume_refuses_a_file_whose_resume_state_lacks_what_the_guard_now_keeps(scene, tmp_path, monkeypatch):
    """A run file of an earlier softsim, whose guard kept fewer numbers (here: no
    ``guard_recheck_change``), cannot go on the same way: refused in one line naming what it lacks,
    not a failure at its first frame."""
    from softsim.errors import SimulationError
    from softsim.integrators.guard import FrameGuard
    from softsim.model import initial_state
    from softsim.simulation import check_resumable, prepare, simulate

    s = scene(time={"duration": 0.05}, output={"frame_interval": 0.01})
    current = FrameGuard.snapshot
    with monkeypatch.context() as patch:       # the guard of the earlier softsim
        patch.setattr(FrameGuard, "snapshot",
                      lambda self: {k: v for k, v in current(self).items() if k != "guard_recheck_change"})
        simulate(prepare(s), tmp_path / "old.h5", should_stop=_stop_after(2))
    with pytest.raises(SimulationError, match=r"earlier softsim, whose resume state lacks guard_recheck_change; "
                                              r"start the run again with --overwrite"):
        check_resumable(s, tmp_path / "old.h5")
    with h5py.File(tmp_path / "old.h5") as f:
        before = dict(f.attrs)
    with pytest.raises(SimulationError, match="lacks guard_recheck_change"):   # the library's resume too,
        simulate(prepare(s), tmp_path / "old.h5", resume=True)                 # and the file is left as it was
    with h5py.File(tmp_path / "old.h5") as f:
        assert dict(f.attrs) == before and f.attrs["status"] == "interrupted"
    model = prepare(s).model
    guard = FrameGuard(model, 1.0, 1e-4, "substep", initial_state(s, model))
    assert set(current(guard)) == set(FrameGuard.SNAPSHOT_NAMES)


def test_cli_resume_after_sigterm(tmp_path):
    """The README's promise end to end: kill a run with SIGTERM, `--resume` finishes it."""
    scene = write_scene(tmp_path, 0.03)
    out = tmp_path / "out.h5"
    process = subprocess.Popen([sys.executable, "-m", "softsim.cli.main", "run", str(scene), "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while frame_count(out) < 2 and process.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        if process.poll() is None:
            os.kill(process.pid, signal.SIGTERM)
        process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    with h5py.File(out) as f:
        kept = frames_written(f)
        last = float(f["frames/time"][kept - 1])
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(out), "--resume"])
    if process.returncode == 130:
        assert result.exit_code == 0, result.output
        assert f"info: resuming {out} from t = {last:.6g} s, its last complete frame ({kept} kept)" in result.stderr
        assert re.search(r"wall [0-9.]+ s this session", result.stdout), result.stdout
    else:    # the run had already finished before the signal arrived
        assert result.exit_code != 0 and "is complete" in result.stderr
    with h5py.File(out) as f:
        assert f.attrs["status"] == "complete"
        assert f["frames/time"].shape[0] == 31
