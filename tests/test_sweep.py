"""``softsim sweep``: the sweep file's checks, run names, and real sweeps on a local Dask cluster.

One cluster of two single-threaded process workers serves the whole module; the sweeps run a
120-tet bar for a few dozen steps, so the file takes well under a minute on a quiet 2-core machine.
"""

import asyncio
import contextlib
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from softsim.cli import sweep as cli_sweep
from softsim.cli.main import cli
from softsim.config import parse_scene
from softsim.errors import ConfigError, MissingDependencyError, SimulationError
from softsim.mesh import build_mesh
from softsim.simulation import prepare, simulate
from softsim.sweep import expand_sweep, load_sweep, parse_sweep, plot_summary, run_sweep, tip_vertices
from softsim.sweep.runner import (build_meshes, import_distributed, local_client, plan_runs, summary_columns,
                                  write_summary)
from softsim.sweep import runner
from softsim.sweep.spec import format_value, labels_for, run_name

pytest.importorskip("distributed")

# A 0.3 x 0.1 x 0.1 m bar clamped at x = 0: 120 tets, 63 vertices; 50 steps of 1e-4 s, 6 frames.
BAR = {
    "mesh": {"shape": "box", "size": [0.3, 0.1, 0.1], "origin": [0.0, -0.05, -0.05],
             "element_size": 0.05, "structured": True},
    "material": {"model": "stvk", "youngs_modulus": 1.0e6, "poissons_ratio": 0.3, "density": 1000.0},
    "fixed": [{"min": [-1.0e-6, -1, -1], "max": [1.0e-6, 1, 1]}],
    "time": {"duration": 0.005, "dt": 1.0e-4, "dt_policy": "allow"},
    "output": {"frame_interval": 0.001},
}
# 2 x 2: at E = 1e7 Pa the stable step is about 1.6e-4 s, so dt = 4e-4 s (dt_policy: allow) blows up
# and the guard stops that run; the other three finish.
SWEEP = {"base": "bar.yaml",
         "parameters": {"material.youngs_modulus": [1.0e6, 1.0e7], "time.dt": [1.0e-4, 4.0e-4]}}
NAMES = ["youngs_modulus=1e+06__dt=0.0001", "youngs_modulus=1e+06__dt=0.0004",
         "youngs_modulus=1e+07__dt=0.0001", "youngs_modulus=1e+07__dt=0.0004"]
FAILING = "youngs_modulus=1e+07__dt=0.0004"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """A local cluster of 2 process workers, 1 Dask thread and 1 Numba thread each, for the module.

    One short run here first: after a kernel change it compiles once into Numba's disk cache,
    which the workers then load, instead of every worker compiling the same code at once.
    """
    folder = tmp_path_factory.mktemp("warm-up")
    simulate(prepare(parse_scene(BAR, folder)), folder / "warm-up.h5")
    with local_client(workers=2, numba_threads=1) as dask_client:
        yield dask_client


def write_sweep(folder, sweep=SWEEP, base=BAR):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "bar.yaml").write_text(yaml.safe_dump(base))
    path = folder / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep, sort_keys=False))
    return path


def sweep_runs(tmp_path, sweep):
    """The runs of ``sweep`` (over ``BAR``, written into ``tmp_path``) and their output folder, made."""
    out = tmp_path / "out"
    out.mkdir()
    return expand_sweep(load_sweep(write_sweep(tmp_path, sweep)), out), out


def interrupt_after_the_first_run(done, failed, running, total):
    """A ``run_sweep`` progress callback: Ctrl-C once a run has finished."""
    if done >= 1:
        raise KeyboardInterrupt


def read_csv(path):
    with open(path, newline="") as stream:
        return list(csv.DictReader(stream))


def mtimes(folder):
    return {path.name: path.stat().st_mtime_ns for path in Path(folder).glob("*.h5")}


# ---------------------------------------------------------------------------------------------
# The sweep file


