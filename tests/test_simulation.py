"""The time loop against physics with known answers: conservation laws, free fall, a bar in
tension, the time plan, ground contact and friction, damping, prescribed motion, determinism.

Every expected value is computed here from the scene's inputs (E, nu, rho, g, dt, ...), never
copied from a run.  Meshes are tiny structured boxes so the whole file runs in seconds once the
step loop is compiled (Numba caches it on disk).
"""

import math
import platform

import h5py
import numba
import numpy as np
import pytest

from softsim.errors import ConfigError, SimulationError
from softsim.integrators.stability import exact_stable_step
from softsim.integrators.symplectic_euler import work_buffer
from softsim.integrators.timestep import AUTO_SAFETY
from softsim.model import initial_state
from softsim.simulation import prepare, simulate, step

EPS = np.finfo(np.float64).eps
MODELS = ("linear", "stvk", "corotated", "neohookean")
ROTATION_INVARIANT = ("stvk", "corotated", "neohookean")
# Half-width [m] of the selection boxes around a face of the mesh.
TOL_BOX = 1e-6


def start(scene):
    """``(prepared, state, corner_forces)`` for a scene, at t = 0."""
    prepared = prepare(scene)
    model = prepared.model
    return prepared, initial_state(scene, model), np.empty((model.tet_count, 4, 3))


def run_steps(prepared, state, corner_forces, steps, chunk=None):
    """Advance ``state`` by ``steps`` steps of the plan's dt through ``simulation.step``, in calls
    of ``chunk`` steps (default: one call); returns a copy of the positions after each call."""
    snapshots = []
    chunk = chunk or steps
    done = 0
    while done < steps:
        count = min(chunk, steps - done)
        step(prepared.model, state, prepared.plan.dt, count, prepared.scene.damping, corner_forces)
        done += count
        snapshots.append(state.x.copy())
    return snapshots


def momenta(model, state):
    """Linear momentum sum m v [kg m/s] and angular momentum sum m x cross v about the origin."""
    m = model.mass[:, None]
    return (m * state.v).sum(axis=0), (m * np.cross(state.x, state.v)).sum(axis=0)


# ---------------------------------------------------------------------------------------------
# 1. Conservation of momentum


@pytest.mark.parametrize("model_name", MODELS)
def test_momentum_is_conserved_without_external_forces(scene, model_name):
    """Nothing held, no gravity, a sheared/stretched start that spins and drifts.

    Symplectic Euler here is ``v' = v + dt f(x)/m``, ``x' = x + dt v'``.
    - Linear momentum: sum m v' = sum m v + dt sum f, and the elastic forces of every tet sum to
      zero (f0 = -(f1 + f2 + f3)), so P is conserved exactly, up to round-off, for every model.
    - Angular momentum: L' = sum m x' x v' = sum m x x v' (v' x v' = 0) = L + dt sum x x f(x).
      The torque sum x x f vanishes for any rotation-invariant energy (F P^T symmetric), so L is
      also conserved *exactly* (not just to O(dt)) for stvk, corotated and neohookean.  The linear
      model's small-strain energy is not rotation invariant: its L drifts, which shows the check
      has teeth.
    Tolerances: a 1e-12 fraction of the natural scales sum m |v| and sum m |x| |v| (round-off is
    ~1e-16 per operation over a few hundred steps).
    """
    s = scene(
        material={"model": model_name},
        gravity=[0.0, 0.0, 0.0],
        initial_deformation={"matrix": [[1.05, 0.03, 0.0], [0.0, 0.97, 0.02], [0.01, 0.0, 1.03]],
                             "translation": [0.1, -0.2, 0.3]},
        initial_velocity=[0.3, -0.1, 0.2],
        angular_velocity=[1.0, -2.0, 3.0],
        time={"duration": 0.5},
    )
    prepared, state, corner = start(s)
    model = prepared.model
    assert not model.held.any()
    P0, L0 = momenta(model, state)
    # The spin is about the centre of mass: it adds no linear momentum.
    np.testing.assert_allclose(P0, model.mass.sum() * np.array([0.3, -0.1, 0.2]), rtol=1e-13)
    v0 = state.v.copy()
    run_steps(prepared, state, corner, prepared.plan.total_steps)
    P1, L1 = momenta(model, state)

    # The elastic forces really acted: velocities changed by more than their initial size / 10.
    assert np.abs(state.v - v0).max() > 0.1 * np.abs(v0).max()

    m = model.mass
    p_scale = (m * np.linalg.norm(state.v, axis=1)).sum()
    l_scale = (m * np.linalg.norm(state.x, axis=1) * np.linalg.norm(state.v, axis=1)).sum()
    np.testing.assert_allclose(P1, P0, rtol=0, atol=1e-12 * p_scale)
    if model_name in ROTATION_INVARIANT:
        np.testing.assert_allclose(L1, L0, rtol=0, atol=1e-12 * l_scale)
    else:
        assert np.abs(L1 - L0).max() > 1e-3 * l_scale   # spurious rotational stress: torques


