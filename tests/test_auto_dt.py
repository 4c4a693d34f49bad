"""``dt: auto`` lies in the band the stability issue asks for: the largest stable step is at or
above the auto step and at most twice it, for every material model and mesh kind.

The band is checked by running the time loop, not from theory: on each small free body of the
stability report (``softsim.reports.limits``: a 10 cm cube, structured, gmsh or with slivers,
nu = 0.499, where the nodal bound was loosest) symplectic Euler must stay bounded at the auto step
and blow up at twice it.  Each case is two runs of a few hundred tets, well under a second.
"""

import math

import pytest

from softsim.integrators.stability import exact_stable_step
from softsim.integrators.timestep import AUTO_EIGEN_MIN_STEPS, AUTO_EIGEN_SAFETY, AUTO_SAFETY
from softsim.reports.catalogue import MODELS, catalogue
from softsim.reports.limits import LimitCase, limit_meshes, limit_scene, perturbation_velocities, stays_bounded
from softsim.simulation import auto_step, prepare

KINDS = ("structured", "gmsh", "slivers")


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    return limit_meshes(tmp_path_factory.mktemp("limit-meshes"), KINDS)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("model", MODELS)
def test_auto_is_stable_and_twice_auto_is_not(meshes, model, kind):
    case = LimitCase(model, 1e5, 0.499, kind)
    prepared = prepare(limit_scene(case, meshes[kind]))
    auto = prepared.safe_dt
    v0 = perturbation_velocities(prepared.model, prepared.wave_speed)
    stable, steps = stays_bounded(prepared, auto, v0, steps=2000)
    assert stable, f"{case.label}: unstable at the auto step {auto:.3g} s (after {steps} steps)"
    stable, steps = stays_bounded(prepared, 2.0 * auto, v0, steps=2000)
    assert not stable, f"{case.label}: still stable at twice the auto step: auto is wasteful"
    assert steps < 500                                    # it blows up early, not marginally


@pytest.mark.parametrize("kind", KINDS)
def test_auto_is_between_0_6_and_0_8_of_the_eigenvalue_limit(meshes, kind):
    """Long runs use the eigenvalue limit; auto is never below the old nodal-bound step."""
    prepared = prepare(limit_scene(LimitCase("neohookean", 1e5, 0.3, kind), meshes[kind]))
    exact = exact_stable_step(prepared.model, tol=1e-8)
    assert prepared.scene.time.duration / (AUTO_SAFETY * prepared.dt_estimate) >= AUTO_EIGEN_MIN_STEPS
    assert AUTO_EIGEN_SAFETY * exact * (1 - 1e-3) <= prepared.safe_dt <= AUTO_SAFETY * exact
    assert prepared.safe_dt >= AUTO_SAFETY * prepared.dt_estimate
    if kind != "structured":                               # the nodal bound is loose there: Lanczos wins
        assert prepared.safe_dt == pytest.approx(AUTO_EIGEN_SAFETY * exact, rel=1e-3)
        assert prepared.safe_dt > 1.1 * AUTO_SAFETY * prepared.dt_estimate


def test_a_short_run_keeps_the_nodal_step_without_lanczos(meshes, monkeypatch):
    """Below AUTO_EIGEN_MIN_STEPS steps the eigenvalue estimate is not worth its cost."""
    import softsim.simulation as simulation

    prepared = prepare(limit_scene(LimitCase("linear", 1e5, 0.3, "gmsh"), meshes["gmsh"]))
    nodal = AUTO_SAFETY * prepared.dt_estimate
    calls = []
    monkeypatch.setattr(simulation, "exact_stable_step", lambda *a, **k: calls.append(1) or math.inf)
    assert auto_step(prepared.model, 0.5 * AUTO_EIGEN_MIN_STEPS * nodal, prepared.dt_estimate) == nodal
    assert calls == []
    assert auto_step(prepared.model, 2.0 * AUTO_EIGEN_MIN_STEPS * nodal, prepared.dt_estimate) == math.inf
    assert calls == [1]


def test_every_catalogue_scene_has_its_limit_within_1_to_2_auto(tmp_path):
    """At rest every model's tangent is Hooke's law: the limit 2 / omega_max (which the report's
    bisection measures, tests/test_stability_report.py) against the auto step of each scene (the
    large-dt scenes with dt: auto instead of their given step).  neohookean: the schema refuses the
    inverted starts for linear and stvk."""
    from softsim.config import parse_scene

    for entry in catalogue(tmp_path, quick=False):
        data = entry.scene_data("neohookean")
        data["time"] = {key: value for key, value in data["time"].items() if key not in ("dt", "dt_policy")}
        prepared = prepare(parse_scene(data))
        ratio = exact_stable_step(prepared.model, tol=1e-8) / prepared.safe_dt
        assert 1.2 <= ratio <= 1.75, f"{entry.name}: limit / auto = {ratio:.3f}"
