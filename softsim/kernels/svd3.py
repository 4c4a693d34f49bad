"""Inversion-aware singular value decomposition of a 3x3 matrix.

``F = U diag(s) V^T`` with ``U`` and ``V`` proper rotations (det = +1).  A reflection in ``F``
(det F < 0, an inverted element) is moved into the smallest singular value, which becomes
negative (Irving, Teran & Fedkiw 2004, "Invertible finite elements for robust simulation of large
deformation").  ``R = U V^T`` is then the rotation that maximises ``tr(R^T F)`` over SO(3), and
an inverted element sees a restoring force instead of a mirrored rest state.

Method: cyclic Jacobi on ``C = F^T F`` gives ``V`` and ``s^2``; the columns of ``U`` follow from
``F V``, with the third one as the cross product of the first two so that ``det U = +1``.

The material laws no longer call this (arrays per call, scalar code): they use ``polar3``, the
same method on scalars.  Kept as the array-based version that ``tests/test_kernels.py`` checks.
"""

import math

import numpy as np

from .jit import njit

_JACOBI_SWEEPS = 30


@njit
def _symmetric_eigen(C):
    """Eigenvalues (3,) descending and eigenvectors (3, 3) as columns of symmetric ``C`` (3, 3)."""
    A = C.copy()
    V = np.eye(3)
    scale = abs(A[0, 0]) + abs(A[1, 1]) + abs(A[2, 2]) + 1e-300
    for _ in range(_JACOBI_SWEEPS):
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        if off <= (1e-17 * scale) ** 2:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = A[p, q]
            if apq == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            if theta < 0.0:
                t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            # A <- J^T A J with J the plane rotation (c, s) in (p, q); V <- V J
            for k in range(3):
                akp = A[k, p]
                akq = A[k, q]
                A[k, p] = c * akp - s * akq
                A[k, q] = s * akp + c * akq
            for k in range(3):
                apk = A[p, k]
                aqk = A[q, k]
                A[p, k] = c * apk - s * aqk
                A[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp = V[k, p]
                vkq = V[k, q]
                V[k, p] = c * vkp - s * vkq
                V[k, q] = s * vkp + c * vkq
    w = np.array([A[0, 0], A[1, 1], A[2, 2]])
    order = np.argsort(-w)
    return w[order], V[:, order]


@njit
def _dot(a, b):
    """``a . b`` for two (3,) vectors without BLAS."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit
def _mat_vec(A, b):
    """``A @ b`` for A (3, 3) and b (3,) without BLAS (Numba's ``@`` needs SciPy)."""
    out = np.empty(3)
    for r in range(3):
        out[r] = A[r, 0] * b[0] + A[r, 1] * b[1] + A[r, 2] * b[2]
    return out


@njit
def _orthonormal_to(u):
    """A unit vector orthogonal to the unit vector ``u`` (3,)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    w = a - _dot(a, u) * u
    return w / math.sqrt(_dot(w, w))


@njit
def svd3_inversion_aware(F):
    """``(U, s, V)`` with ``F = U diag(s) V^T``, det U = det V = +1, ``s[0] >= s[1] >= |s[2]|``.

    F: 9-tuple (row-major).  U, V: (3, 3) arrays; s: (3,) array, s[2] < 0 iff det F < 0.
    """
    Fa = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            Fa[r, c] = F[3 * r + c]
    C = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            C[r, c] = Fa[0, r] * Fa[0, c] + Fa[1, r] * Fa[1, c] + Fa[2, r] * Fa[2, c]
    _, V = _symmetric_eigen(C)
    if _dot(np.cross(V[:, 0], V[:, 1]), V[:, 2]) < 0.0:
        V[:, 2] = -V[:, 2]
    U = np.empty((3, 3))
    f0 = _mat_vec(Fa, V[:, 0])
    n0 = math.sqrt(_dot(f0, f0))
    u0 = f0 / n0 if n0 > 0.0 else V[:, 0].copy()
    f1 = _mat_vec(Fa, V[:, 1])
    w1 = f1 - _dot(f1, u0) * u0
    n1 = math.sqrt(_dot(w1, w1))
    u1 = w1 / n1 if n1 > 1e-14 * (n0 + 1e-300) else _orthonormal_to(u0)
    u2 = np.cross(u0, u1)
    U[:, 0] = u0
    U[:, 1] = u1
    U[:, 2] = u2
    s = np.empty(3)
    s[0] = _dot(u0, f0)
    s[1] = _dot(u1, f1)
    s[2] = _dot(u2, _mat_vec(Fa, V[:, 2]))
    return U, s, V