# ---------------------------------------------------------------------------------------------
# 2. Free fall


@pytest.mark.parametrize("model_name", MODELS)
def test_free_fall_matches_discrete_symplectic_euler(scene, model_name):
    """v_n = n dt g, x_n = x_0 + g dt^2 n (n + 1) / 2 for every vertex, to round-off.

    A rigid translation has F = I (up to round-off of Ds Dm^-1), so the elastic forces vanish.
    The tolerance allows some tens of ulps of the coordinates: the round-off stress of F = I +- eps
    gives accelerations ~ eps |x| / dt^2 that a stable step keeps bounded.  Any other integrator
    (e.g. x_n = x_0 + g (n dt)^2 / 2) would be off by g dt^2 n / 2, some 1e9 times more.
    """
    g = np.array([0.3, -0.2, -9.81])
    s = scene(material={"model": model_name, "youngs_modulus": 1.0e6}, gravity=g.tolist(),
              mesh={"origin": [1.0, 2.0, 3.0]})
    prepared, state, corner = start(s)
    dt = prepared.plan.dt
    x0 = state.x.copy()
    assert not state.v.any()
    n = 0
    for chunk in (1, 9, 40, 150):
        run_steps(prepared, state, corner, chunk)
        n += chunk
        expected = x0 + g * dt * dt * n * (n + 1) / 2
        np.testing.assert_allclose(state.x, expected, rtol=0, atol=50 * EPS * np.abs(expected).max())
        np.testing.assert_allclose(state.v, np.broadcast_to(n * dt * g, state.v.shape),
                                   rtol=0, atol=1e-10 * n * dt * np.linalg.norm(g))


def test_the_float32_step_flushes_subnormal_numbers_and_leaves_the_caller_s_unflushed(scene):
    """A gravity below float32's smallest normal number is read as zero inside the step
    (``kernels.simd.flush_subnormals``: x86's FTZ and DAZ), so a body at rest stays at rest to the
    bit (in float32 its forces are exactly zero: the laws take ``H = 0``), where plain arithmetic
    would give it a subnormal velocity; after the step the calling thread computes subnormals
    again.  (In float64 a body at rest feels round-off forces of ``Ds Dm^-1``, which hide a
    subnormal gravity: ``tests/test_simd.py`` checks the flush there.)"""
    dtype, tiny = np.float32, 1e-39
    s = scene(gravity=[0.0, 0.0, -tiny], precision="float32")
    prepared, state, _ = start(s)
    x0 = state.x.copy()
    unflushed = dtype(prepared.plan.dt) * dtype(-tiny)
    assert unflushed != 0.0 and abs(unflushed) < np.finfo(dtype).tiny       # what no flush would add
    run_steps(prepared, state, work_buffer(prepared.model), 3)
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert not state.v.any()
        np.testing.assert_array_equal(state.x, x0)
    assert dtype(tiny) * dtype(1.0) != 0.0


# ---------------------------------------------------------------------------------------------
# 3. A bar under end traction on roller supports


def stvk_uniaxial_stretches(sigma, E, nu):
    """Exact axial and lateral stretches of St. Venant-Kirchhoff under nominal axial stress sigma.

    With F = diag(a, b, b), Green strain e1 = (a^2 - 1)/2, and S22 = 0 one finds e2 = -nu e1 and
    S11 = E e1, so P11 = a S11 = E a (a^2 - 1) / 2 = sigma: a cubic in a, solved by Newton from 1.
    """
    a = 1.0
    for _ in range(50):
        residual = 0.5 * E * a * (a * a - 1.0) - sigma
        a -= residual / (0.5 * E * (3.0 * a * a - 1.0))
    e1 = 0.5 * (a * a - 1.0)
    return a, math.sqrt(1.0 - 2.0 * nu * e1)


