"""Stability on stiff and extreme cases: the dt policies, the per-frame re-check of the stable step
on the deformed mesh, the blow-up guard, and inversion recovery.

Every run here writes a file; the autouse fixture of conftest.py checks that no written file
holds a non-finite number.
"""

import dataclasses
import math

import h5py
import numpy as np
import pytest

from softsim.errors import ConfigError, SimulationError
from softsim.kernels.blocked import build_block_layout
from softsim.kernels.jit import CompileTimeConstant
from softsim.integrators.stability import exact_stable_step
from softsim.simulation import prepare, simulate

CUBE = {"shape": "box", "size": [0.1, 0.1, 0.1], "element_size": 0.025, "structured": True}
RUBBER = {"youngs_modulus": 1.0e5, "poissons_ratio": 0.3, "density": 1000.0}


def volume_ratios(f, frame=-1):
    """J of every tet in frame ``frame`` of an open output file."""
    X = f["mesh/points"][:]
    x = f["frames/points"][frame]
    t = f["mesh/tets"][:]
    return np.linalg.det(x[t][:, 1:] - x[t][:, :1]) / np.linalg.det(X[t][:, 1:] - X[t][:, :1])


def crushed_cube(scene, model, duration=0.5):
    """A 10 cm cube whose top face is pushed down to a tenth of its height over ``duration``."""
    return scene(mesh=CUBE, material={"model": model, **RUBBER}, gravity=[0, 0, 0], damping=5.0,
                 fixed=[{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]},
                        {"min": [-1, -1, 0.1 - 1e-6], "max": [1, 1, 1], "velocity": [0, 0, -0.09 / duration]}],
                 time={"duration": duration}, output={"frame_interval": duration / 20})


