"""Symplectic Euler's exact stability limit (``softsim.integrators.stability``).

The matrix-free Lanczos value of ``lambda_max(M^-1 K)`` is checked against dense eigenvalues
computed here, independently: for the linear model ``K`` is assembled analytically from each tet's
corner gradients (``K_ab = V (lambda b_a b_b^T + mu (b_a . b_b) I + mu b_b b_a^T)``); for a
nonlinear model at a deformed state, column by column from central differences of
``elastic_forces``.  Then the limit is shown to be real: symplectic Euler just below it keeps the
energy bounded, just above it the energy explodes.

Meshes are tiny (tens to a couple of hundred tets), so dense eigenvalue problems are instant.
"""

import math

import numpy as np
import pytest

from softsim.integrators.stability import (
    element_frequency_bound,
    exact_stable_step,
    frequency_analysis,
    largest_frequency_squared,
    nodal_frequency_bound,
)
from softsim.kernels.forces import elastic_forces
from softsim.mesh import checked_mesh
from softsim.model import build_model, initial_state
from softsim.simulation import prepare, step

MODELS = ("linear", "stvk", "corotated", "neohookean")
STRUCTURED = {"size": [0.3, 0.2, 0.2], "element_size": 0.1, "structured": True}          # 60 tets
GMSH = {"size": [0.2, 0.15, 0.1], "element_size": 0.1, "structured": False}              # ~180 tets
HELD_END = [{"min": [-1e-6, -1.0, -1.0], "max": [1e-6, 1.0, 1.0]}]                        # face x = 0


def model_of(scene):
    return prepare(scene).model


def free_components(model):
    """Flat bool mask (3n,) of the components that move: not held and not massless."""
    return (~model.held & (model.inv_mass > 0.0)[:, None]).ravel()


def hooke_stiffness(model, lam, mu):
    """Dense (3n, 3n) stiffness of linear elasticity, assembled tet by tet from ``Dm_inv``."""
    n = model.node_count
    K = np.zeros((3 * n, 3 * n))
    for e, tet in enumerate(model.tets):
        G = model.Dm_inv[e]                                   # row a-1: gradient of corner a
        b = np.vstack([-G.sum(axis=0), G])
        V = model.rest_volume[e]
        for a in range(4):
            for c in range(4):
                block = V * (lam * np.outer(b[a], b[c]) + mu * (b[a] @ b[c]) * np.eye(3)
                             + mu * np.outer(b[c], b[a]))
                K[3 * tet[a]:3 * tet[a] + 3, 3 * tet[c]:3 * tet[c] + 3] += block
    return K


def fd_stiffness(model, x, h):
    """Dense tangent stiffness at ``x`` by central differences of the elastic forces, column by column."""
    n = model.node_count
    K = np.zeros((3 * n, 3 * n))
    for col in range(3 * n):
        d = np.zeros(3 * n)
        d[col] = h
        d = d.reshape(n, 3)
        f = [elastic_forces(x + s * d, model.tets, model.Dm_inv, model.rest_volume, model.material_id,
                            model.lam, model.mu, model.csr_offsets, model.csr_slots) for s in (1.0, -1.0)]
        K[:, col] = -(f[0] - f[1]).ravel() / (2.0 * h)
    return K


def dense_lambda_max(model, K, ground_diagonal=None):
    """Largest real eigenvalue of ``M^-1 K`` (+ ground diagonal) restricted to the free components."""
    free = free_components(model)
    A = np.repeat(model.inv_mass, 3)[:, None] * K
    if ground_diagonal is not None:
        A += np.diag(ground_diagonal)
    return float(np.linalg.eigvals(A[np.ix_(free, free)]).real.max())


def linear_K(model):
    return hooke_stiffness(model, model.lam, model.mu)


# ---------------------------------------------------------------------------------------------
# 1. Against dense eigenvalues