@pytest.mark.parametrize("model_name", MODELS)
def test_bar_under_end_traction_stretches_by_sigma_L_over_E(scene, model_name):
    """Bar 1.0 x 0.2 x 0.2 m, rollers on x=0 (x held), y=0 (y held), z=0 (z held), nominal traction
    sigma on x=L, damped to rest.

    The homogeneous uniaxial state is the exact discrete equilibrium of linear tets (constant P,
    consistent face loads area/3 per vertex, rollers free to slide), so every vertex must sit at
    (a X, b Y, b Z).  Small-strain theory: a - 1 = sigma/E, b - 1 = -nu sigma/E, with an O(sigma/E)
    relative error for the nonlinear models (sigma/E = 1e-3 here: allow 3e-3).  linear and
    corotated (diagonal F: R = I, P linear in F) must match it to the convergence of the damping;
    stvk must match its own exact uniaxial solution to that accuracy too.

    Damping 2 omega_1, critical for the slowest mode (axial, fixed-free: omega_1 = pi c / 2L), and a
    run of 20 / omega_1 leaves a transient of ~ 20 e^-20 ~ 1e-7 of the displacement.
    """
    L, W = 1.0, 0.2
    E, nu, rho = 1.0e6, 0.3, 1000.0
    sigma = 1.0e-3 * E
    omega_1 = 0.5 * math.pi * math.sqrt(E / rho) / L
    damping = 2.0 * omega_1
    duration = 20.0 / omega_1
    s = scene(
        mesh={"size": [L, W, W], "element_size": 0.1},
        material={"model": model_name, "youngs_modulus": E, "poissons_ratio": nu, "density": rho},
        gravity=[0.0, 0.0, 0.0],
        damping=damping,
        fixed=[{"min": [-TOL_BOX, -1, -1], "max": [TOL_BOX, 1, 1], "axes": ["x"]},
               {"min": [-1, -TOL_BOX, -1], "max": [2, TOL_BOX, 1], "axes": ["y"]},
               {"min": [-1, -1, -TOL_BOX], "max": [2, 1, TOL_BOX], "axes": ["z"]}],
        tractions=[{"min": [L - TOL_BOX, -1, -1], "max": [L + TOL_BOX, 1, 1], "traction": [sigma, 0, 0]}],
        time={"duration": duration},
        output={"frame_interval": duration},
    )
    prepared, state, corner = start(s)
    model = prepared.model
    X = model.rest_points
    run_steps(prepared, state, corner, prepared.plan.total_steps)

    strain = sigma / E
    # At rest: velocities a tiny fraction of the transient's scale strain L omega_1.
    assert np.abs(state.v).max() < 1e-5 * strain * L * omega_1

    # Measured stretches: mean end-face displacements.
    a = 1.0 + (state.x[:, 0] - X[:, 0])[X[:, 0] > L - TOL_BOX].mean() / L
    b = 1.0 + (state.x[:, 1] - X[:, 1])[X[:, 1] > W - TOL_BOX].mean() / W
    # Small-strain theory, within its O(sigma/E) error.
    assert abs((a - 1.0) / strain - 1.0) < 3.0 * strain
    assert abs((b - 1.0) / (-nu * strain) - 1.0) < 3.0 * strain

    if model_name in ("linear", "corotated"):
        a_exact, b_exact = 1.0 + strain, 1.0 - nu * strain
    elif model_name == "stvk":
        a_exact, b_exact = stvk_uniaxial_stretches(sigma, E, nu)
    else:
        a_exact, b_exact = a, b
    assert abs((a - a_exact) / strain) < 1e-5
    assert abs((b - b_exact) / (nu * strain)) < 1e-5
    # Every vertex on the homogeneous field (the patch test): x = (a X, b Y, b Z).
    expected = X * np.array([a_exact, b_exact, b_exact])
    np.testing.assert_allclose(state.x, expected, rtol=0, atol=1e-5 * strain * L)


# ---------------------------------------------------------------------------------------------
# 4. The frame plan


def test_auto_dt_fits_whole_steps_per_frame_and_respects_the_stable_step(scene):
    E, nu, rho, a = 1.0e5, 0.3, 1000.0, 0.1
    s = scene(material={"youngs_modulus": E, "poissons_ratio": nu, "density": rho},
              time={"duration": 0.1, "dt": "auto"}, output={"frame_interval": 0.0123})
    prepared = prepare(s)
    plan = prepared.plan
    # The stable-step bound lies below the true limit 2 / omega_max (from the dense eigenvalues of
    # M^-1 K, tests/test_stability_limit.py checks exact_stable_step against them), within 2x.
    exact = exact_stable_step(prepared.model, tol=1e-8)
    assert 0.5 * exact <= prepared.dt_estimate <= exact
    steps_per_frame = round(0.0123 / plan.dt)
    assert steps_per_frame * plan.dt == pytest.approx(0.0123, rel=1e-13)
    assert plan.dt <= AUTO_SAFETY * prepared.dt_estimate
    # ... and it is the largest such step: one step fewer per frame would exceed the limit.
    assert 0.0123 / (steps_per_frame - 1) > AUTO_SAFETY * prepared.dt_estimate
    assert all(b - a == steps_per_frame for a, b in zip(plan.frame_steps[:-2], plan.frame_steps[1:-1]))