def test_a_layout_without_rest_data_runs_as_one_with_them(scene, tmp_path):
    """A layout that stores no rest data (``rest_from_points``: float64 ``Dm^-1`` above
    ``REST_FROM_POINTS_BYTES``, or asked for in the triangular form): the step and the guard's
    element checks compute them from the rest positions.  The crushed neo-Hookean cube (the
    triangular form), forced there, re-checks its step as often and ends where it ends with them
    stored, to round-off."""
    s = crushed_cube(scene, "neohookean", duration=0.1)
    s = s.model_copy(update={"time": s.time.model_copy(update={
        "dt": 0.9 * exact_stable_step(prepare(s).model), "dt_policy": "substep"})})
    runs = {}
    for computing in (False, True):
        prepared = prepare(s)
        if computing:
            model = prepared.model
            assert model.blocks.triangular
            prepared = dataclasses.replace(prepared, model=dataclasses.replace(model, blocks=build_block_layout(
                model.tets, model.Dm_inv, model.rest_volume, model.node_count, rest_from_points=True,
                model=model.material_id)))
        assert prepared.model.blocks.rest_from_points is computing
        assert (prepared.model.blocks.rest.shape[0] == 0) is computing
        summary = simulate(prepared, tmp_path / f"{computing}.h5")
        with h5py.File(tmp_path / f"{computing}.h5") as f:
            assert f.attrs["status"] == "complete"
            runs[computing] = summary, f["frames/points"][-1], f["frames/time"][:]
    (stored, x_stored, t_stored), (computed, x_computed, t_computed) = runs[False], runs[True]
    assert computed.frames == stored.frames and np.array_equal(t_computed, t_stored)
    np.testing.assert_allclose(x_computed, x_stored, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model, rest_step_survives", [("neohookean", False), ("corotated", True)])
def test_crushed_cube_stays_stable_because_the_step_is_rechecked(scene, tmp_path, model, rest_step_survives):
    """Squashed to 1/10 of its height.  The kernels are total-Lagrangian (rest gradients, rest
    masses), so the stable step changes only with the material's tangent stiffness: neohookean
    stiffens where the cube bulges, and a step of 0.9x the rest-state limit
    blows up under ``allow``, while ``substep`` re-checks the eigenvalue limit, splits the step and
    finishes.  Corotated's tangent stays bounded under compression: the rest step survives."""
    s = crushed_cube(scene, model)
    given = 0.9 * exact_stable_step(prepare(s).model)     # stable at rest

    def with_dt(policy):
        return s.model_copy(update={"time": s.time.model_copy(update={"dt": given, "dt_policy": policy})})

    summary = simulate(prepare(with_dt("substep")), tmp_path / "crush.h5")
    with h5py.File(tmp_path / "crush.h5") as f:
        assert f.attrs["status"] == "complete"
        top = f["mesh/points"][:, 2] > 0.1 - 1e-6
        t_end = f["frames/time"][-1]
        np.testing.assert_allclose(f["frames/points"][-1][top, 2], 0.1 - 0.18 * t_end, atol=1e-12)
        assert t_end >= 0.5
    assert summary.frames >= 21

    if rest_step_survives:
        simulate(prepare(with_dt("allow")), tmp_path / "unchecked.h5")
    else:
        with pytest.raises(SimulationError, match="blew up"):
            simulate(prepare(with_dt("allow")), tmp_path / "unchecked.h5")


def test_the_guard_looks_again_after_the_change_its_margin_allows(scene, tmp_path, monkeypatch):
    """``recheck_change``: 5 % of J or stretch where the step is at the sub-steps' limit, more where
    the last look left a margin m, keeping the step's worst case the same (a tangent stiffness
    growing as the fourth power of the stretch lets the limit fall by (1 + change)^-2 unseen), at
    most 25 %.  The crushed neo-Hookean cube at dt: auto looks less often than at a fixed 5 %, and
    ends where that run ends."""
    from softsim.integrators import guard

    assert guard.recheck_change(1.0) == pytest.approx(guard.RECHECK_CHANGE)
    for margin in (1.02, 1.1, 1.2, 1.33):
        change = guard.recheck_change(margin)
        assert guard.RECHECK_CHANGE < change < guard.RECHECK_CHANGE_MAX
        assert (1.0 + change) ** 2 / margin == pytest.approx((1.0 + guard.RECHECK_CHANGE) ** 2)
    assert guard.recheck_change(4.0) == guard.recheck_change(math.inf) == guard.RECHECK_CHANGE_MAX

    looks = []
    looked = guard.FrameGuard._substeps

    def recording(self, state, time, moved):
        substeps = looked(self, state, time, moved)
        if moved:
            looks.append((substeps, self.recheck_change))
        return substeps

    monkeypatch.setattr(guard.FrameGuard, "_substeps", recording)
    s = crushed_cube(scene, "neohookean")
    runs = {}
    for threshold in ("margin", "fixed"):
        if threshold == "fixed":
            monkeypatch.setattr(guard, "recheck_change", lambda margin: guard.RECHECK_CHANGE)
        looks.clear()
        simulate(prepare(s), tmp_path / f"{threshold}.h5")
        with h5py.File(tmp_path / f"{threshold}.h5") as f:
            assert f.attrs["status"] == "complete"
            runs[threshold] = len(looks), max(change for _, change in looks), f["frames/points"][-1]
    (margin_looks, largest, x_margin), (fixed_looks, _, x_fixed) = runs["margin"], runs["fixed"]
    assert largest > guard.RECHECK_CHANGE and margin_looks < fixed_looks
    np.testing.assert_allclose(x_margin, x_fixed, rtol=0, atol=1e-9)


def test_the_guard_takes_forward_differences_unless_an_element_is_inverted(scene, tmp_path, monkeypatch):
    """Its looks apply K by forward differences (one force evaluation an application), but where an
    element is inverted by central ones: corotated's forces jump at an exact reflection, and the
    forward form then gave the mirrored cube a limit 0.58x the central one, stopping at t = 0 a run
    that the central one lets finish."""
    from softsim.integrators import guard

    taken = []
    look = guard.exact_stable_step

    def recording(model, x=None, **kwargs):
        taken.append(kwargs["differences"])
        return look(model, x, **kwargs)

    monkeypatch.setattr(guard, "exact_stable_step", recording)
    mirrored = scene(mesh=CUBE, material={"model": "corotated", **RUBBER}, gravity=[0, 0, 0], damping=20.0,
                     initial_deformation={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]},
                     time={"duration": 0.025}, output={"frame_interval": 0.025})
    simulate(prepare(mirrored), tmp_path / "mirrored.h5")
    assert taken and taken[0] == "central"
    taken.clear()
    crushed = crushed_cube(scene, "neohookean")             # the first fifth of it: to 0.82 of its height
    crushed = crushed.model_copy(update={"time": crushed.time.model_copy(update={"duration": 0.1})})
    simulate(prepare(crushed), tmp_path / "crushed.h5")
    assert taken and set(taken) == {"forward"}