@pytest.mark.parametrize("mesh", [STRUCTURED, GMSH], ids=["structured", "gmsh"])
@pytest.mark.parametrize("fixed", [None, HELD_END], ids=["free", "held-end"])
def test_matches_dense_eigenvalue_of_the_linear_model(scene, mesh, fixed):
    model = model_of(scene(mesh=mesh, material={"model": "linear", "poissons_ratio": 0.45}, fixed=fixed))
    expected = dense_lambda_max(model, linear_K(model))
    assert largest_frequency_squared(model) == pytest.approx(expected, rel=1e-4)
    assert exact_stable_step(model) == pytest.approx(2.0 / math.sqrt(expected), rel=1e-4)


@pytest.mark.parametrize("model_name", MODELS)
def test_every_model_linearises_to_hooke_at_rest(scene, model_name):
    """At rest every model's tangent is Hooke's law with the scene's E and nu (Neo-Hookean's remap)."""
    s = scene(mesh=STRUCTURED, material={"model": model_name, "poissons_ratio": 0.3})
    model = model_of(s)
    E, nu = s.material.youngs_modulus, s.material.poissons_ratio
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    expected = dense_lambda_max(model, hooke_stiffness(model, lam, mu))
    assert largest_frequency_squared(model) == pytest.approx(expected, rel=1e-4)


@pytest.mark.parametrize("model_name", ["stvk", "neohookean"])
def test_matches_dense_tangent_at_a_deformed_state(scene, model_name):
    """Away from rest the tangent is the model's own; compare with a finite-difference dense K there."""
    model = model_of(scene(mesh=STRUCTURED, material={"model": model_name, "poissons_ratio": 0.4},
                           fixed=HELD_END))
    rng = np.random.default_rng(7)
    A = np.array([[1.3, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 0.7]])
    x = model.rest_points @ A.T + 0.005 * rng.standard_normal(model.rest_points.shape)
    expected = dense_lambda_max(model, fd_stiffness(model, x, 1e-7))
    rest = largest_frequency_squared(model)
    got = largest_frequency_squared(model, x)
    assert got == pytest.approx(expected, rel=1e-3)
    assert abs(got / rest - 1.0) > 0.05            # the state matters: not just the rest value


@pytest.mark.parametrize("model_name", MODELS)
def test_forward_differences_give_the_central_value_at_a_deformed_state(scene, model_name):
    """The guard's estimate applies K by forward differences from the forces at x, one force
    evaluation an application instead of two: at a stretched, sheared and shaken state the same
    largest eigenvalue as central differences to 1e-6, and as the dense tangent to 1e-3.  Where
    the forces at x are not finite, no finite step is stable: infinity, as the central form gives."""
    model = model_of(scene(mesh=STRUCTURED, material={"model": model_name, "poissons_ratio": 0.4},
                           fixed=HELD_END))
    rng = np.random.default_rng(11)
    A = np.array([[1.3, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 0.7]])
    x = model.rest_points @ A.T + 0.005 * rng.standard_normal(model.rest_points.shape)
    central = frequency_analysis(model, x, tol=1e-10, differences="central")
    forward = frequency_analysis(model, x, tol=1e-10, differences="forward")
    assert central.converged and forward.converged
    assert forward.lambda_max == pytest.approx(central.lambda_max, rel=1e-6)
    assert forward.lambda_max == pytest.approx(dense_lambda_max(model, fd_stiffness(model, x, 1e-7)), rel=1e-3)
    # the guard's call: tol 1e-2, at most 80 applications
    guard = largest_frequency_squared(model, x, iterations=80, tol=1e-2, differences="forward")
    assert guard == pytest.approx(central.lambda_max, rel=1e-2)
    broken = x.copy()
    broken[model.tets[0, 1], 0] = np.nan
    for differences in ("central", "forward"):
        assert frequency_analysis(model, broken, differences=differences).lambda_max == math.inf
    with pytest.raises(ValueError, match="differences"):
        frequency_analysis(model, x, differences="backward")


