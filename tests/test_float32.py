"""The float32 step (``precision: float32``): the laws in displacement form, the float32 force
kernel and whole float32 runs, each against float64 (``tests/naive.py`` or softsim's float64 run).

float32 keeps about 7 digits.  A steel strain of 1e-6 survives it only because the step stores
displacements ``u = x - X`` and the laws take ``H = F - I``; the tests below also show that the
plain ``F`` form would lose it.
"""

import numba
import numpy as np
import pytest

import naive
from softsim.config import parse_scene
from softsim.config.schema import FLOAT32_MODELS
from softsim.errors import ConfigError
from softsim.integrators.symplectic_euler import SinglePrecisionWork, advance, step_arguments, update_vertex
from softsim.kernels.jit import CompileTimeConstant
from softsim.materials import models
from softsim.materials.models import DISPLACEMENT_FORM_MODELS, MODEL_IDS, model_lame_parameters
from softsim.model import initial_state
from softsim.simulation import prepare, step
from test_blocked_kernels import Body, mesh, with_prefetch

E_PA = 1.0e6
NU = 0.3
STEEL = {"model": "stvk", "youngs_modulus": 2.0e11, "poissons_ratio": 0.3, "density": 7850.0}

DISPLACEMENT_LAWS = {name: getattr(models, f"{name}_first_piola_displacement") for name in DISPLACEMENT_FORM_MODELS}
DEFORMATION_LAWS = {name: getattr(models, f"{name}_first_piola") for name in DISPLACEMENT_FORM_MODELS}


def random_gradient(scale, seed):
    return np.random.default_rng(seed).normal(size=(3, 3)) * scale


def test_the_schema_offers_float32_for_the_models_with_a_displacement_form():
    assert set(FLOAT32_MODELS) == set(DISPLACEMENT_FORM_MODELS)


@pytest.mark.parametrize("scale", [0.4, 1e-3])
@pytest.mark.parametrize("model", DISPLACEMENT_FORM_MODELS)
def test_displacement_form_is_the_law_at_f_equal_i_plus_h(model, scale):
    """``P(H)`` equals the independent NumPy law at ``F = I + H`` (float64), large and small strain."""
    lam, mu = model_lame_parameters(model, E_PA, NU)
    for seed in range(5):
        H = random_gradient(scale, seed)
        expected = naive.pk1(model, np.eye(3) + H, lam, mu)
        got = np.array(DISPLACEMENT_LAWS[model](tuple(H.ravel()), lam, mu)).reshape(3, 3)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-11 * np.abs(expected).max())


@pytest.mark.parametrize("model", DISPLACEMENT_FORM_MODELS)
def test_float32_displacement_form_keeps_a_steel_strain_the_f_form_loses(model):
    """At strain 1e-6, float32 ``P(H)`` is good to 1e-5 relative; float32 ``P(F)`` is off by percents
    (F's diagonal rounds to 6e-8 of 1, 6 % of the strain)."""
    lam, mu = model_lame_parameters(model, 2.0e11, NU)
    worst_h, worst_f = 0.0, 0.0
    for seed in range(5):
        H = random_gradient(1e-6, seed)
        expected = naive.pk1(model, np.eye(3) + H, lam, mu)
        scale = np.abs(expected).max()
        h32 = tuple(np.float32(h) for h in H.ravel())
        f32 = tuple(np.float32(f) for f in (np.eye(3) + H).ravel())
        lam32, mu32 = np.float32(lam), np.float32(mu)
        P_h = np.array(DISPLACEMENT_LAWS[model](h32, lam32, mu32), dtype=np.float64).reshape(3, 3)
        P_f = np.array(DEFORMATION_LAWS[model](f32, lam32, mu32), dtype=np.float64).reshape(3, 3)
        worst_h = max(worst_h, np.abs(P_h - expected).max() / scale)
        worst_f = max(worst_f, np.abs(P_f - expected).max() / scale)
    assert worst_h < 1e-5
    assert worst_f > 1e-2


def test_float32_laws_compute_in_float32():
    """No float64 constant promotes the float32 lane loop (it would halve the SIMD width)."""
    h32 = tuple(np.float32(0.01 * k) for k in range(9))
    for law in DISPLACEMENT_LAWS.values():
        law(h32, np.float32(1.0), np.float32(2.0))
        assert str(law.nopython_signatures[-1].return_type) == "UniTuple(float32 x 9)"