@pytest.mark.parametrize("sweep, message", [
    ({"base": "bar.yaml", "parameters": {"material.youngs": [1e6]}},
     "parameters.material.youngs: is not a scene key; did you mean 'material.youngs_modulus'?"),
    ({"base": "bar.yaml", "parametrs": {"material.density": [1e3]}},
     "parametrs: unknown section; did you mean 'parameters'?"),
    ({"base": "bar.yaml", "parameters": {"material.poissons_ratio": {"start": 0.2, "stop": 0.4}}},
     "parameters.material.poissons_ratio: num: required key missing"),
    ({"base": "bar.yaml", "parameters": {"material.density": {"start": 0, "stop": 10, "num": 3, "log": True}}},
     "start = 0.0: must be greater than 0 with log: true"),
    ({"base": "bar.yaml", "parameters": {"material.density": []}},
     "parameters.material.density = []: must be a non-empty list"),
    ({"base": "bar.yaml", "parameters": {"material.density": [1e3, 1e3]}}, "listed twice"),
    ({"base": "bar.yaml", "zip": {"mesh.element_size": [0.05, 0.1], "time.dt": [1e-4]}},
     "zip.time.dt: has 1 values but mesh.element_size has 2"),
    ({"base": "bar.yaml", "parameters": {"material": [{}]}, "zip": {"material.density": [1e3]}},
     "material.density: overlaps material"),
    ({"base": "bar.yaml", "parameters": {"output.path": ["a.h5"]}}, "output.path: is set by the sweep"),
    ({"base": "bar.yaml", "parameters": {"fixed.min": [[0, 0, 0]]}},
     "parameters.fixed.min: is not a scene key: fixed is a list; name an item, as fixed[0].min"),
    ({"base": "bar.yaml", "parameters": {"material[0]": [0.0]}}, "material[0]: is not a scene key: material is not a list"),
    ({"base": "bar.yaml", "parameters": {"gravity[0].x": [0.0]}}, "gravity[0] is a value, not a section"),
    ({"base": "bar.yaml", "parameters": {"gravity[0]": [0.0]}},
     "run 1 of 1 (gravity_0=0): gravity[0]: gravity has no items, so no gravity[0]; give the whole list as gravity"),
    ({"base": "bar.yaml", "parameters": {"fixed[0].velocity": [[0, 0, 1]]}, "set": {"fixed": []}},
     "fixed[0].velocity: overlaps fixed"),
    ({"base": "bar.yaml", "parameters": {"fixed[1].velocity": [[0, 0, 1]]}},
     "run 1 of 1 (velocity=0,0,1): fixed[1].velocity: fixed has 1 item, so no fixed[1]"),
    ({"base": "bar.yaml", "parameters": {"damping": [0.0, 1.0]}, "set": {"damping": 2.0}},
     "damping: is given twice (parameters, zip, set)"),
    ({"base": "bar.yaml", "parameters": {"damping": [0.0, 1.0]}, "set": {"time.durations": 2.0}},
     "set.time.durations: is not a scene key; did you mean 'time.duration'?"),
    ({"base": "bar.yaml"}, "parameters: required: at least one scene key to vary"),
    ({"base": "missing.yaml", "parameters": {"material.density": [1e3]}}, "base scene file not found"),
    # An invalid combination: named by its run and the scene key.
    ({"base": "bar.yaml", "parameters": {"material.poissons_ratio": [0.3, 0.6]}},
     "run 2 of 2 (poissons_ratio=0.6): material.poissons_ratio = 0.6: must be greater than -1 and less than 0.5"),
])
def test_bad_sweep_files_get_one_line(tmp_path, sweep, message):
    path = write_sweep(tmp_path, sweep)
    with pytest.raises(ConfigError) as error:
        expand_sweep(load_sweep(path), tmp_path / "out")
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_a_list_item_is_swept_by_its_number(tmp_path):
    """``fixed[0].velocity``: a key of one item of a list, as the error messages name it."""
    sweep = {"base": "bar.yaml", "parameters": {"fixed[0].velocity": [[0, 0, -0.01], [0, 0, -0.02]]},
             "set": {"fixed[0].axes": ["z"]}}
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, sweep)), tmp_path / "out")
    assert [run.scene.fixed[0].velocity for run in runs] == [(0.0, 0.0, -0.01), (0.0, 0.0, -0.02)]
    assert all(run.scene.fixed[0].axes == ("z",) and run.scene.fixed[0].min == (-1.0e-6, -1, -1) for run in runs)
    assert [run.parameters for run in runs] == [{"fixed[0].velocity": [0, 0, -0.01]},
                                                {"fixed[0].velocity": [0, 0, -0.02]}]
    assert labels_for(["fixed[0].min[1]", "mesh.min[1]", "fixed[0].velocity"]) == {
        "fixed[0].min[1]": "fixed_0.min_1", "mesh.min[1]": "mesh.min_1", "fixed[0].velocity": "velocity"}
    twice = {"base": "bar.yaml", "parameters": {"mesh.size[0]": [0.3]}, "set": {"mesh.size[00]": 0.6}}
    with pytest.raises(ConfigError, match=r"mesh.size\[0\]: is given twice"):
        load_sweep(write_sweep(tmp_path, twice))
    lengths = {"base": "bar.yaml", "parameters": {"mesh.size[0]": [0.3, 0.6]}}       # a vector's component
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, lengths)), tmp_path / "out")
    assert [run.scene.mesh.size for run in runs] == [(0.3, 0.1, 0.1), (0.6, 0.1, 0.1)]
    assert [run.path.name for run in runs] == ["size_0=0.3.h5", "size_0=0.6.h5"]