def test_ground_springs_are_a_diagonal_term_on_z(scene):
    model = model_of(scene(mesh=STRUCTURED, material={"model": "linear"}, ground={"height": 0.0, "stiffness": 1e7}))
    diagonal = np.zeros((model.node_count, 3))
    diagonal[:, 2] = model.contact_stiffness_bound * model.inv_mass
    expected = dense_lambda_max(model, linear_K(model), diagonal.ravel())
    without = dense_lambda_max(model, linear_K(model))
    assert expected > 1.5 * without                # the ground dominates here
    assert largest_frequency_squared(model) == pytest.approx(expected, rel=1e-4)
    assert largest_frequency_squared(model) <= without + diagonal.max() * (1 + 1e-9)


def test_massless_vertices_and_held_components_do_not_count(scene):
    """A vertex no tet uses (massless, held) changes nothing; holding everything gives no limit."""
    s = scene(mesh=STRUCTURED, material={"model": "linear"})
    base = model_of(s)
    mesh = base.mesh
    points = np.vstack([mesh.points, [[5.0, 5.0, 5.0]]])
    lonely = build_model(s, checked_mesh(points, mesh.tets, "test"))
    assert (lonely.inv_mass == 0.0).sum() == 1
    assert largest_frequency_squared(lonely) == pytest.approx(largest_frequency_squared(base), rel=1e-6)
    everything = model_of(scene(mesh=STRUCTURED, material={"model": "linear"},
                                fixed=[{"min": [-1, -1, -1], "max": [1, 1, 1]}]))
    assert largest_frequency_squared(everything) == 0.0
    assert exact_stable_step(everything) == math.inf


def test_result_is_deterministic(scene):
    model = model_of(scene(mesh=GMSH, material={"model": "corotated"}))
    first = frequency_analysis(model)
    second = frequency_analysis(model)
    assert first.converged
    assert first.lambda_max == second.lambda_max     # bit for bit
    assert np.array_equal(first.mode, second.mode)


def test_rigorous_bounds_are_above_the_exact_value(scene):
    """Element (Irons) and nodal bounds are upper bounds of lambda_max; the nodal one is the tighter."""
    for mesh in (STRUCTURED, GMSH):
        model = model_of(scene(mesh=mesh, material={"model": "neohookean", "poissons_ratio": 0.49}))
        exact = largest_frequency_squared(model)
        nodal = nodal_frequency_bound(model)
        assert exact <= nodal * (1 + 1e-9)
        assert nodal <= element_frequency_bound(model) * (1 + 1e-9)
        assert nodal < 4.0 * exact                   # the dt from it is within 2x of the limit


# ---------------------------------------------------------------------------------------------
# 2. End to end: the limit is real


def energy(model, K, state):
    """Kinetic + elastic energy [J] of the linear model (its elastic energy is exactly u^T K u / 2)."""
    u = (state.x - model.rest_points).ravel()
    return 0.5 * float((model.mass[:, None] * state.v ** 2).sum()) + 0.5 * float(u @ K @ u)


def run_energy(prepared, K, dt, steps, chunk=100, stop_factor=1e8):
    """Energies after every ``chunk`` steps of symplectic Euler at ``dt`` from a small random perturbation."""
    model = prepared.model
    state = initial_state(prepared.scene, model)
    rng = np.random.default_rng(3)
    h = float(np.cbrt(model.rest_volume.min()))
    state.x += np.where(model.held, 0.0, 1e-4 * h * rng.standard_normal(state.x.shape))
    corner_forces = np.empty((model.tet_count, 4, 3))
    energies = [energy(model, K, state)]
    done = 0
    while done < steps and energies[-1] < stop_factor * energies[0]:
        step(model, state, dt, chunk, 0.0, corner_forces)
        done += chunk
        energies.append(energy(model, K, state))
    return np.array(energies)


