"""The triangular rest data (``kernels.rotated_rest``): ``R^-1`` of ``Dm = Q R`` with ``Q`` a rotation,
and the same forces as ``Dm^-1`` for the laws invariant under a turn of the rest frame, not for
small-strain ``linear`` (the check can fail)."""

import numpy as np
import pytest

from softsim.kernels.rotated_rest import triangular_rest_inverses
from softsim.materials.models import MODEL_IDS, ROTATION_INVARIANT, first_piola, model_lame_parameters


def rest_shapes(rng):
    """``Dm`` of well-shaped tets, slivers (one edge 1e-3 of the others, or nearly coplanar
    corners), tets of 1e-4 m and 1e2 m, and left-handed ones (``det Dm < 0``)."""
    shapes = [rng.normal(size=(3, 3)) for _ in range(20)]
    for _ in range(5):
        flat = rng.normal(size=(3, 3))
        flat[:, 2] = flat[:, 0] + flat[:, 1] + 1e-3 * rng.normal(size=3)
        shapes.append(flat)
        thin = rng.normal(size=(3, 3))
        thin[:, 1] *= 1e-3
        shapes.append(thin)
    shapes += [1e-4 * rng.normal(size=(3, 3)), 1e2 * rng.normal(size=(3, 3))]
    shapes = np.array(shapes)
    shapes[::3, :, [0, 1]] = shapes[::3, :, [1, 0]]          # flip every third one's orientation
    return shapes


def test_r_inverse_is_upper_triangular_and_dm_times_it_a_rotation():
    rng = np.random.default_rng(11)
    Dm = rest_shapes(rng)
    a = triangular_rest_inverses(np.linalg.inv(Dm))
    A = np.zeros_like(Dm)
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 1, 1], A[:, 1, 2], A[:, 2, 2] = a.T
    assert (A[:, 0, 0] > 0).all() and (A[:, 1, 1] > 0).all()
    assert (np.sign(A[:, 2, 2]) == np.sign(np.linalg.det(Dm))).all()
    Q = Dm @ A                                              # Dm = Q R  ->  Q = Dm R^-1
    cond = np.linalg.cond(Dm)
    assert (np.abs(np.swapaxes(Q, 1, 2) @ Q - np.eye(3)).max(axis=(1, 2)) < 1e-15 * cond ** 2).all()
    assert np.allclose(np.linalg.det(Q), 1.0, atol=1e-12)
    # what the forces need: R^-1 R^-T = Dm^-1 Dm^-T, to round-off of its scale
    B = np.linalg.inv(Dm)
    G, G_r = B @ np.swapaxes(B, 1, 2), A @ np.swapaxes(A, 1, 2)
    assert (np.abs(G_r - G).max(axis=(1, 2)) < 1e-14 * cond * np.abs(G).max(axis=(1, 2))).all()


@pytest.mark.parametrize("model", tuple(MODEL_IDS))
def test_forces_from_r_inverse_are_the_forces_from_dm_inverse_only_for_rotation_invariant_laws(model):
    """``-V0 P(Ds R^-1) R^-T`` against ``-V0 P(Ds Dm^-1) Dm^-T`` on randomly deformed tets (strain
    ~0.3): equal to round-off for StVK, neo-Hookean and corotated; for ``linear`` they differ at
    the size of the forces, which is why ``linear`` keeps ``Dm^-1``."""
    rng = np.random.default_rng(12)
    lam, mu = model_lame_parameters(model, 1e6, 0.3)
    worst = 0.0
    for Dm in rest_shapes(rng)[:20]:
        if np.linalg.det(Dm) < 0:
            continue
        B = np.linalg.inv(Dm)
        a = triangular_rest_inverses(B[None])[0]
        A = np.array([[a[0], a[1], a[2]], [0.0, a[3], a[4]], [0.0, 0.0, a[5]]])
        Ds = (np.eye(3) + 0.3 * rng.normal(size=(3, 3))) @ Dm
        if np.linalg.det(Ds) <= 0:
            continue
        P = np.reshape(first_piola(MODEL_IDS[model], tuple((Ds @ B).ravel()), lam, mu), (3, 3))
        P_r = np.reshape(first_piola(MODEL_IDS[model], tuple((Ds @ A).ravel()), lam, mu), (3, 3))
        H, H_r = P @ B.T, P_r @ A.T
        worst = max(worst, np.abs(H_r - H).max() / np.abs(H).max())
    if model in ROTATION_INVARIANT:
        assert worst < 1e-12
    else:
        assert worst > 1e-2