def test_bad_sweep_file_via_cli(tmp_path):
    path = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.modulus": [1e6, 2e6]}})
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert result.output.strip().count("\n") == 0
    assert "parameters.material.modulus: is not a scene key" in result.output
    assert not (tmp_path / "out").exists()


def test_a_scene_and_a_sweep_file_mixed_up_name_the_other_command(tmp_path):
    """``softsim sweep scene.yaml`` said ``mesh: unknown section``, ``softsim run sweep.yaml``
    ``base: unknown section``: now each names the command the file is for."""
    sweep_file = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.density": [1e3, 2e3]}})
    runner = CliRunner()
    as_scene = runner.invoke(cli, ["run", str(sweep_file), "-o", str(tmp_path / "x.h5")])
    assert as_scene.exit_code == 1
    assert as_scene.stderr.strip().splitlines() == [
        f"Error: {sweep_file}: is a sweep file (it has 'base', and no 'mesh'); run it with softsim sweep {sweep_file}"]
    scene_file = tmp_path / "bar.yaml"
    as_sweep = runner.invoke(cli, ["sweep", str(scene_file), "-o", str(tmp_path / "out")])
    assert as_sweep.exit_code == 1
    assert as_sweep.stderr.strip().splitlines() == [
        f"Error: {scene_file}: is a scene file (it has 'mesh', and no 'base'); run it with softsim run {scene_file}, "
        f"or sweep it from a sweep file whose base it is"]
    assert not (tmp_path / "out").exists() and not (tmp_path / "x.h5").exists()


def test_combinations_are_revalidated_copies(tmp_path):
    path = write_sweep(tmp_path, {"base": "bar.yaml",
                                  "parameters": {"material.youngs_modulus": {"start": 1e6, "stop": 1e8, "num": 3,
                                                                              "log": True},
                                                 "material.model": ["stvk", "neohookean"]},
                                  "zip": {"mesh.element_size": [0.05, 0.1], "time.dt": [1e-4, 2e-4]},
                                  "set": {"time.duration": 0.002, "material.density": 1200.0}})
    sweep = load_sweep(path)
    base = yaml.safe_load(yaml.safe_dump(sweep.base))
    runs = expand_sweep(sweep, tmp_path / "out")
    assert len(runs) == 3 * 2 * 2
    assert sweep.base == base                       # never mutated
    assert [run.scene.material.youngs_modulus for run in runs[::4]] == [1e6, 1e7, 1e8]
    assert {(run.scene.mesh.element_size, run.scene.time.dt) for run in runs} == {(0.05, 1e-4), (0.1, 2e-4)}
    assert {(run.scene.time.duration, run.scene.material.density) for run in runs} == {(0.002, 1200.0)}
    assert runs[3].name == "youngs_modulus=1e+06__model=neohookean__element_size=0.1__dt=0.0002"
    assert runs[3].path == (tmp_path / "out" / f"{runs[3].name}.h5").absolute()
    assert str(runs[3].path) == runs[3].scene.output.path
    meshes, keys = build_meshes(runs)
    assert len(meshes) == 2                         # one mesh per distinct mesh section


def test_run_names_are_stable_and_safe():
    assert [format_value(v) for v in (1e8, 0.3, 5e-6, 0.25, 2, True, "stvk", [0, 0, -9.81])] == \
        ["1e+08", "0.3", "5e-06", "0.25", "2", "true", "stvk", "0,0,-9.81"]
    labels = {"a.b": "b", "c": "c"}
    assert run_name({"a.b": 1e-4, "c": "x/y z"}, labels) == "b=0.0001__c=x_y_z"
    long = run_name({"a.b": "x" * 500, "c": 1}, labels)
    assert len(long) <= 200 and long == run_name({"a.b": "x" * 500, "c": 1}, labels)


def test_dry_run_lists_runs_and_names(tmp_path):
    path = write_sweep(tmp_path)
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out"), "--dry-run"])
    assert result.exit_code == 0, result.output
    for name in NAMES:
        assert f"{name}.h5  run" in result.output
    assert "4 runs, 4 to run" in result.output
    assert not (tmp_path / "out").exists()


def test_prepare_with_a_shared_mesh_matches_prepare(tmp_path):
    scene = parse_scene(dict(BAR, time={"duration": 0.006, "dt": 1.2e-3}), tmp_path)
    mine, reference = prepare(scene, build_mesh(scene.mesh)), prepare(scene)
    assert mine.plan == reference.plan and mine.substeps == reference.substeps > 1
    assert (mine.dt_estimate, mine.safe_dt, mine.wave_speed) == \
        (reference.dt_estimate, reference.safe_dt, reference.wave_speed)


def test_tip_is_the_far_end_face():
    points = np.array([[x, y, z] for x in (0.0, 0.5, 1.0) for y in (0.0, 0.1) for z in (0.0, 0.1)])
    fixed = points[:, 0] == 0.0
    assert sorted(tip_vertices(points, fixed)) == list(np.flatnonzero(points[:, 0] == 1.0))
    assert tip_vertices(points, np.zeros(len(points), bool)).size == 0