def float32_forces(body, u, model, lam, mu):
    """Elastic forces [N] (float32) of displacements ``u`` from one step of ``advance`` with ``dt = 1``,
    unit inverse masses and ``v = 0`` (see ``test_blocked_kernels``)."""
    n = body.node_count
    u = np.array(u, dtype=np.float32)
    v = np.zeros_like(u)
    blocks, colour_offsets, scatter, offsets, slots, vf, corner = step_arguments(body, body.work.forces)
    # the rest positions in float64, as the step takes them (``SinglePrecisionWork.rest``): the same compiled step
    advance(u, body.rest_points, v, 0, 1, np.float32(1.0), blocks, colour_offsets, scatter,
            CompileTimeConstant(MODEL_IDS[model]), np.float32(lam), np.float32(mu), offsets, slots, vf, corner,
            np.ones(n, np.float32), body.work.gravity, None, np.zeros((n, 3), np.bool_), u.copy(),
            np.zeros((n, 3), np.float32), None, None, None, 1, True)
    return v.astype(np.float64)


class SingleBody(Body):
    precision = "float32"

    def __init__(self, points, tets, scatter):
        super().__init__(points, tets, scatter)
        from softsim.kernels.blocked import build_block_layout

        self.blocks = build_block_layout(self.tets, self.Dm_inv, self.V0, self.node_count, scatter,
                                         dtype=np.float32, model=self.material_id)
        self.rest_points, self.inv_mass = self.X, np.ones(self.node_count)
        self.external_accel = self.held_velocity = np.zeros((self.node_count, 3))
        self.gravity, self.has_tractions = np.zeros(3), False
        self.work = SinglePrecisionWork(self)


@pytest.mark.parametrize("strain", [0.2, 1e-6])
# csr in float32 is no scene's nor benchmark's (see CSR_SLOW in test_blocked_kernels.py)
@pytest.mark.parametrize("scatter", ["colour", pytest.param("csr", marks=pytest.mark.slow)])
@pytest.mark.parametrize("model", DISPLACEMENT_FORM_MODELS)
def test_float32_kernel_forces_match_naive_float64(model, scatter, strain):
    """Randomly deformed (strain 0.2) or barely so (1e-6, a steel load): float32 forces within
    1e-5 of the largest float64 force."""
    points, tets, x = mesh((7, 5, 3))
    x = points + strain / 0.2 * (x - points)
    body = SingleBody(points, tets, scatter)
    assert body.blocks.rest.dtype == np.float32
    lam, mu = model_lame_parameters(model, E_PA, NU)
    expected = naive.elastic_forces(x, body.X, body.tets, model, lam, mu)
    got = float32_forces(body, x - points, model, lam, mu)
    assert np.abs(got - expected).max() < 1e-5 * np.abs(expected).max()


@pytest.mark.parametrize("model", ["stvk"] + [pytest.param(m, marks=pytest.mark.slow)
                                              for m in DISPLACEMENT_FORM_MODELS if m != "stvk"])
def test_float32_prefetching_changes_no_bit(model):
    """The displacement-form lane loops with the rest data and the first-used vertex rows
    prefetched (``BlockLayout.prefetch``, forced onto a mesh too small to get it) give the same
    bits as without."""
    from softsim.kernels.blocked import PREFETCH_BLOCKS_AHEAD

    points, tets, x = mesh((7, 5, 3))
    body = SingleBody(points, tets, "colour")
    assert body.blocks.prefetch is None
    lam, mu = model_lame_parameters(model, E_PA, NU)
    plain = float32_forces(body, x - points, model, lam, mu)
    body.blocks = with_prefetch(body.blocks, PREFETCH_BLOCKS_AHEAD, body.node_count)
    assert float32_forces(body, x - points, model, lam, mu).tobytes() == plain.tobytes()


