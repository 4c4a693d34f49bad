"""Material laws against continuum mechanics: Hooke's law from the notes, small-strain agreement of
all four models with the user's E and nu, P = dPsi/dF, and frame indifference.

Every expected value is built here from E, nu and the formulas of the notes / Sifakis & Barbic
2012 / Smith et al. 2018, never copied from softsim's output.
"""

import numpy as np
import pytest

import naive
from softsim.errors import ConfigError
from softsim.materials.lame import lame_parameters
from softsim.materials.models import (
    INVERSION_SAFE,
    MODEL_IDS,
    ROTATION_INVARIANT,
    energy_density,
    first_piola,
    hooke_stress,
    model_lame_parameters,
)

MODELS = tuple(MODEL_IDS)
E_PA = 1.0e6
# Poisson ratios spanning auxetic, zero, typical and nearly incompressible solids.
NUS = (-0.3, 0.0, 0.3, 0.45, 0.49)


def _tuple(F):
    return tuple(float(v) for v in np.asarray(F, dtype=np.float64).ravel())


def P_of(model, F, lam, mu):
    """softsim's first Piola-Kirchhoff stress as a (3, 3) array."""
    return np.array(first_piola(MODEL_IDS[model], _tuple(F), lam, mu)).reshape(3, 3)


def psi_of(model, F, lam, mu):
    return float(energy_density(MODEL_IDS[model], _tuple(F), lam, mu))


def random_rotation(rng, min_angle=0.5 * np.pi):
    """Rodrigues rotation about a random axis by an angle in [min_angle, pi]."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(min_angle, np.pi)
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def random_stretch(rng, amount=0.25):
    """A well-conditioned F with det > 0 and clearly distinct singular values."""
    while True:
        F = np.eye(3) + amount * rng.normal(size=(3, 3))
        s = np.linalg.svd(F, compute_uv=False)
        if np.linalg.det(F) > 0.3 and np.min(np.diff(-s)) > 0.05:
            return F


# ---------------------------------------------------------------------------------------------
# Hooke's law and the Lame parameters


@pytest.mark.parametrize("nu", NUS)
def test_lame_parameters_reproduce_the_notes_6x6_hooke_matrix(nu):
    """sigma = lam tr(eps) I + 2 mu eps with (lam, mu) = lame_parameters(E, nu) equals the notes'
    6x6 Voigt matrix (engineering shear strains 2 eps_ij) applied to the same strain."""
    rng = np.random.default_rng(1)
    lam, mu = lame_parameters(E_PA, nu)
    for _ in range(5):
        A = 1e-3 * rng.normal(size=(3, 3))
        eps = 0.5 * (A + A.T)
        expected = naive.notes_stress(eps, E_PA, nu)
        lame_form = lam * np.trace(eps) * np.eye(3) + 2.0 * mu * eps
        np.testing.assert_allclose(lame_form, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        # softsim's own Hooke kernel with those constants
        got = np.array(hooke_stress(_tuple(eps), lam, mu)).reshape(3, 3)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        # 'linear' is exactly Hooke's law for a symmetric displacement gradient, at any size
        got = P_of("linear", np.eye(3) + eps, lam, mu)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_lame_parameters_uniaxial_stress_gives_youngs_modulus_and_poisson_ratio():
    """Invert Hooke's law for uniaxial stress sigma_11 = s: strain_11 = s/E, strain_22 = -nu s/E."""
    for nu in NUS:
        lam, mu = lame_parameters(E_PA, nu)
        # 3x3 normal block of lam tr(eps) I + 2 mu eps on diagonal strains
        K = lam * np.ones((3, 3)) + 2.0 * mu * np.eye(3)
        strain = np.linalg.solve(K, np.array([1.0, 0.0, 0.0]))
        assert strain[0] == pytest.approx(1.0 / E_PA, rel=1e-12)
        assert strain[1] == pytest.approx(-nu / E_PA, rel=1e-12, abs=1e-24)
        assert strain[2] == pytest.approx(-nu / E_PA, rel=1e-12, abs=1e-24)


@pytest.mark.parametrize("E, nu", [(0.0, 0.3), (-1.0, 0.3), (1e6, 0.5), (1e6, -1.0), (1e6, 0.7)])
def test_lame_parameters_reject_unphysical_constants(E, nu):
    with pytest.raises(ConfigError):
        lame_parameters(E, nu)


