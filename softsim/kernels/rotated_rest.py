"""The rest data of a tet in a rotated rest frame: ``R^-1`` of ``Dm = Q R``, six numbers instead of nine.

With ``Dm = Q R`` (``Q`` a rotation, ``R`` upper triangular), ``Dm^-1 = R^-1 Q^T`` and
``F = Ds Dm^-1 = F_r Q^T`` where ``F_r = Ds R^-1``.  A law that is objective and isotropic
(StVK, neo-Hookean, corotated; not small-strain ``linear``) has ``psi(F Q^T) = psi(F)`` and
``P(F Q^T) = P(F) Q^T``, so the corner forces ``H = -V0 P(F) Dm^-T = -V0 P(F_r) Q^T Q R^-T
= -V0 P(F_r) R^-T`` need only the upper triangle of ``R^-1`` (Sifakis & Barbic 2012, section 4.3,
with the rest frame turned by ``Q``).
``F_r`` has the same ``det`` and stretches as ``F``.  Forming ``F_r`` and ``H`` then takes 18
multiply-adds each instead of 27, and a tet's stored rest data 7 numbers instead of 10.

``R`` comes from Gram-Schmidt on the columns (edges) of ``Dm``, with ``r00, r11 > 0`` and ``r22``
of the sign of ``det Dm``, so that ``Q`` is a rotation (``det Q = +1``) also for a tet whose rest
shape is inverted.  Its accuracy does not rest on ``Q``'s orthogonality: the forces need
``R^-1 R^-T = Dm^-1 Dm^-T``, which Gram-Schmidt's ``R`` meets to round-off (``tests``).
"""

import math

import numpy as np

from .jit import njit, njit_inline
from .mat3 import mat3_cofactor_inline

TRIANGULAR_ENTRIES = 6     # (R^-1)_00, _01, _02, _11, _12, _22


@njit_inline
def triangular_rest_inverse(D):
    """``(a00, a01, a02, a11, a12, a22, det)``: the upper triangle of ``R^-1`` [1/m] of ``Dm = Q R``
    (``D``: ``Dm`` as a 9-tuple, row-major, columns the edges ``X_c - X_0`` [m]) and ``det Dm``
    [m^3].  Gram-Schmidt: two square roots and two divisions (one of them, of ``r00 r11 det``,
    for the three reciprocals the result needs)."""
    c00, c01, c02 = D[0], D[3], D[6]           # the columns of Dm
    c10, c11, c12 = D[1], D[4], D[7]
    c20, c21, c22 = D[2], D[5], D[8]
    cof = mat3_cofactor_inline(D)
    det = D[0] * cof[0] + D[1] * cof[1] + D[2] * cof[2]
    r00 = math.sqrt(c00 * c00 + c01 * c01 + c02 * c02)
    d01 = c00 * c10 + c01 * c11 + c02 * c12    # c0 . c1 = r00 r01
    d02 = c00 * c20 + c01 * c21 + c02 * c22    # c0 . c2 = r00 r02
    k = d01 / (r00 * r00)                      # w1 = c1 - (c0 . c1 / |c0|^2) c0, orthogonal to c0
    w0, w1, w2 = c10 - k * c00, c11 - k * c01, c12 - k * c02
    r11 = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    e12 = w0 * c20 + w1 * c21 + w2 * c22       # w1 . c2 = r11 r12
    t = 1.0 / (r00 * r11 * det)
    inv_r00 = r11 * det * t
    inv_r11 = r00 * det * t
    inv_det = r00 * r11 * t
    r01 = d01 * inv_r00
    r02 = d02 * inv_r00
    r12 = e12 * inv_r11
    a22 = r00 * r11 * inv_det                  # 1 / r22, r22 = det / (r00 r11)
    return (inv_r00, -r01 * inv_r00 * inv_r11, (r01 * r12 - r02 * r11) * inv_det,
            inv_r11, -r12 * inv_r11 * a22, a22, det)


@njit
def triangular_rest_inverses(Dm_inv):
    """``triangular_rest_inverse`` of every tet from its ``Dm^-1`` (m, 3, 3) [1/m]: (m, 6) [1/m],
    columns ``TRIANGULAR_ENTRIES``.  Once per mesh, on one thread (``kernels.jit.njit_parallel``)."""
    m = Dm_inv.shape[0]
    out = np.empty((m, TRIANGULAR_ENTRIES))
    for e in range(m):
        B = (Dm_inv[e, 0, 0], Dm_inv[e, 0, 1], Dm_inv[e, 0, 2], Dm_inv[e, 1, 0], Dm_inv[e, 1, 1],
             Dm_inv[e, 1, 2], Dm_inv[e, 2, 0], Dm_inv[e, 2, 1], Dm_inv[e, 2, 2])
        cof = mat3_cofactor_inline(B)
        inv_det = 1.0 / (B[0] * cof[0] + B[1] * cof[1] + B[2] * cof[2])
        Dm = (cof[0] * inv_det, cof[3] * inv_det, cof[6] * inv_det, cof[1] * inv_det, cof[4] * inv_det,
              cof[7] * inv_det, cof[2] * inv_det, cof[5] * inv_det, cof[8] * inv_det)
        a = triangular_rest_inverse(Dm)
        for k in range(TRIANGULAR_ENTRIES):
            out[e, k] = a[k]
    return out