@pytest.mark.parametrize("mesh, fixed", [(STRUCTURED, HELD_END), (GMSH, None)], ids=["structured-held", "gmsh-free"])
@pytest.mark.parametrize("factor, stable", [(0.97, True), (1.05, False), (0.995, True), (1.005, False)])
def test_symplectic_euler_is_stable_below_the_limit_and_blows_up_above(scene, mesh, fixed, factor, stable):
    """Linear model, no gravity, at rest plus a random perturbation (v = 0).

    Below the limit each mode keeps symplectic Euler's modified energy
    ``E - dt omega^2 x v / 2``, which is at least ``(1 - omega dt / 2) E``; it starts at ``E0``
    (v = 0), so ``E <= E0 / (1 - factor)`` for ever.  Above it, the top mode grows by a factor
    ``> 1.2`` per step (1.005x) or ``~1.9`` (1.05x): orders of magnitude within a few hundred steps.
    """
    prepared = prepare(scene(mesh=mesh, material={"model": "linear", "poissons_ratio": 0.3},
                             gravity=[0.0, 0.0, 0.0], fixed=fixed))
    model = prepared.model
    K = linear_K(model)
    dt = factor * exact_stable_step(model)
    energies = run_energy(prepared, K, dt, steps=3000)
    assert np.isfinite(energies).all()
    if stable:
        assert len(energies) == 31                                   # ran all 3000 steps
        assert energies.max() <= energies[0] / (1.0 - factor) * (1 + 1e-6)
    else:
        assert energies.max() > 1e6 * energies[0]


@pytest.mark.parametrize("model_name", MODELS)
def test_the_operator_takes_the_steps_blocked_forces_equal_to_the_per_tet_ones(scene, model_name):
    """The operator's force evaluations run the step's blocked kernels where the model steps in
    float64 (3-7x the per-tet kernel's speed); at a deformed state they agree with the per-tet
    ``elastic_forces`` to round-off, for every law (corotated's Newton iteration included), with
    the layout's rest data stored or computed from the rest positions, prefetched or not.  Each
    evaluation starts corotated's blocks at the same first Newton steps: near rest, where a
    block's steps fall from call to call, two evaluations give the same bits.  A float32 model,
    whose blocks hold float32 rest data, keeps the per-tet kernel."""
    import dataclasses

    from softsim.integrators.stability import _SymmetricOperator
    from softsim.kernels.blocked import PREFETCH_BLOCKS_AHEAD, build_block_layout, prefetching

    model = model_of(scene(mesh=GMSH, material={"model": model_name, "poissons_ratio": 0.4}, fixed=HELD_END))
    rng = np.random.default_rng(3)
    A = np.array([[1.3, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 0.7]])
    deformed = model.rest_points @ A.T + 0.003 * rng.standard_normal(model.rest_points.shape)
    near_rest = model.rest_points + 1e-7 * rng.standard_normal(model.rest_points.shape)
    computed = build_block_layout(model.tets, model.Dm_inv, model.rest_volume, model.node_count,
                                  rest_from_points=True, model=model.material_id)
    for layout in (model.blocks, prefetching(model.blocks, model.node_count, PREFETCH_BLOCKS_AHEAD), computed):
        m = dataclasses.replace(model, blocks=layout)
        for x in (np.ascontiguousarray(deformed), np.ascontiguousarray(near_rest)):
            op = _SymmetricOperator(m, x)
            assert op.blocked is not None
            got = op._forces(x, np.empty_like(x))
            expected = elastic_forces(x, m.tets, m.Dm_inv, m.rest_volume, m.material_id, m.lam, m.mu,
                                      m.csr_offsets, m.csr_slots)
            scale = np.abs(expected).max()
            assert scale > 0.0 and np.abs(got - expected).max() <= 1e-10 * scale
            assert op._forces(x, np.empty_like(x)).tobytes() == got.tobytes()        # again: the same bits
    single = model_of(scene(mesh=GMSH, fixed=HELD_END, precision="float32"))
    assert _SymmetricOperator(single, single.rest_points).blocked is None