def test_the_command_line_does_not_import_dask():
    code = "import sys, softsim.cli.main; print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"


def test_without_dask_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(MissingDependencyError, match=r'pip install "\.\[sweep\]" in softsim\'s source folder'):
        import_distributed()


# ---------------------------------------------------------------------------------------------
# Sweeps on the cluster


def _numba_threads():
    import numba

    return os.environ.get("NUMBA_NUM_THREADS"), numba.config.NUMBA_NUM_THREADS, numba.get_num_threads()


def test_workers_do_not_oversubscribe_also_after_a_restart(client):
    """One Dask thread and one Numba thread per worker, before and after the nanny restarts them
    (it does when a worker stops answering); the client's process keeps its own environment."""
    before = os.environ.get("NUMBA_NUM_THREADS")
    for restart in (False, True):
        if restart:
            client.restart()
        assert set(client.nthreads().values()) == {1}
        assert set(client.run(_numba_threads).values()) == {("1", 1, 1)}
        assert os.environ.get("NUMBA_NUM_THREADS") == before


def test_sweep_reports_a_failed_run_reruns_skip_and_force(tmp_path, client):
    runs = expand_sweep(load_sweep(write_sweep(tmp_path)), tmp_path / "out")
    out = tmp_path / "out"
    out.mkdir()
    result = run_sweep(runs, out, client)
    assert [row["name"] for row in result.rows] == NAMES
    rows = {row["name"]: row for row in read_csv(out / "summary.csv")}
    assert list(rows) == NAMES
    for name, row in rows.items():
        with h5py.File(out / f"{name}.h5") as f:        # the summary says what the file says
            assert (row["status"], row["status_reason"]) == (f.attrs["status"], f.attrs["status_reason"])
        assert (out / f"{name}.xdmf").is_file()
        assert row["material.youngs_modulus"] and row["time.dt"] and float(row["wall_time_s"]) > 0
    assert rows[FAILING]["status"] == "failed" and "blew up" in rows[FAILING]["status_reason"]
    for name in set(NAMES) - {FAILING}:
        row = rows[name]
        assert row["status"] == "complete" and int(row["steps_done"]) == int(row["steps"]) > 0
        assert float(row["tip_dz"]) < 0 and abs(float(row["tip_x"]) - 0.3) < 0.01   # sags; tip at x = 0.3 m
        assert float(row["max_displacement"]) >= float(row["tip_displacement"]) > 0
        assert float(row["final_kinetic_energy"]) > 0 and float(row["tet_steps_per_s"]) > 0

    before = mtimes(out)
    again = run_sweep(runs, out, client)                 # complete runs are skipped, the failed one retried
    assert again.skipped == 3
    after = mtimes(out)
    assert {name for name in before if before[name] != after[name]} == {f"{FAILING}.h5"}
    assert [row["status"] for row in again.rows] == [row["status"] for row in result.rows]

    forced = run_sweep(runs, out, client, force=True)
    assert forced.skipped == 0
    assert all(mtimes(out)[name] != after[name] for name in after)


def test_a_complete_file_of_another_scene_is_not_replaced(tmp_path, client):
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6]}}
    out = tmp_path / "out"
    out.mkdir()
    run_sweep(expand_sweep(load_sweep(write_sweep(tmp_path, sweep)), out), out, client)
    changed = dict(BAR, material=dict(BAR["material"], density=1100.0))
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, sweep, changed)), out)
    with pytest.raises(SimulationError, match=r"material.density: 1000.0 -> 1100.0\); pass --force"):
        plan_runs(runs)
    assert len(plan_runs(runs, force=True)[0]) == 1


def test_a_complete_run_of_a_mesh_file_that_changed_is_not_taken_as_done(tmp_path, client):
    """A run of ``shape: file`` is skipped only while the file holds what the run read."""
    import meshio

    from softsim.mesh.generate import structured_box

    points, tets = structured_box((0.3, 0.1, 0.1), (0.0, -0.05, -0.05), 0.05)
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(points, [("tetra", tets)]))
    base = dict(BAR, mesh={"shape": "file", "file": "bar.vtu"})
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6]}}
    out = tmp_path / "out"
    out.mkdir()
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, sweep, base)), out)
    run_sweep(runs, out, client)
    assert plan_runs(runs) == ([], runs)
    with h5py.File(runs[0].path, "a") as f:           # as a softsim that kept no hash wrote it: rerun
        hashed = f.attrs.pop("mesh_file_sha256")
    assert plan_runs(runs) == (runs, [])
    with h5py.File(runs[0].path, "a") as f:
        f.attrs["mesh_file_sha256"] = hashed
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(2.0 * points, [("tetra", tets)]))
    with pytest.raises(SimulationError, match=r"mesh.file: the content of .*bar.vtu' changed .*; pass --force"):
        plan_runs(runs)