def test_crushed_stvk_cube_is_stopped_by_the_guard(scene, tmp_path):
    """St. Venant-Kirchhoff softens under compression and collapses: the guard stops the run with
    the element, time and step, keeps the frames before, and marks the file failed."""
    with pytest.raises(SimulationError) as caught:
        simulate(prepare(crushed_cube(scene, "stvk")), tmp_path / "stvk.h5")
    message = str(caught.value)
    assert "inverted" in message and "stvk" in message and "at t = " in message and "step" in message
    with h5py.File(tmp_path / "stvk.h5") as f:
        assert f.attrs["status"] == "failed" and f.attrs["status_reason"] == message
        k = f["frames/time"].shape[0]
        assert 1 < k < 21 and f["frames/points"].shape[0] == k
        assert (volume_ratios(f) > 0).all()            # the written frames are all sound


@pytest.mark.parametrize("model, mirror", [
    ("neohookean", [[1, 0, 0], [0, -0.3, 0], [0, 0, 1]]),   # mirrored and squashed
    ("corotated", [[1, 0, 0], [0, -0.3, 0], [0, 0, 1]]),
    ("corotated", [[1, 0, 0], [0, 1, 0], [0, 0, 0.01]]),    # squashed nearly flat
    ("neohookean", [[1, 0, 0], [0, 1, 0], [0, 0, 0.01]]),
])
def test_inverted_or_flattened_start_recovers(scene, tmp_path, model, mirror):
    """Turned inside out (or flattened) at t = 0, the inversion-safe models push every element
    back to positive volume and the cube returns to its rest shape (damped)."""
    s = scene(mesh=CUBE, material={"model": model, **RUBBER}, gravity=[0, 0, 0], damping=20.0,
              initial_deformation={"matrix": mirror}, time={"duration": 0.5}, output={"frame_interval": 0.05})
    simulate(prepare(s), tmp_path / "inverted.h5")
    with h5py.File(tmp_path / "inverted.h5") as f:
        assert f.attrs["status"] == "complete"
        assert (volume_ratios(f, 0) <= 0.011).all()     # it did start inverted / flat
        np.testing.assert_allclose(volume_ratios(f), 1.0, atol=0.02)


def test_an_exact_mirror_either_recovers_or_stops_cleanly(scene, tmp_path):
    """Turned exactly inside out, a neohookean cube releases 2 lambda alpha of energy per unit
    volume and its elements pass through flat at nearly the wave speed: a run either recovers or is
    stopped with the squashed element named; never garbage."""
    s = scene(mesh=CUBE, material={"model": "neohookean", **RUBBER}, gravity=[0, 0, 0], damping=20.0,
              initial_deformation={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]},
              time={"duration": 0.2}, output={"frame_interval": 0.05})
    try:
        simulate(prepare(s), tmp_path / "mirror.h5")
    except SimulationError as exc:
        assert "safe step (0.8 x the stability limit) fell" in str(exc) or "blew up" in str(exc)
        with h5py.File(tmp_path / "mirror.h5") as f:
            assert f.attrs["status"] == "failed" and f.attrs["status_reason"] == str(exc)
    else:
        with h5py.File(tmp_path / "mirror.h5") as f:
            assert f.attrs["status"] == "complete" and (volume_ratios(f) > 0).all()