def test_a_split_dt_that_does_not_fit_the_frames_is_named_with_its_sub_steps(scene, caplog):
    s = scene(time={"duration": 0.05, "dt": 0.0123}, output={"frame_interval": 0.01})     # split (substep)
    with caplog.at_level("WARNING", logger="softsim"):
        prepared = prepare(s)
    assert prepared.substeps > 1
    assert (f"time.dt = 0.0123 s, split into {prepared.substeps} sub-steps of {prepared.plan.dt:.4g} s, does not "
            f"fit output.frame_interval = 0.01 s") in caplog.text


@pytest.mark.parametrize("dt, frame_interval, duration", [
    ("auto", 0.02, 0.105),   # duration not a whole number of frames: a last, shorter frame
    ("auto", 0.025, 0.1),
    (0.003, 0.01, 0.05),     # given dt: frames every round(0.01 / 0.003) = 3 steps = 0.009 s
])
def test_output_frames_hold_true_times_and_end_at_the_end(scene, tmp_path, caplog, dt, frame_interval, duration):
    # dt_policy allow: the given dt is used as given (this one is within the true limit).
    s = scene(time={"duration": duration, "dt": dt, "dt_policy": "allow"}, output={"frame_interval": frame_interval})
    with caplog.at_level("WARNING", logger="softsim"):
        prepared = prepare(s)
    moved = "time.dt = 0.003 s does not fit output.frame_interval = 0.01 s a whole number of times: frames come " \
            "every 3 steps, 0.009 s"
    assert (moved in caplog.text) == (dt == 0.003), caplog.text
    plan = prepared.plan
    out = tmp_path / "run.h5"
    summary = simulate(prepared, out)

    with h5py.File(out, "r") as f:
        times = f["frames/time"][:]
        points = f["frames/points"][:]
        assert f.attrs["status"] == "complete"
        assert f.attrs["dt"] == plan.dt
    if dt != "auto":
        assert plan.dt == dt
    steps_per_frame = round(frame_interval / plan.dt) if dt != "auto" else frame_interval / plan.dt
    assert steps_per_frame == pytest.approx(round(steps_per_frame), abs=1e-9)
    steps_per_frame = round(steps_per_frame)
    # True times: a whole number of steps times dt; frame 0 at t = 0; evenly spaced by the plan.
    assert times[0] == 0.0
    np.testing.assert_allclose(times / plan.dt, np.rint(times / plan.dt), rtol=0, atol=1e-9)
    full = times[:-1] if (plan.total_steps % steps_per_frame) else times
    np.testing.assert_allclose(np.diff(full), steps_per_frame * plan.dt, rtol=1e-12)
    # The last frame is at the end of the run: at or just past the duration.
    last_steps = round(times[-1] / plan.dt)
    assert last_steps == plan.total_steps == summary.steps
    assert duration - 1e-12 <= times[-1] < duration + plan.dt
    assert len(times) == len(points) == summary.frames == math.ceil(plan.total_steps / steps_per_frame) + 1
    # ... and holds the state after total_steps steps (same as stepping by hand), in user order.
    prepared_again, state, corner = start(s)
    run_steps(prepared_again, state, corner, plan.total_steps)
    np.testing.assert_array_equal(points[-1], prepared_again.model.to_user_order(state.x))
    np.testing.assert_array_equal(points[0], prepared.mesh.points)   # no initial deformation


def test_auto_dt_fits_a_run_shorter_than_a_frame(scene):
    """A frame interval longer than the run (or a run shorter than a step): dt fits the duration,
    so the run ends at it instead of a step or a frame interval later, with its one frame there."""
    for duration in (0.005, 1e-9):
        plan = prepare(scene(time={"duration": duration}, output={"frame_interval": 1.0})).plan
        assert plan.total_steps * plan.dt == pytest.approx(duration, rel=1e-12)
        assert plan.frame_steps == (0, plan.total_steps)


# ---------------------------------------------------------------------------------------------
# 5. Ground contact and friction

A_CUBE, RHO_CUBE, K_GROUND, G = 0.2, 1000.0, 1.0e6, 9.81


def cube_on_ground(scene, element_size=0.05, **overrides):
    """A 0.2 m cube resting its bottom face on the ground z = 0 (stiff body: E = 1e7 >> k a)."""
    base = dict(mesh={"element_size": element_size}, material={"youngs_modulus": 1.0e7, "density": RHO_CUBE},
                gravity=[0.0, 0.0, -G], ground={"height": 0.0, "stiffness": K_GROUND})
    base.update(overrides)
    return scene(**base)


def uniform_pressure_penetration():
    """Weight / (stiffness x bottom area) [m]: the depth at which k depth A carries the weight."""
    return RHO_CUBE * A_CUBE ** 3 * G / (K_GROUND * A_CUBE ** 2)


