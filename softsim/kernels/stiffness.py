"""The largest eigenvalue of each tet's linear-elastic stiffness, from two 3 x 3 eigenvalue problems.

For the stable time step (``integrators.stability``).  A linear tet with corner gradients ``b_a``
(a = 0..3, ``sum_a b_a = 0``) and volume ``V`` has the 12 x 12 stiffness ``K`` with

    u^T K u = V (lambda tr(H)^2 + 2 mu |sym H|^2),    H = sum_a u_a b_a^T  (3 x 3)

(Hooke's law on the constant displacement gradient ``H``).  The smallest ``|u|^2`` giving a
``H`` is ``tr(H C^-1 H^T)``, ``C = sum_a b_a b_a^T``; in the eigenbasis of ``C`` (eigenvalues
``s_1 >= s_2 >= s_3``; the form is isotropic, so the basis does not change it) the diagonal and
off-diagonal entries of ``H`` decouple:

- the diagonal gives the 3 x 3 matrix ``M = lambda sqrt(s) sqrt(s)^T + 2 mu diag(s)``,
- each pair ``H_ij, H_ji`` the eigenvalues ``mu (s_i + s_j)`` and 0,
- and the six rigid motions (H = 0, or antisymmetric) eigenvalue 0,

so ``lambda_max(K) = V max(lambda_max(M), mu (s_1 + s_2))``: two 3 x 3 symmetric eigenvalue
problems instead of a 12 x 12 one (``tests/test_stiffness.py`` checks it against
LAPACK on the assembled ``K``).
"""

import math

import numpy as np
from numba import prange

from .deformation import edge_matrix
from .jit import njit, njit_parallel
from .mat3 import mat3_cofactor, mat3_det
from .polar3 import jacobi_sweep


@njit
def symmetric3_eigenvalues(a00, a11, a22, a01, a02, a12):
    """Eigenvalues ``(largest, middle, smallest)`` of the symmetric 3 x 3 matrix with these entries:
    the diagonal after ``polar3.JACOBI_SWEEPS`` cyclic Jacobi sweeps (``polar3.jacobi_sweep``),
    accurate to round-off relative to the largest, repeated eigenvalues included (the
    trigonometric closed form lost 8 digits of the largest where the two largest coincide)."""
    A = (a00, a11, a22, a01, a02, a12)
    V = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    d0, d1, d2 = A[0], A[1], A[2]
    largest = max(d0, d1, d2)
    smallest = min(d0, d1, d2)
    return largest, max(min(d0, d1), min(max(d0, d1), d2)), smallest


@njit
def tet_stiffness_maximum(Ds, lam, mu):
    """``lambda_max`` [N/m] of the linear-elastic stiffness of the tet with edge matrix ``Ds``
    (9-tuple [m], ``deformation.edge_matrix``) and Lame parameters ``lam``, ``mu`` [Pa] (module
    docstring); inf for a flat tet (``det Ds = 0``: LAPACK's inverse refused it)."""
    det = mat3_det(Ds)
    if det == 0.0:
        return np.inf
    cof = mat3_cofactor(Ds)
    # gradient of corner a (1..3): row a - 1 of Ds^-1 = column a - 1 of cof / det; corner 0: minus their sum
    c00 = c11 = c22 = c01 = c02 = c12 = 0.0
    s0 = s1 = s2 = 0.0
    for a in range(3):
        g0, g1, g2 = cof[a], cof[3 + a], cof[6 + a]
        s0 += g0
        s1 += g1
        s2 += g2
        c00 += g0 * g0
        c11 += g1 * g1
        c22 += g2 * g2
        c01 += g0 * g1
        c02 += g0 * g2
        c12 += g1 * g2
    scale = 1.0 / (det * det)
    c00 = (c00 + s0 * s0) * scale
    c11 = (c11 + s1 * s1) * scale
    c22 = (c22 + s2 * s2) * scale
    c01 = (c01 + s0 * s1) * scale
    c02 = (c02 + s0 * s2) * scale
    c12 = (c12 + s1 * s2) * scale
    e1, e2, e3 = symmetric3_eigenvalues(c00, c11, c22, c01, c02, c12)
    r1, r2, r3 = math.sqrt(max(e1, 0.0)), math.sqrt(max(e2, 0.0)), math.sqrt(max(e3, 0.0))
    m_largest, _, _ = symmetric3_eigenvalues((lam + 2.0 * mu) * e1, (lam + 2.0 * mu) * e2, (lam + 2.0 * mu) * e3,
                                             lam * r1 * r2, lam * r1 * r3, lam * r2 * r3)
    return abs(det) / 6.0 * max(m_largest, mu * (e1 + e2))


@njit_parallel
def element_stiffness_maxima(x, tets, lam, mu):
    """``tet_stiffness_maximum`` of every tet (tet_count,) [N/m] at positions ``x`` (n, 3) [m]."""
    m = tets.shape[0]
    out = np.empty(m)
    for e in prange(m):
        out[e] = tet_stiffness_maximum(edge_matrix(x, tets, np.int64(e)), lam, mu)   # (njit_parallel)
    return out
