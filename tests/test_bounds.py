"""Bounds: a run that would take hours, outgrow the disk or not fit in memory is stopped before it
starts, with the estimate in one line (``--yes`` starts a long one anyway)."""

import shutil
from collections import namedtuple

import pytest
from click.testing import CliRunner

from softsim import simulation
from softsim.cli.main import cli
from softsim.errors import MeshError, SimulationError
from softsim.mesh import build_mesh
from softsim.simulation import check_run_cost, estimate_run, prepare

# 25,000 steel tets for 10,000 s at a microsecond step: 4e14 tet-steps, days of work on any
# machine (4.5 days even at 1e9 tet-steps/s; at 1000 s, 46 h on a Xeon, which the test's "days"
# no longer matched once the step reached 235 M tet-steps/s).
LONG = ["mesh.element_size=0.01", "material.youngs_modulus=2e11", "material.density=7850",
        "time.duration=10000", "output.frame_interval=10", "output.fields=[]", "damping=0"]


def write_scene(tmp_path, scene):
    path = tmp_path / "scene.yaml"
    path.write_text("""\
mesh: {shape: box, size: [0.5, 0.1, 0.1], element_size: 0.05, structured: true}
material: {model: stvk, youngs_modulus: 1.0e6, poissons_ratio: 0.3, density: 1000.0}
fixed: [{min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}]
time: {duration: 0.01}
output: {frame_interval: 0.005, fields: [velocities]}
""")
    return path


def test_a_run_of_days_is_refused_with_its_measured_estimate(tmp_path):
    path = write_scene(tmp_path, None)
    args = ["run", str(path), "-o", str(tmp_path / "long.h5")]
    for override in LONG:
        args += ["--set", override]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1
    message = result.output.strip().splitlines()[-1]
    assert "25,000 tets x" in message and "days at this machine's measured" in message, message
    assert message.endswith("continue with --yes")
    assert not (tmp_path / "long.h5").exists()


def test_the_estimate_measures_speed_only_for_long_runs(scene, tmp_path, monkeypatch):
    short = estimate_run(prepare(scene()), tmp_path / "out.h5")
    assert short.tet_steps / simulation.SLOWEST_TET_STEPS_PER_S < simulation.LONG_RUN_S
    assert short.seconds is None and short.tet_steps_per_s is None and short.problems() == []
    steel = dict(mesh={"shape": "box", "size": [0.5, 0.1, 0.1], "element_size": 0.01, "structured": True},
                 material={"model": "stvk", "youngs_modulus": 2e11, "poissons_ratio": 0.3, "density": 7850})
    # 1.25e11 tet-steps: 2 min even at 1e9 tet-steps/s, so a speed above any softsim reaches would
    # not have it measured, but 17 h at the slowest: it is measured (minutes at softsim's speed)
    minutes = estimate_run(prepare(scene(**steel, time={"duration": 5.0}, output={"frame_interval": 1.0})),
                           tmp_path / "out.h5")
    assert minutes.tet_steps / 1e9 < 600 < minutes.tet_steps / simulation.SLOWEST_TET_STEPS_PER_S
    assert minutes.seconds == pytest.approx(minutes.tet_steps / minutes.tet_steps_per_s)
    long = prepare(scene(**steel, time={"duration": 1000.0}, output={"frame_interval": 1.0}))
    estimate = estimate_run(long, tmp_path / "out.h5")
    assert 1e5 < estimate.tet_steps_per_s < 1e10
    assert estimate.seconds == pytest.approx(estimate.tet_steps / estimate.tet_steps_per_s)
    assert estimate.seconds > simulation.LONG_RUN_S
    with pytest.raises(SimulationError, match="continue with --yes"):
        check_run_cost(long, tmp_path / "out.h5")
    assert len(check_run_cost(long, tmp_path / "out.h5", confirmed=True)) == 1


def test_a_run_is_long_when_it_could_take_over_an_hour_at_half_the_measured_speed():
    """The burst steps bare; a run also writes and checks frames on a machine that drifts: the
    cantilever for 2000 s, estimated at 43 min, stepped as for 68.  Estimated at 36 min, a run asks."""
    def estimate(seconds):
        return simulation.RunEstimate(tets=1000, steps=10**6, tet_steps=1e9, tet_steps_per_s=1e9 / seconds,
                                      seconds=seconds, output_bytes=0, free_bytes=1)

    assert simulation.SPEED_MARGIN == 2.0
    assert estimate(0.49 * simulation.LONG_RUN_S).problems() == []
    (problem,) = estimate(0.6 * simulation.LONG_RUN_S).problems()
    assert "take about 36 min at this machine's measured 0.463 M tet-steps/s, up to 1.2 h" in problem, problem


def test_output_larger_than_the_free_disk_is_refused(scene, tmp_path, monkeypatch):
    prepared = prepare(scene(output={"frame_interval": 0.001, "fields": ["velocities", "stress"]}))
    estimate = estimate_run(prepared, tmp_path / "out.h5")
    model = prepared.model
    per_frame = 8 * (3 * model.node_count + 1) + 8 * 3 * model.node_count + 8 * 9 * model.tet_count
    assert estimate.output_bytes == len(prepared.plan.frame_steps) * per_frame
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(1, 1, estimate.output_bytes // 2))
    with pytest.raises(SimulationError, match=r"output needs about .* GB but only .* GB are free"):
        check_run_cost(prepared, tmp_path / "out.h5")


def test_a_mesh_that_would_not_fit_in_memory_is_refused_before_meshing(scene, monkeypatch):
    import softsim.mesh as mesh_module

    monkeypatch.setattr(mesh_module, "available_memory_bytes", lambda: 100e6)
    spec = scene(mesh={"shape": "box", "size": [1.0, 1.0, 1.0], "element_size": 0.02}).mesh
    with pytest.raises(MeshError, match=r"mesh.element_size = 0.02: about .* tetrahedra need ~.* GB .* only 0.1 GB"):
        build_mesh(spec)