def ground_frequency():
    """omega = sqrt(k A / M) [rad/s] of the cube bouncing on the ground as on a spring."""
    return math.sqrt(K_GROUND * A_CUBE ** 2 / (RHO_CUBE * A_CUBE ** 3))


def test_cube_settles_on_the_ground_and_never_falls_through(scene):
    """Damped near critically for the bounce, the cube comes to rest just below z = 0.

    The weight is carried by penalty pressure k * depth on the bottom: depth = W / (k A).  The
    bounds below (no deeper than that; no shallower than if the bottom-edge side strips,
    perimeter x cell height, also pushed) fail if the stiffness's units (Pa/m) are not honoured.
    """
    h = 0.05
    omega = ground_frequency()
    duration = 25.0 / omega
    s = cube_on_ground(scene, element_size=h, damping=2.0 * omega, time={"duration": duration},
                       output={"frame_interval": duration})
    prepared, state, corner = start(s)
    X = prepared.model.rest_points
    lowest = min(x[:, 2].min() for x in run_steps(prepared, state, corner, prepared.plan.total_steps, chunk=10))

    depth = uniform_pressure_penetration()
    assert np.abs(state.v).max() < 1e-6 * depth * omega      # at rest
    bottom = X[:, 2] < TOL_BOX
    penetration = -state.x[bottom, 2]
    assert penetration.min() > 0.0
    assert penetration.max() < depth * 1.01
    assert penetration.mean() > depth * A_CUBE ** 2 / (A_CUBE ** 2 + 4 * A_CUBE * h)
    assert (state.x[~bottom, 2] > 0.0).all()             # only the bottom touches the ground
    assert lowest > -depth * 1.01                         # never deeper than the rest depth


def test_resting_penetration_is_weight_over_stiffness_times_area(scene):
    """Contact pressure acts on each vertex's downward (projected) area only, so a flat body at
    rest sinks weight / (stiffness x bottom area), whatever the mesh resolution."""
    h = 0.05
    omega = ground_frequency()
    duration = 25.0 / omega
    s = cube_on_ground(scene, element_size=h, damping=2.0 * omega, time={"duration": duration},
                       output={"frame_interval": duration})
    prepared, state, corner = start(s)
    run_steps(prepared, state, corner, prepared.plan.total_steps)
    bottom = prepared.model.rest_points[:, 2] < TOL_BOX
    assert -state.x[bottom, 2].mean() == pytest.approx(uniform_pressure_penetration(), rel=0.05)


@pytest.mark.parametrize("has_ground", [True, False])
def test_dropped_cube_stops_on_the_ground_or_falls_through_without_one(scene, has_ground):
    """Undamped, released at rest touching z = 0: on the ground it bounces (a spring released at
    zero compression reaches twice the static depth, never more); without a ground it falls
    g t^2 / 2 = 0.44 m > 0.2 m in 0.3 s, wholly below z = 0."""
    s = cube_on_ground(scene, element_size=0.1, ground={"height": 0.0, "stiffness": K_GROUND} if has_ground else None,
                       time={"duration": 0.3}, output={"frame_interval": 0.3})
    prepared, state, corner = start(s)
    snapshots = run_steps(prepared, state, corner, prepared.plan.total_steps, chunk=5)
    lowest = min(x[:, 2].min() for x in snapshots)
    if has_ground:
        assert lowest > -2.0 * uniform_pressure_penetration() * 1.02
        assert lowest < 0.0
        assert state.x[:, 2].max() > A_CUBE - 4.0 * uniform_pressure_penetration()
    else:
        t = prepared.plan.total_steps * prepared.plan.dt
        assert state.x[:, 2].max() < A_CUBE - 0.5 * G * t * t + 1e-6
        assert state.x[:, 2].max() < 0.0


def test_a_cube_started_in_the_ground_is_pushed_out_with_the_energy_of_its_springs(scene, tmp_path, caplog):
    """Started 2 mm into a stiff ground without gravity, the cube's bottom springs hold
    1/2 k A d^2 = 0.8 J (A = 0.04 m^2; the side faces face no way down).  Released, they throw
    the cube up: the run completes (the guard counts that energy as put in, and so does not take
    it for a blow-up), warned that the body starts in the ground, and the cube never holds more
    than the springs gave it."""
    from softsim.integrators.guard import ground_spring_energy

    depth, stiffness = 0.002, 1.0e7
    s = scene(material={"model": "neohookean", "youngs_modulus": 1.0e7}, gravity=[0.0, 0.0, 0.0],
              ground={"height": depth, "stiffness": stiffness}, time={"duration": 0.02},
              output={"frame_interval": 0.002, "fields": ["energy"]})
    with caplog.at_level("WARNING", logger="softsim"):
        prepared = prepare(s)
    assert "ground.height = 0.002 m: 9 vertices start below it" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="softsim"):
        prepare(s, resuming=True)          # a resumed run goes on from a stored frame, not from the start
    assert "start below it" not in caplog.text
    stored = ground_spring_energy(prepared.model, initial_state(s, prepared.model).x)
    assert stored == pytest.approx(0.5 * stiffness * A_CUBE ** 2 * depth ** 2, rel=1e-12)
    summary = simulate(prepared, tmp_path / "out.h5")
    assert summary.status == "complete"
    with h5py.File(tmp_path / "out.h5", "r") as f:
        kinetic, elastic = f["frames/energy/kinetic"][...], f["frames/energy/elastic"][...]
        lowest = f["frames/points"][-1][:, 2].min()
    assert (kinetic + elastic).max() <= stored * 1.05
    assert kinetic[-1] > 0.5 * stored and lowest > depth           # thrown clear of the ground