def test_ctrl_c_cancels_and_keeps_the_summary(tmp_path, client):
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6, 3e6, 4e6, 5e6, 6e6]}}
    runs, out = sweep_runs(tmp_path, sweep)

    with pytest.raises(KeyboardInterrupt):
        run_sweep(runs, out, client, progress=interrupt_after_the_first_run)
    statuses = [row["status"] for row in read_csv(out / "summary.csv")]
    assert statuses.count("complete") >= 1 and statuses.count("interrupted") >= 1
    assert set(statuses) <= {"complete", "interrupted"}
    rerun = run_sweep(runs, out, client)                 # the cluster is still usable; the rest finishes
    assert rerun.skipped == statuses.count("complete") and not rerun.failed


def test_a_scatter_that_hangs_is_given_up_and_the_runs_carry_the_mesh(tmp_path, client, monkeypatch, caplog):
    async def never_finishes(*args, **kwargs):
        await asyncio.sleep(3600)

    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6]}}
    runs, out = sweep_runs(tmp_path, sweep)
    monkeypatch.setattr(runner, "SCATTER_TIMEOUT_S", 0.5)
    monkeypatch.setattr(client, "scatter", lambda *args, **kwargs: never_finishes())
    with caplog.at_level("WARNING", logger="softsim"):
        result = run_sweep(runs, out, client)
    assert "took over 0.5 s; the runs carry it themselves" in caplog.text
    assert result.counts["complete"] == 2 and all((out / row["file"]).is_file() for row in result.rows)


def test_a_run_refused_before_writing_is_reported_without_a_file(tmp_path, client):
    sweep = {"base": "bar.yaml", "parameters": {"time.dt_policy": ["refuse", "substep"]},
             "set": {"time.dt": 1.0e-3}}
    runs, out = sweep_runs(tmp_path, sweep)
    result = run_sweep(runs, out, client)
    refused, split = result.rows
    assert list(refused) == list(split) == summary_columns(runs)      # known before the runs (--plot)
    assert refused["status"] == "failed" and "dt_policy: refuse" in refused["status_reason"]
    assert not (out / refused["file"]).exists()
    assert split["status"] == "complete" and (out / split["file"]).is_file()


def test_cli_on_an_existing_scheduler_with_a_shared_dir(tmp_path, client):
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6, 2.0e6]}}
    path = write_sweep(tmp_path, sweep)
    out = tmp_path / "shared"
    args = ["sweep", str(path), "--scheduler", client.scheduler.address, "--shared-dir", str(out),
            "--plot", "youngs_modulus:tip_displacement"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "2 runs, 2 complete (0 skipped, already complete), 0 failed" in result.output
    assert (out / "youngs_modulus=2e+06.h5").is_file() and (out / "summary.png").stat().st_size > 0
    result = CliRunner().invoke(cli, args[:-2])
    assert "2 runs, 2 complete (2 skipped, already complete)" in result.output


@pytest.mark.parametrize("spec", ["nope:tip_dz", "youngs_modulus:nope", "youngs_modulus:tip_dz:nope"])
@pytest.mark.parametrize("dry_run", [True, False])
def test_a_bad_plot_column_is_refused_before_any_run(tmp_path, spec, dry_run):
    path = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6, 2.0e6]}})
    args = ["sweep", str(path), "-o", str(tmp_path / "out"), "--plot", spec] + (["--dry-run"] if dry_run else [])
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2
    assert "'nope' is not a column of the summary (columns: run, name, file, material.youngs_modulus, status" in (
        result.output)
    assert not (tmp_path / "out").exists()


def test_a_plot_without_matplotlib_is_refused_before_any_run(tmp_path, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else
                        find_spec(name, *a))
    path = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6]}})
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out"), "--plot", "youngs_modulus:tip_dz"])
    assert result.exit_code == 1 and "the sweep plot needs matplotlib" in result.output
    assert not (tmp_path / "out").exists()


def test_ctrl_c_while_the_local_workers_stop_reports_the_finished_sweep(tmp_path, client, monkeypatch):
    """Ctrl-C after the last run, while the local cluster shut down (seconds), said 'sweep cancelled'
    of a sweep whose runs had all finished."""
    @contextlib.contextmanager
    def interrupted_on_exit(workers, numba_threads):
        yield client
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_sweep, "local_client", interrupted_on_exit)
    path = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1.0e6, 2.0e6]}})
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 130
    assert result.stderr.strip().splitlines()[-1] == (
        f"softsim: interrupted after the sweep's 2 runs ended (2 complete, 0 failed); "
        f"summary in {tmp_path / 'out' / 'summary.csv'}")
    assert [row["status"] for row in read_csv(tmp_path / "out" / "summary.csv")] == ["complete", "complete"]