def test_a_too_large_dt_under_allow_is_caught_by_the_guard(scene, tmp_path):
    """Three times the estimated limit, used as given: the guard stops the run at the first frame
    where the energy is far above what was put in (or a value is non-finite), with a readable file."""
    base = scene(mesh=CUBE, material={"model": "neohookean", **RUBBER},
                 fixed=[{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]}],
                 time={"duration": 0.5}, output={"frame_interval": 0.01})
    too_large = 3.0 * prepare(base).dt_estimate
    s = base.model_copy(update={"time": base.time.model_copy(update={"dt": too_large, "dt_policy": "allow"})})
    with pytest.raises(SimulationError, match=r"blew up at t = .* s \(step \d+\).*vertex \d+"):
        simulate(prepare(s), tmp_path / "allow.h5")
    with h5py.File(tmp_path / "allow.h5") as f:
        assert f.attrs["status"] == "failed" and "blew up" in f.attrs["status_reason"]
        assert f["frames/time"].shape[0] >= 1


def test_refuse_refuses_before_any_output_and_substep_agrees_with_auto(scene, tmp_path):
    """refuse: a ConfigError naming the given and the stable step, before any file exists.
    substep: the given step split into equal stable sub-steps gives the auto run's answer."""
    base = scene(mesh=CUBE, material={"model": "neohookean", **RUBBER},
                 fixed=[{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]}],
                 time={"duration": 0.1}, output={"frame_interval": 0.01})
    auto = prepare(base)
    given = 0.01                       # one step per frame: far above the stable step
    with pytest.raises(ConfigError, match=r"time.dt = 0.01: above the safe step"):
        prepare(base.model_copy(update={"time": base.time.model_copy(update={"dt": given, "dt_policy": "refuse"})}))
    assert not any(tmp_path.glob("*.h5"))

    sub = prepare(base.model_copy(update={"time": base.time.model_copy(update={"dt": given})}))
    assert sub.substeps == round(given / sub.plan.dt) > 1 and sub.plan.dt <= auto.safe_dt
    simulate(auto, tmp_path / "auto.h5")
    simulate(sub, tmp_path / "sub.h5")
    with h5py.File(tmp_path / "auto.h5") as a, h5py.File(tmp_path / "sub.h5") as b:
        np.testing.assert_allclose(a["frames/time"][:], b["frames/time"][:], rtol=1e-12)
        sag = np.abs(a["frames/points"][-1] - a["mesh/points"][:]).max()
        assert sag > 1e-4                               # it moved
        # both are O(dt) approximations of the same motion with nearby steps
        np.testing.assert_allclose(b["frames/points"][-1], a["frames/points"][-1], atol=0.02 * sag)