def test_simulate_checks_the_output_again_just_before_making_it(scene, tmp_path):
    """``softsim run`` checks its output before meshing and compiling, which may take long enough for
    another run to write the file: ``simulate`` checks again, by the same ``--overwrite``."""
    prepared = prepare(scene(time={"duration": 0.002}))
    out = tmp_path / "out.h5"
    out.write_text("written meanwhile by another run\n")
    with pytest.raises(SimulationError, match="the file exists; pass --overwrite to replace it"):
        simulate(prepared, out, overwrite=False)
    assert out.read_text() == "written meanwhile by another run\n"
    assert simulate(prepared, out).status == "complete"          # the library's default replaces it


def test_the_files_wall_time_counts_the_work_before_the_file_is_made(scene, tmp_path, monkeypatch):
    """The file's ``wall_time_s`` holds its ``compile_time_s``: compiling before the file is made
    (the initial state's and the guard's kernels, on a cold cache) counted in the compile time but
    not in the wall time, which was shorter (28.5 s against 33.9 s), and a sweep's rate came out
    blank.  Here the work before the file is a sleep."""
    import time as time_module

    import softsim.simulation as simulation

    prepared = prepare(scene(time={"duration": 0.002}))
    slow_initial_state = simulation.initial_state

    def initial_state_taking_a_while(*args):
        time_module.sleep(0.3)
        return slow_initial_state(*args)

    monkeypatch.setattr(simulation, "initial_state", initial_state_taking_a_while)
    summary = simulate(prepared, tmp_path / "out.h5")
    with h5py.File(tmp_path / "out.h5", "r") as f:
        wall = float(f.attrs["wall_time_s"])
    assert 0.3 <= wall <= summary.wall_time_s


@pytest.mark.parametrize("friction", [0.5, 0.0])
def test_sliding_cube_decelerates_with_friction_and_keeps_going_without(scene, friction):
    """Launched along the ground at v0 = (1, 0.5) m/s from its resting depth, no damping.

    Coulomb friction: while the cube slides, its centre decelerates at mu g straight against v0,
    so it would stop after |v0| / (mu g) = 0.23 s.  We check the velocity at 0.4 of that time
    (still sliding), and that the cube has then lost most of its speed after the stop time; it is
    not required to be at rest then: the elastic cube on its penalty springs keeps rocking,
    undamped, once the bottom sticks.  Without friction nothing acts horizontally (the ground
    pushes along z only, elastic forces sum to zero), so the centre of mass keeps v0 exactly.
    """
    v0 = np.array([1.0, 0.5, 0.0])
    speed = np.linalg.norm(v0)
    stop_time = speed / (0.5 * G)
    s = cube_on_ground(scene, element_size=0.1,
                       ground={"height": uniform_pressure_penetration(), "stiffness": K_GROUND,
                               "friction": friction},
                       initial_velocity=v0.tolist(), time={"duration": 1.5 * stop_time},
                       output={"frame_interval": 1.5 * stop_time})
    prepared, state, corner = start(s)
    model = prepared.model
    M = model.mass.sum()
    dt = prepared.plan.dt

    def centre(a):
        return (model.mass[:, None] * a).sum(axis=0) / M

    c0 = centre(state.x)
    sliding_steps = int(0.4 * stop_time / dt)
    run_steps(prepared, state, corner, sliding_steps)
    v_sliding = centre(state.v)[:2]
    run_steps(prepared, state, corner, prepared.plan.total_steps - sliding_steps)
    t_end = prepared.plan.total_steps * dt
    if friction > 0:
        expected = v0[:2] * (1.0 - friction * G * sliding_steps * dt / speed)
        np.testing.assert_allclose(v_sliding, expected, rtol=0.05)
        assert np.linalg.norm(centre(state.v)[:2]) < 0.2 * speed
        travelled = centre(state.x)[:2] - c0[:2]
        assert np.linalg.norm(travelled) < 1.1 * speed ** 2 / (2 * friction * G)
    else:
        np.testing.assert_allclose(centre(state.v)[:2], v0[:2], rtol=1e-12)
        np.testing.assert_allclose(centre(state.x)[:2] - c0[:2], v0[:2] * t_end, rtol=1e-10)
        assert state.x[:, 2].min() > -2.0 * uniform_pressure_penetration() * 1.02   # still on top