def test_cli_local_cluster_exit_code_on_a_failed_run(tmp_path):
    sweep = {"base": "bar.yaml", "parameters": {"time.dt": [1.0e-4, 1.0e-2]},
             "zip": {"material.youngs_modulus": [1.0e7]}}
    path = write_sweep(tmp_path, sweep)
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out"), "--workers", "1"])
    assert result.exit_code == 1
    assert "2 runs, 1 complete (0 skipped, already complete), 1 failed" in result.output
    assert "run 2 (dt=0.01__youngs_modulus=1e+07) failed: the simulation blew up" in result.output


def test_summary_csv_and_parquet_only_with_pyarrow(tmp_path, monkeypatch):
    rows = [{"run": 1, "name": "E=1", "material.youngs_modulus": 1e6, "status": "complete", "tip_dz": -0.01},
            {"run": 2, "name": "E=2", "material.youngs_modulus": 2e6, "status": "failed", "tip_dz": float("nan")}]
    with monkeypatch.context() as patch:
        patch.setitem(sys.modules, "pyarrow", None)
        assert write_summary(rows, tmp_path) == [tmp_path / "summary.csv"]
    assert [row["tip_dz"] for row in read_csv(tmp_path / "summary.csv")] == ["-0.01", ""]
    parquet = pytest.importorskip("pyarrow.parquet")
    paths = write_summary(rows, tmp_path)
    table = parquet.read_table(paths[1])
    assert table.column_names == list(rows[0]) and table.num_rows == 2
    assert table.column("material.youngs_modulus").to_pylist() == [1e6, 2e6]


def test_plot_summary(tmp_path):
    summary = tmp_path / "summary.csv"
    summary.write_text("run,material.youngs_modulus,material.poissons_ratio,status,tip_displacement\n"
                       "1,1e6,0.2,complete,0.01\n2,1e7,0.2,complete,0.001\n"
                       "3,1e6,0.4,complete,0.009\n4,1e7,0.4,failed,\n")
    image = plot_summary(summary, tmp_path / "plot.png", "material.youngs_modulus", "tip_displacement",
                         "material.poissons_ratio")
    assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ConfigError, match="plot column 'tip'"):
        plot_summary(summary, tmp_path / "plot.png", "material.youngs_modulus", "tip")


def test_runs_lost_with_their_workers_are_submitted_again(tmp_path, client):
    """Every worker process killed once the first run is done (their nannies start new ones): the
    runs that were on them, and the mesh the client had scattered, are gone, and Dask cancels the
    runs that needed it; they are submitted again, carrying the mesh, and all finish."""
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6, 3e6, 4e6, 5e6, 6e6]}}
    runs, out = sweep_runs(tmp_path, sweep)
    restarted = []

    def restart_once(done, failed, running, total):
        if done >= 1 and not restarted:
            restarted.append(done)
            with contextlib.suppress(Exception):     # the workers die before they answer
                client.run(os._exit, 1)

    result = run_sweep(runs, out, client, progress=restart_once)
    assert restarted and result.counts["complete"] == 6, [row["status_reason"] for row in result.failed]
    assert all((out / row["file"]).is_file() for row in result.rows)


def test_a_run_the_scheduler_forgot_is_submitted_again(tmp_path, client):
    """The race the test above can hit: a run finished on a worker that died while the client
    fetched its result, and could not run again (its mesh died too), so the scheduler forgot it;
    asked about the key, it answers "cancelled" with no reason, which the client calls "unknown".
    Here the scheduler forgets a run not yet done and is asked about it: the run is submitted again
    and finishes."""
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6, 3e6, 4e6]}}
    runs, out = sweep_runs(tmp_path, sweep)
    forgotten = []

    def forget_a_run(dask_scheduler, client_id):
        runs_left = [key for key, task in dask_scheduler.tasks.items()
                     if str(key).startswith("softsim-run-") and task.state != "memory"]
        key = sorted(runs_left)[-1]
        dask_scheduler.client_releases_keys(keys=[key], client=client_id, stimulus_id="test-forget")
        dask_scheduler.report_on_key(key, client=client_id)
        return key

    def forget_once(done, failed, running, total):
        if done >= 1 and not forgotten:
            forgotten.append(client.run_on_scheduler(forget_a_run, client_id=client.id))

    result = run_sweep(runs, out, client, progress=forget_once)
    assert forgotten and result.counts["complete"] == 4, [row["status_reason"] for row in result.failed]