@pytest.mark.parametrize("material", ["stvk", "linear"])     # rest data in the triangular form, and the full one
def test_element_checks_tell_whether_any_tet_moved_as_the_largest_change_does_and_nan_moved(scene, material):
    """The guard's test of whether the elements moved enough since it last computed the stable step
    to compute it again, in the same compiled pass that measures J and the stretch (blocked and tet
    by tet), against the largest change in NumPy; a NaN counts as moved."""
    from softsim.kernels.element_checks import block_volume_ratios_and_stretches, element_volume_ratios_and_stretches

    model = prepare(scene(mesh={**CUBE, "element_size": 0.03}, material={"model": material, **RUBBER})).model
    assert model.tet_count % 64 != 0            # a last block part-filled
    assert model.blocks.triangular == (material != "linear")
    m, rng, limit = model.tet_count, np.random.default_rng(3), 0.05
    x_rest = model.rest_points.copy()
    J_rest, stretch_rest, J, stretch = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    element_volume_ratios_and_stretches(x_rest, model.tets, model.Dm_inv, J_rest, stretch_rest, np.ones(m),
                                        np.ones(m), limit)

    # the layout of a mesh above REST_FROM_POINTS_BYTES: no rest data stored, the pass computes them
    computing = build_block_layout(model.tets, model.Dm_inv, model.rest_volume, model.node_count,
                                   rest_from_points=True, model=model.material_id)
    assert computing.rest.shape[0] == 0

    def both_say(x, J_seen, stretch_seen):
        computed = block_volume_ratios_and_stretches(x, computing.tets, computing.rest,
                                                     CompileTimeConstant(computing.triangular), m, computing.whole_rows,
                                                     J, stretch, J_seen, stretch_seen, limit, model.rest_points)
        J_computed, stretch_computed = J.copy(), stretch.copy()
        blocked = block_volume_ratios_and_stretches(x, model.blocks.tets, model.blocks.rest,
                                                    CompileTimeConstant(model.blocks.triangular), m,
                                                    model.blocks.whole_rows, J, stretch, J_seen, stretch_seen, limit)
        J_blocked, stretch_blocked = J.copy(), stretch.copy()
        np.testing.assert_allclose(J_computed, J_blocked, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(stretch_computed, stretch_blocked, rtol=1e-12)
        assert computed == blocked
        per_tet = element_volume_ratios_and_stretches(x, model.tets, model.Dm_inv, J, stretch, J_seen, stretch_seen,
                                                      limit)
        np.testing.assert_allclose(J_blocked, J, rtol=1e-12)
        np.testing.assert_allclose(stretch_blocked, stretch, rtol=1e-12)
        assert blocked == per_tet
        return blocked

    size = np.ptp(x_rest, axis=0).max()
    for scale in (0.0, 1e-4, 1e-3, 1e-2, 3e-2, 1e-1):
        x = x_rest + scale * size * rng.normal(size=x_rest.shape)
        J_seen = J_rest * (1.0 + 0.01 * rng.normal(size=m))
        stretch_seen = stretch_rest * (1.0 + 0.01 * rng.normal(size=m))
        said = both_say(x, J_seen, stretch_seen)
        change = max(np.abs(J - J_seen).max(), np.abs(stretch / stretch_seen - 1.0).max())
        assert said == (change > limit), (scale, change)
    x = x_rest.copy()
    assert not both_say(x, J_rest, stretch_rest)
    for factor in (0.9, 1.1):          # one tet's J, or its stretch, just inside or past the limit
        e = rng.integers(m)
        J_seen = J_rest.copy()
        J_seen[e] -= factor * limit
        assert both_say(x, J_seen, stretch_rest) == (factor > 1.0)
        stretch_seen = stretch_rest.copy()
        stretch_seen[e] /= 1.0 + factor * limit
        assert both_say(x, J_rest, stretch_seen) == (factor > 1.0)
    x[model.tets[m // 2, 0], 1] = np.nan
    assert both_say(x, J_rest, stretch_rest)


def test_all_finite_finds_one_nan_or_infinite_value_in_positions_or_velocities():
    from softsim.kernels.element_checks import all_finite
    rng = np.random.default_rng(5)
    for n in (1, 7, 1000):
        x, v = rng.normal(size=(n, 3)) * 1e300, rng.normal(size=(n, 3))
        assert all_finite(x, v)
        for bad in (np.nan, np.inf, -np.inf):
            for array in (x, v):
                kept = array[n - 1, 2]
                array[n - 1, 2] = bad
                assert not all_finite(x, v)
                array[n - 1, 2] = kept
    assert all_finite(np.empty((0, 3)), np.empty((0, 3)))