# ---------------------------------------------------------------------------------------------
# 6. Damping


def test_damping_decays_velocity_by_exp_minus_d_dt_per_step(scene):
    """No forces (no gravity, rigid translation): v_n = v0 e^(-d dt n), and
    x_n = x0 + dt v0 sum_{k=1..n} e^(-d dt k) (damping applies before the position update).
    d dt = 0.01: a first-order factor 1 - d dt would be off by n (d dt)^2 / 2 = 1e-3 after n = 200.
    The translated cube's elastic forces are round-off, not zero (its edges are differences of
    moved coordinates): 1e-12 of v after 200 steps.
    """
    d, dt, n = 10.0, 1.0e-3, 200
    v0 = np.array([0.4, -0.3, 0.2])
    s = scene(gravity=[0.0, 0.0, 0.0], damping=d, initial_velocity=v0.tolist(),
              time={"duration": n * dt, "dt": dt}, output={"frame_interval": n * dt})
    prepared, state, corner = start(s)
    assert prepared.plan.dt == dt
    x0 = state.x.copy()
    factor = math.exp(-d * dt)
    done = 0
    for chunk in (1, 49, 150):
        run_steps(prepared, state, corner, chunk)
        done += chunk
        np.testing.assert_allclose(state.v, np.broadcast_to(v0 * factor ** done, state.v.shape), rtol=1e-11)
        drift = dt * sum(factor ** k for k in range(1, done + 1))
        np.testing.assert_allclose(state.x, x0 + v0 * drift, rtol=0, atol=1e-13)


# ---------------------------------------------------------------------------------------------
# 7. Prescribed motion


def test_held_vertices_follow_their_prescribed_motion(scene):
    """Held components follow x = x0 + v t from their initial (deformed) position, exactly; the
    components not held move freely (here: fall under gravity)."""
    A = np.array([[1.02, 0.01, 0.0], [0.0, 0.99, 0.0], [0.0, 0.02, 1.01]])
    b = np.array([0.05, 0.0, -0.01])
    v_left = np.array([0.0, 0.02, -0.05])
    v_right = np.array([0.1, 0.0, 0.0])
    s = scene(
        initial_deformation={"matrix": A.tolist(), "translation": b.tolist()},
        fixed=[{"min": [-TOL_BOX, -1, -1], "max": [TOL_BOX, 1, 1], "velocity": v_left.tolist()},
               {"min": [0.2 - TOL_BOX, -1, -1], "max": [0.2 + TOL_BOX, 1, 1], "axes": ["x"],
                "velocity": v_right.tolist()}],
        time={"duration": 0.2},
    )
    prepared, state, corner = start(s)
    model = prepared.model
    X = model.rest_points
    x0 = X @ A.T + b
    left = X[:, 0] < TOL_BOX
    right = X[:, 0] > 0.2 - TOL_BOX
    assert left.sum() == right.sum() == 9
    np.testing.assert_array_equal(model.held[left], True)
    np.testing.assert_array_equal(model.held[right], [[True, False, False]] * 9)
    assert not model.held[~(left | right)].any()

    dt = prepared.plan.dt
    n = 0
    for chunk in (1, 19, 80):
        run_steps(prepared, state, corner, chunk)
        n += chunk
        t = n * dt
        np.testing.assert_allclose(state.x[left], x0[left] + v_left * t, rtol=0, atol=4 * EPS)
        np.testing.assert_allclose(state.x[right, 0], x0[right, 0] + v_right[0] * t, rtol=0, atol=4 * EPS)
        np.testing.assert_array_equal(state.v[left], np.broadcast_to(v_left, (9, 3)))
        np.testing.assert_array_equal(state.v[right, 0], v_right[0])
    # Free components really are free: the right face sagged under gravity (it is not held in z;
    # a held z would stay exactly at x0).
    assert (state.x[right, 2] < x0[right, 2] - 1e-3).all()