def run_pair(scene_data, steps):
    """Positions [m] after ``steps`` steps in float64 and in float32, and the rest positions."""
    out = []
    for precision in ("float64", "float32"):
        prepared = prepare(parse_scene({**scene_data, "precision": precision}))
        model = prepared.model
        state = initial_state(prepared.scene, model)
        from softsim.integrators.symplectic_euler import work_buffer

        work = work_buffer(model)
        for _ in range(4):             # in several calls: the state crosses to float32 and back each time
            step(model, state, prepared.plan.dt, steps // 4, prepared.scene.damping, work)
        out.append(state.x.copy())
    return out[0], out[1], model.rest_points


def test_float32_steel_cantilever_follows_float64():
    """A steel beam's first steps move its vertices by ~1e-8 m a step, below float32's spacing at
    1 m (1.2e-7 m): stored as displacements they add up as in float64."""
    scene_data = {"mesh": {"shape": "box", "size": [1.0, 0.1, 0.1], "element_size": 0.05, "structured": True},
                  "material": STEEL, "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
                  "time": {"duration": 1.0}}
    x64, x32, X = run_pair(scene_data, 400)
    moved = np.abs(x64 - X).max()
    assert moved > 1e-6
    assert np.abs(x32 - x64).max() < 1e-4 * moved


def test_float32_ground_damping_and_driven_vertices_follow_float64():
    """A rubber cube dropped on the ground, damped, one face driven: float32 follows float64."""
    scene_data = {"mesh": {"shape": "box", "size": [0.2, 0.2, 0.2], "element_size": 0.05, "structured": True},
                  "material": {"model": "neohookean", "youngs_modulus": 1e6, "poissons_ratio": 0.45,
                               "density": 1000.0},
                  "initial_deformation": {"translation": [0.0, 0.0, 0.001]}, "initial_velocity": [0, 0, -1.0],
                  "ground": {"height": 0.0}, "damping": 2.0,
                  "fixed": [{"min": [-1, -1, 0.2 - 1e-6], "max": [1, 1, 1], "axes": ["x"], "velocity": [0.3, 0, 0]}],
                  "time": {"duration": 1.0}}
    x64, x32, X = run_pair(scene_data, 800)
    moved = np.abs(x64 - X).max()
    assert x64[:, 2].min() > -0.005          # the ground stopped it (in free fall it would be 0.3 m lower)
    assert moved > 1e-3
    assert np.abs(x32 - x64).max() < 1e-4 * moved



@numba.njit
def _update_every_vertex(x, rest, v, dt, inv_mass, gravity, held, ground, damping_factor):
    """``update_vertex`` of every vertex with no elastic force (zero in the precision of ``v``) and
    no tractions; held components (if any) start at 0 and stay there."""
    zero = v.dtype.type(0.0)
    held_start, held_velocity = np.zeros_like(x), np.zeros_like(v)
    for i in range(x.shape[0]):
        update_vertex(x, rest, v, i, zero, zero, zero, dt, dt, inv_mass, gravity, None, held, held_start,
                      held_velocity, ground, damping_factor)


def test_float32_damping_scales_the_float32_velocity_after_the_ground():
    """In float32 the ground's push and friction (float64 scalars) give a velocity rounded to
    float32, as if stored, before the damping scales it: damped, each velocity is the undamped
    float32 one times the factor, rounded once more.  (Kept in float64 through the damping, 28 %
    of the velocities of vertices below the ground differed in their last bit.)"""
    rng = np.random.default_rng(5)
    n = 400
    rest = rng.uniform(-1.0, 1.0, size=(n, 3))
    u = rng.normal(scale=0.01, size=(n, 3)).astype(np.float32)
    v = rng.normal(size=(n, 3)).astype(np.float32)
    inv_mass = rng.uniform(0.5, 2.0, size=n).astype(np.float32)
    gravity = (np.float32(0.0), np.float32(0.0), np.float32(-9.81))
    held = np.zeros((n, 3), dtype=np.bool_)
    area_z = -rng.uniform(0.0, 1e-3, size=n)
    dt, factor = np.float32(1e-3), 0.999
    velocities = {}
    for damping in (None, factor):
        v_after = v.copy()
        _update_every_vertex(u.copy(), rest, v_after, dt, inv_mass, gravity, held, (0.0, 1e6, 0.3, area_z.copy()),
                             damping)
        velocities[damping] = v_after
    below = rest[:, 2] + u[:, 2] < 0.0
    assert below.sum() > 100 and (velocities[None][below] != v[below]).all()      # the ground acted
    expected = (velocities[None].astype(np.float64) * factor).astype(np.float32)
    np.testing.assert_array_equal(velocities[factor], expected)

def test_float32_refuses_corotated_with_a_one_line_error():
    with pytest.raises(ConfigError, match=r"precision = 'float32'.*corotated.*linear, stvk, neohookean"):
        parse_scene({"mesh": {"shape": "box", "size": [1, 1, 1], "element_size": 0.5},
                     "material": {"model": "corotated", "youngs_modulus": 1e6, "poissons_ratio": 0.3,
                                  "density": 1000.0},
                     "precision": "float32"})


def test_float32_warns_when_a_step_damps_below_its_resolution(caplog):
    """A steel beam's step is ~1e-6 s: damping 0.5/s takes 5e-7 of a velocity a step, near float32's
    6e-8 spacing; a float64 run says nothing."""
    scene = {"mesh": {"shape": "box", "size": [1.0, 0.1, 0.1], "element_size": 0.05, "structured": True},
             "material": STEEL, "damping": 0.5, "time": {"duration": 0.01}}
    with caplog.at_level("WARNING", logger="softsim"):
        prepare(parse_scene({**scene, "precision": "float64"}))
    assert "float32" not in caplog.text
    with caplog.at_level("WARNING", logger="softsim"):
        prepare(parse_scene({**scene, "precision": "float32"}))
    assert "precision: float32 with damping 0.5" in caplog.text and "use float64" in caplog.text