def test_a_shared_dir_this_machine_does_not_see_fails_the_runs(tmp_path, client, monkeypatch):
    """With --shared-dir, a worker that writes where this machine does not see the file (another
    folder at that path on its host) does not pass for a complete run."""
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6]}}
    out, elsewhere = tmp_path / "out", tmp_path / "the worker's folder"
    out.mkdir()
    elsewhere.mkdir()
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, sweep)), out)
    execute_run = runner.execute_run

    def writes_elsewhere(scene, mesh, name, target_dir, *rest):   # sent to the workers by value
        return execute_run(scene, mesh, name, str(elsewhere), *rest)

    monkeypatch.setattr(runner, "execute_run", writes_elsewhere)
    monkeypatch.setattr(runner, "SHARED_FILE_WAIT_S", 0.5)
    _unfinished_run_file(runs[0]).finish("failed", "an older run")   # must not pass for the new one
    result = run_sweep(runs, out, client, shared_dir=True)
    assert result.counts["failed"] == 2 and len(list(elsewhere.glob("*.h5"))) == 2
    assert all("this machine does not see it there: --shared-dir must be a folder" in row["status_reason"]
               for row in result.rows)


def test_a_cluster_without_workers_is_named_in_one_line():
    distributed = import_distributed()
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as cluster:
        address = cluster.scheduler_address
        with pytest.raises(SimulationError) as raised:
            with runner.remote_client(address, worker_wait_s=0.5):
                pass
    assert str(raised.value) == (f"--scheduler {address}: the cluster has no workers (none joined in 0.5 s); "
                                 f"start some with: dask worker {address}")


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:87x99", "tcp://127.0.0.1:1"])
def test_a_scheduler_that_is_not_there_is_one_line(tmp_path, monkeypatch, address):
    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    path = write_sweep(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6]}})
    result = CliRunner().invoke(cli, ["sweep", str(path), "-o", str(tmp_path / "out"), "--scheduler", address])
    assert result.exit_code == 1
    assert f"--scheduler {address}: cannot connect (" in result.output
    assert "is a Dask scheduler running there" in result.output and "Traceback" not in result.output
    assert "sweep: 2 runs" not in result.output


def _unfinished_run_file(run):
    """Start writing ``run``'s file as a run does: returns its ``RunWriter``, the file open (its
    ``finish`` closes it)."""
    from softsim.io.hdf5 import RunWriter

    prepared = prepare(run.scene)
    model = prepared.model
    return RunWriter(run.path, model.mesh.points, model.mesh.tets, model.fixed, "{}", prepared.plan.dt,
                     prepared.plan.total_steps, ["velocities"], frames=2)


def test_a_run_file_still_being_written_stops_the_sweep_before_any_run(tmp_path):
    """A file another run writes now (a run of an earlier sweep that a cluster's worker goes on
    with, after the sweep was interrupted) is named before anything runs, and left alone."""
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6]}}
    out = tmp_path / "out"
    runs = expand_sweep(load_sweep(write_sweep(tmp_path, sweep)), out)
    out.mkdir()
    writer = _unfinished_run_file(runs[1])
    with pytest.raises(SimulationError, match=r"run 2 \(youngs_modulus=2e\+06\): .* is open for writing by "
                                              r"another process \(a run of an earlier sweep still going on"):
        plan_runs(runs)
    writer.finish("interrupted")
    assert runs[1].path.is_file() and plan_runs(runs) == (runs, [])


def test_ctrl_c_stops_the_runs_a_cluster_is_running(tmp_path, client):
    """Ctrl-C on a sweep with --shared-dir: the runs already on the workers (which Dask cannot
    stop) end at their next frame, their files marked interrupted, instead of running on (these
    would take tens of seconds) and writing files the summary calls interrupted."""
    from softsim.io.hdf5 import being_written, run_attributes

    sweep = {"base": "bar.yaml", "parameters": {"time.duration": [0.005, 600.0, 601.0]},
             "set": {"output.frame_interval": 0.1}}
    runs, out = sweep_runs(tmp_path, sweep)

    with pytest.raises(KeyboardInterrupt):
        run_sweep(runs, out, client, shared_dir=True, progress=interrupt_after_the_first_run)
    # a started run's file appears within a second or two (a run waiting on a worker is cancelled
    # before it starts); stopped, it is not written after its next frame
    started = [run.path for run in runs[1:]]
    deadline = time.monotonic() + runner.STOP_POLL_S + 15.0
    while time.monotonic() < deadline and (not any(p.is_file() for p in started) or any(map(being_written, started))):
        time.sleep(0.2)
    statuses = [run_attributes(run.path)["status"] if run.path.is_file() else None for run in runs]
    assert statuses[0] == "complete" and "interrupted" in statuses[1:], statuses
    assert set(statuses[1:]) <= {None, "interrupted"}, statuses      # not started, or started and stopped