@pytest.mark.parametrize("key, region, message", [
    ("fixed", {"min": [0.21, -1, -1], "max": [0.3, 1, 1]}, "holds no vertex"),
    # the box holds the corners of the x = 0.2 face but no whole face: its edge at z = 0.2 only
    ("tractions", {"min": [0.2, -1, 0.2], "max": [0.2, 1, 1], "traction": [1e3, 0, 0]},
     r"holds no boundary face \(all three corners inside\)"),
])
def test_a_region_that_selects_nothing_is_refused(scene, key, region, message):
    """A fixed or traction box that misses the mesh would leave the body unheld or unloaded
    without a word: refused, naming the key, the box and the mesh's extent."""
    inside = dict(region, max=[0.2, 1, 1], min=[0.2 - TOL_BOX, -1, -1])
    prepare(scene(**{key: [inside]}))                          # a box on the x = 0.2 face: fine
    with pytest.raises(ConfigError, match=rf"^{key}\[1\]: the box min = .* {message} of the mesh, which spans "
                                          r"x 0\.\.0\.2, y 0\.\.0\.2, z 0\.\.0\.2 m; a .* box must hold at least one$"):
        prepare(scene(**{key: [inside, region]}))


# ---------------------------------------------------------------------------------------------
# 8. Determinism


def busy_scene(scene):
    """Every feature at once: corotated (SVD), ground with friction, damping, traction, driven and
    roller constraints, an initial stretch, spin and drift."""
    return scene(
        material={"model": "corotated"},
        mesh={"size": [0.4, 0.2, 0.2]},
        damping=0.5,
        ground={"height": -0.01, "stiffness": 1.0e5, "friction": 0.4},
        fixed=[{"min": [-TOL_BOX, -1, -1], "max": [TOL_BOX, 1, 1], "axes": ["x"], "velocity": [0.01, 0, 0]}],
        tractions=[{"min": [0.4 - TOL_BOX, -1, -1], "max": [0.4 + TOL_BOX, 1, 1], "traction": [2e3, 0, -1e3]}],
        initial_deformation={"matrix": [[1.01, 0, 0], [0, 1, 0.01], [0, 0, 0.99]]},
        initial_velocity=[0.0, 0.2, -0.1],
        angular_velocity=[0.5, 0.0, 1.0],
        time={"duration": 0.2},
        output={"frame_interval": 0.05},
    )


def test_runs_are_bit_identical_whatever_the_thread_count(scene, monkeypatch):
    import softsim.integrators.symplectic_euler as symplectic_euler

    monkeypatch.setattr(symplectic_euler, "TETS_PER_THREAD", 1)     # a small mesh on every thread
    s = busy_scene(scene)
    results = []
    threads = numba.get_num_threads()
    try:
        for count in (threads, threads, 1):
            numba.set_num_threads(count)
            prepared, state, corner = start(s)
            run_steps(prepared, state, corner, prepared.plan.total_steps, chunk=7)
            assert numba.get_num_threads() == count          # the step gives its threads back
            results.append((state.x.copy(), state.v.copy()))
    finally:
        numba.set_num_threads(threads)
    for x, v in results[1:]:
        np.testing.assert_array_equal(x, results[0][0])
        np.testing.assert_array_equal(v, results[0][1])
    assert np.abs(results[0][0] - prepared.model.rest_points).max() > 1e-3   # something happened


def test_two_simulate_runs_write_identical_frames(scene, tmp_path):
    s = busy_scene(scene)
    frames = []
    for name in ("a.h5", "b.h5"):
        simulate(prepare(s), tmp_path / name)
        with h5py.File(tmp_path / name, "r") as f:
            frames.append((f["frames/time"][:], f["frames/points"][:]))
    np.testing.assert_array_equal(frames[0][0], frames[1][0])
    np.testing.assert_array_equal(frames[0][1], frames[1][1])


def test_each_frame_computes_its_elastic_energy_once_for_the_guard_and_the_file(scene, tmp_path, monkeypatch):
    """The guard's energy check and the file's ``energy`` field take the same energies, computed
    once a frame (the elastic energy was computed twice: 0.1 ms a frame on the twisted bar); the
    guard computes its own once, for the budget at the start.  The file still gets every frame's
    elastic energy (finite, and above zero once the beam sags)."""
    import softsim.integrators.guard as guard_module
    import softsim.simulation as simulation

    calls = []

    def counted(name, function):
        def count(*args):
            calls.append(name)
            return function(*args)
        return count

    monkeypatch.setattr(simulation, "elastic_energy", counted("frame", simulation.elastic_energy))
    monkeypatch.setattr(guard_module, "elastic_energy", counted("guard", guard_module.elastic_energy))
    prepared = prepare(scene(time={"duration": 0.004}, output={"frame_interval": 0.001, "fields": ["energy"]}))
    summary = simulate(prepared, tmp_path / "out.h5")
    assert summary.frames == 5
    assert calls.count("guard") == 1 and calls.count("frame") == summary.frames
    with h5py.File(tmp_path / "out.h5", "r") as f:
        elastic = f["frames/energy/elastic"][:]
    assert np.all(np.isfinite(elastic)) and elastic[-1] > 0.0
