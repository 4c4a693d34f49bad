"""The closed-form largest eigenvalue of a tet's stiffness (``kernels.stiffness``) against LAPACK's
on the assembled 12 x 12 matrix, and the 3 x 3 eigenvalues against NumPy's."""

import numpy as np
import pytest

from softsim.kernels.stiffness import element_stiffness_maxima, symmetric3_eigenvalues


def assembled_maxima(x, tets, lam, mu):
    """``eigvalsh`` of ``K_ab = V (lam b_a b_b^T + mu (b_a . b_b) I + mu b_b b_a^T)`` per tet."""
    X = x[tets]
    Ds = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))
    volume = np.abs(np.linalg.det(Ds)) / 6.0
    G = np.linalg.inv(Ds)
    b = np.concatenate([-G.sum(axis=1, keepdims=True), G], axis=1)
    dots = np.einsum("kai,kbi->kab", b, b)
    K = (lam * np.einsum("kai,kbj->kaibj", b, b)
         + mu * dots[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
         + mu * np.einsum("kbi,kaj->kaibj", b, b))
    K = K.reshape(-1, 12, 12) * volume[:, None, None]
    return np.linalg.eigvalsh(K)[:, -1]


def random_tets(rng, count, flatness=1.0):
    """``count`` random tets (4 count vertices), squashed along z by ``flatness``, some inverted."""
    x = rng.normal(size=(4 * count, 3)) * np.array([1.0, 0.3, flatness])
    return x, np.arange(4 * count).reshape(count, 4)


@pytest.mark.parametrize("lam, mu", [(2.0e9, 1.0e9), (-0.4e6, 1.0e6), (4.9e9, 0.1e9), (0.0, 3.0)])
@pytest.mark.parametrize("flatness", [1.0, 1e-3])
def test_closed_form_matches_the_assembled_stiffness(lam, mu, flatness):
    """Random, near-flat and inverted tets; Lame parameters from steel to a negative Poisson ratio
    and near incompressibility: the same largest eigenvalue to 1e-10 of itself."""
    x, tets = random_tets(np.random.default_rng(7), 2000, flatness)
    closed = element_stiffness_maxima(x, tets, lam, mu)
    reference = assembled_maxima(x, tets, lam, mu)
    np.testing.assert_allclose(closed, reference, rtol=1e-10, atol=0)


def test_a_regular_tet_and_a_flat_one():
    """Scaling: lambda_max is proportional to the edge length (V |b|^2 ~ h); a flat tet is inf."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tets = np.array([[0, 1, 2, 3]])
    one = element_stiffness_maxima(x, tets, 1.0, 1.0)[0]
    assert element_stiffness_maxima(2.0 * x, tets, 1.0, 1.0)[0] == pytest.approx(2.0 * one, rel=1e-14)
    assert one == pytest.approx(assembled_maxima(x, tets, 1.0, 1.0)[0], rel=1e-12)
    flat = x.copy()
    flat[3] = [0.3, 0.3, 0.0]
    assert element_stiffness_maxima(flat, tets, 1.0, 1.0)[0] == np.inf


def test_symmetric3_eigenvalues_match_numpy():
    """Random symmetric matrices, diagonal ones, repeated eigenvalues and a multiple of I."""
    rng = np.random.default_rng(1)
    cases = [a + a.T for a in rng.normal(size=(200, 3, 3))]
    cases += [np.diag(rng.normal(size=3)) for _ in range(20)]
    cases += [np.diag([2.0, 2.0, -1.0]), np.diag([1.0, 3.0, 3.0]), 5.0 * np.eye(3)]
    for a in cases:
        got = symmetric3_eigenvalues(a[0, 0], a[1, 1], a[2, 2], a[0, 1], a[0, 2], a[1, 2])
        expected = np.linalg.eigvalsh(a)[::-1]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