@pytest.mark.parametrize("nu", NUS)
@pytest.mark.parametrize("model", MODELS)
def test_every_model_is_hookes_law_at_small_strain_with_the_users_constants(model, nu):
    """F = I + eps G: P(F) = lam tr(e) I + 2 mu e + O(eps^2), e = eps sym(G), with the USER's
    (lam, mu) = lame_parameters(E, nu); the model is fed model_lame_parameters (neohookean must be
    remapped so that its linearisation has the user's E and nu)."""
    rng = np.random.default_rng(2)
    lam_user, mu_user = lame_parameters(E_PA, nu)
    lam, mu = model_lame_parameters(model, E_PA, nu)
    for eps in (1e-6, 1e-5):
        for _ in range(4):
            G = rng.normal(size=(3, 3))
            e = eps * 0.5 * (G + G.T)
            hooke = lam_user * np.trace(e) * np.eye(3) + 2.0 * mu_user * e
            P = P_of(model, np.eye(3) + eps * G, lam, mu)
            rel = np.linalg.norm(P - hooke) / np.linalg.norm(hooke)
            assert rel < 20.0 * eps, (model, nu, eps, rel)


@pytest.mark.parametrize("model", MODELS)
def test_energy_and_stress_vanish_at_rest(model):
    lam, mu = model_lame_parameters(model, E_PA, 0.3)
    assert abs(psi_of(model, np.eye(3), lam, mu)) < 1e-12 * E_PA
    assert np.abs(P_of(model, np.eye(3), lam, mu)).max() < 1e-12 * E_PA


@pytest.mark.parametrize("model", MODELS)
def test_small_strain_energy_is_the_hooke_energy(model):
    """Psi(I + e) = mu e:e + lam/2 tr(e)^2 + O(|e|^3) for symmetric e, with the user's lam, mu."""
    rng = np.random.default_rng(3)
    lam_user, mu_user = lame_parameters(E_PA, 0.3)
    lam, mu = model_lame_parameters(model, E_PA, 0.3)
    eps = 1e-4
    A = rng.normal(size=(3, 3))
    e = eps * 0.5 * (A + A.T)
    expected = mu_user * np.sum(e * e) + 0.5 * lam_user * np.trace(e) ** 2
    assert psi_of(model, np.eye(3) + e, lam, mu) == pytest.approx(expected, rel=20 * eps)


# ---------------------------------------------------------------------------------------------
# P = dPsi/dF


def _fd_pk1(model, F, lam, mu, h):
    P = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            Fp = F.copy()
            Fm = F.copy()
            Fp[r, c] += h
            Fm[r, c] -= h
            P[r, c] = (psi_of(model, Fp, lam, mu) - psi_of(model, Fm, lam, mu)) / (2.0 * h)
    return P


@pytest.mark.parametrize("model", MODELS)
def test_first_piola_is_the_derivative_of_the_energy_density(model):
    rng = np.random.default_rng(4)
    lam, mu = model_lame_parameters(model, E_PA, 0.3)
    states = [random_stretch(rng, 0.3) @ random_rotation(rng, 0.0) for _ in range(4)]
    if model in INVERSION_SAFE:
        # inverted: one negative singular value, clearly the smallest in magnitude
        for _ in range(3):
            U = random_rotation(rng, 0.0)
            V = random_rotation(rng, 0.0)
            states.append(U @ np.diag([1.4, 0.9, -0.4]) @ V.T)
    for F in states:
        P = P_of(model, F, lam, mu)
        P_fd = _fd_pk1(model, F, lam, mu, 1e-6)
        assert np.linalg.norm(P - P_fd) < 1e-6 * np.linalg.norm(P), (model, F)


# ---------------------------------------------------------------------------------------------
# frame indifference


@pytest.mark.parametrize("model", ROTATION_INVARIANT)
def test_rotation_invariant_models_are_frame_indifferent(model):
    """Psi(Q F) = Psi(F) and P(Q F) = Q P(F) for any rotation Q."""
    rng = np.random.default_rng(5)
    lam, mu = model_lame_parameters(model, E_PA, 0.3)
    for _ in range(5):
        F = random_stretch(rng, 0.3)
        Q = random_rotation(rng)
        P = P_of(model, F, lam, mu)
        assert psi_of(model, Q @ F, lam, mu) == pytest.approx(psi_of(model, F, lam, mu), rel=1e-10)
        np.testing.assert_allclose(P_of(model, Q @ F, lam, mu), Q @ P, rtol=0, atol=1e-10 * np.abs(P).max())


def test_linear_model_is_not_frame_indifferent():
    """Documented failure of 'linear': a rigid rotation by a large angle produces stress."""
    rng = np.random.default_rng(6)
    lam, mu = model_lame_parameters("linear", E_PA, 0.3)
    Q = random_rotation(rng)
    assert np.linalg.norm(P_of("linear", Q, lam, mu)) > 0.1 * E_PA
    assert psi_of("linear", Q, lam, mu) > 0.01 * E_PA