def test_a_run_whose_worker_dies_is_named_so(tmp_path, client, monkeypatch):
    """A run that takes its worker process down with it, every time it is tried, fails with a
    reason in the user's terms, and the other run completes (it is let finish first, so that it
    is never the one lost beside it).  Dask tries a task on a new worker until it has killed 2
    (``allowed_failures`` 1 here, 3 by default); a death that also takes the scattered mesh makes
    it cancel the run instead, which the sweep submits again: either way ends in words."""
    sweep = {"base": "bar.yaml", "parameters": {"material.youngs_modulus": [1e6, 2e6]}}
    runs, out = sweep_runs(tmp_path, sweep)
    execute_run, first_done = runner.execute_run, tmp_path / "first run done"

    def second_dies_after_the_first(scene, mesh, name, *rest):     # sent to the workers by value
        if name == runs[1].name:
            deadline = time.monotonic() + 60.0
            while not first_done.exists() and time.monotonic() < deadline:
                time.sleep(0.05)
            os._exit(1)
        return execute_run(scene, mesh, name, *rest)

    def first_done_here(done, failed, running, total):   # its result is in: no worker holds it any more
        if done == 1 and not failed:
            first_done.touch()

    monkeypatch.setattr(runner, "execute_run", second_dies_after_the_first)
    monkeypatch.setattr(client.cluster.scheduler, "allowed_failures", 1)
    result = run_sweep(runs, out, client, progress=first_done_here)
    assert [row["status"] for row in result.rows] == ["complete", "failed"], result.rows
    reason = result.rows[1]["status_reason"]
    assert (reason.startswith("the worker process running it died, on every try")
            or reason.startswith(f"lost {runner.LOST_RUN_RESUBMITS + 1} times with a worker that died")), reason


def test_a_run_asks_whether_its_sweep_was_stopped_at_most_so_often(client):
    """``stop_requested``: False until the sweep's event is set, then True; between two questions
    to the scheduler it gives the last answer.  (Here in the client's process, whose client it uses.)"""
    distributed = import_distributed()
    name = f"softsim-test-stop-{os.urandom(4).hex()}"
    every_time, throttled = runner.stop_requested(name, every_s=0.0), runner.stop_requested(name, every_s=3600.0)
    assert not every_time() and not throttled()
    distributed.Event(name, client=client).set()
    assert every_time() and not throttled()


def test_off_a_worker_a_run_is_never_asked_to_stop(monkeypatch):
    distributed = import_distributed()

    def no_client():
        raise ValueError("No clients found")

    monkeypatch.setattr(distributed, "get_client", no_client)
    assert runner.stop_requested("any")() is False


def test_runs_no_worker_is_left_to_take_fail_and_the_sweep_ends(tmp_path, monkeypatch):
    """A local cluster whose workers are gone for good (its one worker closed with its nanny once
    the first run is done): the runs left fail, in words, after ``NO_WORKERS_TIMEOUT_S``, and the
    sweep ends instead of waiting for a worker for ever."""
    monkeypatch.setattr(runner, "NO_WORKERS_TIMEOUT_S", 2.0)
    moduli = [1e6 * (k + 1) for k in range(8)]         # more than the worker can finish as it closes
    runs, out = sweep_runs(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": moduli}})
    with local_client(workers=1, numba_threads=1) as client:
        closed = []

        def close_the_worker(done, failed, running, total):
            if done >= 1 and not closed:
                closed.append(done)
                client.cluster.scale(0)

        result = run_sweep(runs, out, client, progress=close_the_worker)
    assert closed and result.counts["complete"] >= 1
    reasons = {row["status_reason"] for row in result.failed}
    assert result.counts["complete"] + len(result.failed) == len(moduli) and result.failed
    assert reasons == {"no Dask worker was left to run it for 2 s (they died and none came back)"}


def test_on_a_scheduler_of_its_own_runs_no_worker_is_left_to_take_fail_too(tmp_path, monkeypatch):
    """The same on a cluster the sweep did not make (``--scheduler``), whose scheduler keeps
    Dask's default of waiting for a worker for ever: the sweep's own watch ends it
    (``runner.runs_cancelled_without_workers``)."""
    monkeypatch.setattr(runner, "NO_WORKERS_TIMEOUT_S", 2.0)
    distributed = import_distributed()
    moduli = [1e6 * (k + 1) for k in range(8)]
    runs, out = sweep_runs(tmp_path, {"base": "bar.yaml", "parameters": {"material.youngs_modulus": moduli}})
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        with runner.remote_client(cluster.scheduler_address) as client:
            closed = []

            def close_the_worker(done, failed, running, total):
                if done >= 1 and not closed:
                    closed.append(done)
                    cluster.scale(0)

            started = time.monotonic()
            result = run_sweep(runs, out, client, progress=close_the_worker)
            waited = time.monotonic() - started
    assert closed and result.counts["complete"] >= 1 and waited < 60.0
    reasons = {row["status_reason"] for row in result.failed}
    assert result.counts["complete"] + len(result.failed) == len(moduli) and result.failed
    assert reasons == {"no Dask worker was left to run it for 2 s (they died and none came back)"}
