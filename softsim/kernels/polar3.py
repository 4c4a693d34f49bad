"""The rotation of the corotated model for one 3x3 ``F``, on scalars: no arrays, no calls but
inlined ones (``kernels.mat3``'s ``*_inline``), no data-dependent branches within a stage, so that
the lane loops of ``kernels.blocked`` compile to packed SIMD code.

The rotation is that of the inversion-aware SVD (Irving, Teran & Fedkiw 2004): ``F = U diag(s)
V^T`` with ``U``, ``V`` proper rotations and a reflection in ``F`` (det F < 0, an inverted element)
moved into the smallest singular value, so that ``R = U V^T`` has det +1 and maximises
``tr(R^T F)`` over SO(3).  Two ways to it:

- ``newton_polar_rotation``: Newton's iteration ``X <- (X + X^-T) / 2`` from ``X = F`` (Higham
  1986), which converges to the polar factor.  Where det F > 0 that is ``R``; the norm of the
  iterate before the last bounds the last one's error (``newton_polar_certifies``).
  ``NEWTON_FIRST_STEPS`` steps (``newton_polar_start``) settle the tets of small strain; the others
  take two more (``newton_polar_finish``, ``NEWTON_ITERATIONS`` in all).  Tets of smaller strains
  settle in three or two first steps (``newton_polar_start_three``, ``newton_polar_start_two``):
  the lane loop takes those where the block's last step showed them enough.  About 70 flops a
  step and no division (the iterate is carried scaled, the scale divided out once at the end):
  the fast path, for the tets of a simulation that are neither inverted, nearly flat nor
  stretched by more than about 3x.
- ``jacobi_rotation_and_stretch``: a Jacobi SVD without arrays or branches (after
  McAdams et al. 2011, "Computing the singular value decomposition of 3x3 matrices with minimal
  branching and elementary floating point operations"):

  1. ``JACOBI_SWEEPS`` cyclic sweeps of exact Jacobi rotations on ``C = F^T F``, accumulated into
     ``V`` (a proper rotation by construction);
  2. ``B = F V``, its columns sorted by decreasing norm (a swap negates one column: det V stays
     +1), so that the smallest singular value comes last;
  3. ``U`` by Gram-Schmidt on the columns of ``B``, ``u2 = u0 x u1`` (det U = +1); ``s_k = u_k .
     b_k``, so ``s_2 < 0`` exactly when det F < 0.

  Any F: degenerate ones (rank 2, rank 1, zero) get fallbacks (``u0 = v0`` when
  ``b0 = 0``; ``u1`` a unit vector orthogonal to ``u0`` when ``b1`` is parallel to it), a finite
  proper rotation.  About 8 times the cost of the Newton path.

``polar_rotation`` takes the Newton result where it converged and the Jacobi one elsewhere, per
tet; ``blocked.corotated_block`` makes the same choice per lane.  The functions are always inlined
into their callers (``njit_inline``); ``*_jit`` / ``jacobi_polar_rotation`` /
``polar_rotation`` are ordinary jitted functions.

A matrix is a row-major 9-tuple, as in ``kernels.mat3``; F is dimensionless (R has no unit, ``s``
that of F).
"""

import math

from .jit import njit, njit_inline
from .mat3 import mat3_add_scaled_inline, mat3_cofactor_inline, mat3_ddot_inline, mat3_scale_inline

# Cyclic Jacobi sweeps (3 rotations each) on F^T F.  Measured on 10^6 F per family (random normal;
# near a rotation; large rotations with strain 0.3; singular values spread by up to 1e3, inverted
# or not; nearly repeated; nearly flat, s2 from 1e-12 to 1e-4): the largest error of R against
# numpy.linalg.svd, times the conditioning (s1 + s2) / s0, is 1e10-1e11 eps after 3 sweeps and
# 40-450 eps (rounding, the same as with 5 or 8 sweeps and as the earlier allocating SVD's 30-270)
# after 4.
JACOBI_SWEEPS = 4          # documents the code: the sweeps are written out (jacobi_eigenvectors)

# Newton's polar iteration from X = F: this many steps at most (written out in newton_polar_start
# and newton_polar_finish).
# Measured share of F = Q (I + a G) (Q a random rotation, G standard normal) that fails the
# convergence test, 2 x 10^5 samples:
#     a          0.05     0.1      0.2      0.3 (0.6 % of them inverted)
#     5 steps    0        1e-5     6e-2     3e-1
#     6 steps    0        0        2e-3     7e-2
#     7 steps    0        0        2e-4     2e-2
# Where it passes, R is within 1e-14 of numpy.linalg.svd's.  A step costs about a tenth of the
# Jacobi fallback; 6 steps keep that fallback rare at strains up to about 0.2.  (Measured with the
# earlier test on the last step's length; the norm test, ``newton_polar_certifies``, fails 0, 0,
# 1.8e-3 and 6.5e-2 of 10^5 samples after 6 steps, 2.6e-4, 0.22, 0.89 and 0.98 after 4.)
NEWTON_ITERATIONS = 6      # documents the code: the steps are written out (newton_polar_finish)
# The first stage stops after this many steps where they converged (``newton_polar_start``): share
# of F = Q (I + a G) accepted after 4 steps (2 x 10^4 samples each): all up to a = 0.02, 99.98 % at
# 0.05, 79 % at 0.1; the rest go on to 6 steps.
NEWTON_FIRST_STEPS = 4     # documents the code (newton_polar_start)
# The fewest first steps a block of small strains takes (newton_polar_start_two; a block's count
# adapts between the two: kernels.blocked.next_first_steps).
NEWTON_MIN_FIRST_STEPS = 2
# An iterate ``X_k`` after the first step certifies the next, ``X_k+1``, when ``|X_k|^2 - 3``
# (Frobenius) is at most this: ``X_k+1`` then lies within ``NEWTON_ROTATION_ERROR`` of the polar
# factor (``newton_polar_certifies``).  A stage accepts its last iterate when the one before
# certifies it, and a block's lanes are ``overdone`` (one first step fewer would do) when the
# iterate before that certifies its successor: ``kernels.blocked.corotated_block`` chooses each
# block's first steps (2, 3 or 4) from its last step.  Newton converges quadratically, so a step
# fewer needs an iterate about the square of this; a converged iterate's own rounding puts about
# 1e-15 into ``|X|^2 - 3``.
NEWTON_NORM_TOLERANCE = 2e-7
NEWTON_ROTATION_ERROR = NEWTON_NORM_TOLERANCE ** 2 / 8     # 5e-15
# The iterates are carried scaled, ``Z_k = c_k X_k`` (``newton_polar_step``), with ``c_4 = 2^85 d_0^64
# d_1^16 d_2^4 d_3`` (``d_k = det X_k``, ``d_0 = det F``), which only sets the exponent of Z's
# entries; products within a step reach about ``c_k``.  A result is accepted only while ``c``
# stays within these bounds, where nothing has overflowed or fallen below the normal numbers, the
# test's ``c^2`` and the result's ``1 / c`` included.  They lie beyond where the first four steps
# converge (F = a Q: c_4 from 2^23 to 2^147 for a from 0.8 to 1.25), so they decline only results
# that could not have been accepted anyway; the last two steps start again from ``X_4`` at c = 1.
NEWTON_SCALE_MIN = 2.0 ** -500
NEWTON_SCALE_MAX = 2.0 ** 500

# u1 falls back to a unit vector orthogonal to u0 when |b1 - (b1 . u0) u0| is below this times |b0|
# (b1 parallel to b0: F of rank 1).
RANK_ONE_TOLERANCE = 1e-14


@njit_inline
def jacobi_plane_rotation(app, aqq, apq, arp, arq, vp0, vp1, vp2, vq0, vq1, vq2):
    """One Jacobi rotation ``A <- J^T A J``, ``V <- V J`` in the plane (p, q) that zeroes ``a_pq``.

    A symmetric: its entries ``a_pp, a_qq, a_pq`` and ``a_rp, a_rq`` (r the third index); ``vp``,
    ``vq``: columns p and q of ``V``.  ``J`` has ``J_pp = J_qq = c``, ``J_pq = s``, ``J_qp = -s``
    with ``t = s / c`` the smaller root of ``t^2 + 2 theta t - 1 = 0``, ``theta = (a_qq - a_pp) / (2
    a_pq)`` (rotation angle at most pi/4).  No rotation when ``a_pq = 0`` and ``a_pp = a_qq``.
    Returns ``(a_pp, a_qq, a_rp, a_rq, vp0, vp1, vp2, vq0, vq1, vq2)``, ``a_pq`` being now zero.
    """
    d = aqq - app
    e = 2.0 * apq
    D = abs(d) + math.sqrt(d * d + e * e)           # t = sign(d) e / D,  sign(0) = +1
    n = math.sqrt(D * D + e * e)
    inv = 1.0 / n if n > 0.0 else 0.0
    c = D * inv if n > 0.0 else 1.0
    s = (e if d >= 0.0 else -e) * inv
    cc = c * c
    ss = s * s
    cs2 = 2.0 * c * s * apq
    return (cc * app - cs2 + ss * aqq,
            ss * app + cs2 + cc * aqq,
            c * arp - s * arq,
            s * arp + c * arq,
            c * vp0 - s * vq0, c * vp1 - s * vq1, c * vp2 - s * vq2,
            s * vp0 + c * vq0, s * vp1 + c * vq1, s * vp2 + c * vq2)


@njit_inline
def jacobi_sweep(A, V):
    """One cyclic sweep, planes (0, 1), (0, 2), (1, 2).  A: ``(a00, a11, a22, a01, a02, a12)``;
    V: the 9-tuple of the accumulated rotation (row-major).  Returns the updated ``(A, V)``."""
    a00, a11, a22, a01, a02, a12 = A
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = V
    # (p, q, r) = (0, 1, 2)
    a00, a11, a02, a12, v00, v10, v20, v01, v11, v21 = jacobi_plane_rotation(
        a00, a11, a01, a02, a12, v00, v10, v20, v01, v11, v21)
    a01 = 0.0
    # (p, q, r) = (0, 2, 1)
    a00, a22, a01, a12, v00, v10, v20, v02, v12, v22 = jacobi_plane_rotation(
        a00, a22, a02, a01, a12, v00, v10, v20, v02, v12, v22)
    a02 = 0.0
    # (p, q, r) = (1, 2, 0)
    a11, a22, a01, a02, v01, v11, v21, v02, v12, v22 = jacobi_plane_rotation(
        a11, a22, a12, a01, a02, v01, v11, v21, v02, v12, v22)
    a12 = 0.0
    return (a00, a11, a22, a01, a02, a12), (v00, v01, v02, v10, v11, v12, v20, v21, v22)


@njit_inline
def sort_pair(bi, bj, vi, vj, mi, mj):
    """Columns i < j of ``B`` and ``V`` (3-tuples) and ``|b|^2``: swapped, one negated (det V stays
    +1), when ``mi < mj``.  Returns ``(bi, bj, vi, vj, mi, mj)``."""
    swap = mi < mj
    return ((bj if swap else bi), (
        (-bi[0] if swap else bj[0]), (-bi[1] if swap else bj[1]), (-bi[2] if swap else bj[2])),
        (vj if swap else vi), (
        (-vi[0] if swap else vj[0]), (-vi[1] if swap else vj[1]), (-vi[2] if swap else vj[2])),
        (mj if swap else mi), (mi if swap else mj))


@njit_inline
def jacobi_eigenvectors(F):
    """The eigenvectors of ``F^T F`` as the columns of a proper rotation ``V`` (9-tuple, row-major),
    after ``JACOBI_SWEEPS`` cyclic Jacobi sweeps, in no particular order.  F: 9-tuple."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    A = (f00 * f00 + f10 * f10 + f20 * f20,
         f01 * f01 + f11 * f11 + f21 * f21,
         f02 * f02 + f12 * f12 + f22 * f22,
         f00 * f01 + f10 * f11 + f20 * f21,
         f00 * f02 + f10 * f12 + f20 * f22,
         f01 * f02 + f11 * f12 + f21 * f22)
    V = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    # JACOBI_SWEEPS sweeps, written out: a loop inside the lane loop would keep it scalar
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    A, V = jacobi_sweep(A, V)
    return V


@njit_inline
def rotation_from_eigenvectors(F, V):
    """``(R, s0, s1, s2)`` of ``rotation_and_stretch`` from ``F`` and the eigenvectors ``V`` of
    ``F^T F`` (columns of a proper rotation, any order): steps 2 and 3 of the module docstring."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = V
    v0 = (v00, v10, v20)
    v1 = (v01, v11, v21)
    v2 = (v02, v12, v22)
    b0 = (f00 * v00 + f01 * v10 + f02 * v20, f10 * v00 + f11 * v10 + f12 * v20, f20 * v00 + f21 * v10 + f22 * v20)
    b1 = (f00 * v01 + f01 * v11 + f02 * v21, f10 * v01 + f11 * v11 + f12 * v21, f20 * v01 + f21 * v11 + f22 * v21)
    b2 = (f00 * v02 + f01 * v12 + f02 * v22, f10 * v02 + f11 * v12 + f12 * v22, f20 * v02 + f21 * v12 + f22 * v22)
    m0 = b0[0] * b0[0] + b0[1] * b0[1] + b0[2] * b0[2]
    m1 = b1[0] * b1[0] + b1[1] * b1[1] + b1[2] * b1[2]
    m2 = b2[0] * b2[0] + b2[1] * b2[1] + b2[2] * b2[2]
    # sorting network (0, 1), (0, 2), (1, 2): decreasing |b|
    b0, b1, v0, v1, m0, m1 = sort_pair(b0, b1, v0, v1, m0, m1)
    b0, b2, v0, v2, m0, m2 = sort_pair(b0, b2, v0, v2, m0, m2)
    b1, b2, v1, v2, m1, m2 = sort_pair(b1, b2, v1, v2, m1, m2)
    # U by Gram-Schmidt, u2 = u0 x u1
    n0 = math.sqrt(m0)
    r0 = 1.0 / n0 if n0 > 0.0 else 0.0
    u00 = b0[0] * r0 if n0 > 0.0 else v0[0]
    u01 = b0[1] * r0 if n0 > 0.0 else v0[1]
    u02 = b0[2] * r0 if n0 > 0.0 else v0[2]
    p = b1[0] * u00 + b1[1] * u01 + b1[2] * u02
    w0 = b1[0] - p * u00
    w1 = b1[1] - p * u01
    w2 = b1[2] - p * u02
    n1 = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    # rank 1 (b1 parallel to u0): e_x, or e_y when u0 is near e_x, minus its component along u0
    rank_one = not (n1 > RANK_ONE_TOLERANCE * (n0 + 1e-300))
    near_x = abs(u00) >= 0.9
    q = u01 if near_x else u00
    y0 = (0.0 if near_x else 1.0) - q * u00 if rank_one else w0
    y1 = (1.0 if near_x else 0.0) - q * u01 if rank_one else w1
    y2 = -q * u02 if rank_one else w2
    r1 = 1.0 / math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    u10 = y0 * r1
    u11 = y1 * r1
    u12 = y2 * r1
    u20 = u01 * u12 - u02 * u11
    u21 = u02 * u10 - u00 * u12
    u22 = u00 * u11 - u01 * u10
    s0 = u00 * b0[0] + u01 * b0[1] + u02 * b0[2]
    s1 = u10 * b1[0] + u11 * b1[1] + u12 * b1[2]
    s2 = u20 * b2[0] + u21 * b2[1] + u22 * b2[2]
    R = (u00 * v0[0] + u10 * v1[0] + u20 * v2[0],
         u00 * v0[1] + u10 * v1[1] + u20 * v2[1],
         u00 * v0[2] + u10 * v1[2] + u20 * v2[2],
         u01 * v0[0] + u11 * v1[0] + u21 * v2[0],
         u01 * v0[1] + u11 * v1[1] + u21 * v2[1],
         u01 * v0[2] + u11 * v1[2] + u21 * v2[2],
         u02 * v0[0] + u12 * v1[0] + u22 * v2[0],
         u02 * v0[1] + u12 * v1[1] + u22 * v2[1],
         u02 * v0[2] + u12 * v1[2] + u22 * v2[2])
    return R, s0, s1, s2


@njit_inline
def jacobi_rotation_and_stretch(F):
    """``(R, s0, s1, s2)``: the rotation ``R = U V^T`` (9-tuple, det +1) of the inversion-aware SVD
    ``F = U diag(s) V^T``, and the signed singular values, ``s0 >= s1 >= |s2|``, ``s2 < 0`` iff
    det F < 0.  Any F (9-tuple, row-major): inverted, flat and zero ones included."""
    return rotation_from_eigenvectors(F, jacobi_eigenvectors(F))


# ---------------------------------------------------------------------------------------------
# fast path: Newton's iteration for the polar factor


@njit_inline
def newton_polar_step(Z, c):
    """``(det Z Z + c^2 cof(Z), 2 c det Z, det Z)``: a step of Newton's iteration ``X <- (X +
    X^-T) / 2`` for the polar factor without a division, carried on ``Z = c X`` (9-tuple, scale).

    With ``cof(Z) = c^2 cof(X)`` and ``det Z = c^3 det X`` the result is ``c^4 det X (X + X^-T) =
    c' X'``, ``c' = 2 c det Z``: the next iterate and its scale.  Dividing by ``det`` at every step,
    as ``X^-T = cof(X) / det X`` does, put a division's latency (about 20 cycles) on the chain of
    dependent operations of each step; the lane loop waited on it.  The scale is divided out once,
    at the end (``newton_polar_settle``).  Z of det 0 gives the zero matrix."""
    C = mat3_cofactor_inline(Z)
    det = Z[0] * C[0] + Z[1] * C[1] + Z[2] * C[2]
    return mat3_add_scaled_inline(mat3_scale_inline(C, c * c), Z, det), 2.0 * c * det, det


@njit_inline
def newton_polar_certifies(Z, c):
    """Whether the next Newton step from ``X_k = Z / c`` (9-tuple, scale; ``k >= 1``, det F > 0)
    lands within ``NEWTON_ROTATION_ERROR`` of the polar factor ``R`` (Frobenius): ``|X_k|^2 - 3 <=
    NEWTON_NORM_TOLERANCE``, tested as ``Z : Z <= (3 + tolerance) c^2`` with ``c`` within
    ``[NEWTON_SCALE_MIN, NEWTON_SCALE_MAX]`` (so that ``c^2`` neither overflows nor falls below the
    normal numbers; a NaN or an overflow in Z fails the test).

    A bound, not an estimate.  With ``F = U diag(s) V^T`` (U, V rotations, ``s_i > 0``) every
    iterate is ``U diag(s_k) V^T``, ``s_k+1 = (s_k + 1 / s_k) / 2``, so ``s_k >= 1`` after the first
    step and ``s_k+1 - 1 = (s_k - 1)^2 / (2 s_k) <= (s_k - 1)^2 / 2``.  With ``(s - 1)^2 = (s^2 -
    1)^2 / (s + 1)^2 <= (s^2 - 1)^2 / 4``: ``|X_k+1 - R| <= sum(s_k+1 - 1) <= sum((s_k^2 - 1)^2) / 8
    <= (sum(s_k^2 - 1))^2 / 8 = (|X_k|^2 - 3)^2 / 8``.  Not for ``X_0 = F``, whose singular values
    may lie below 1."""
    in_range = c >= NEWTON_SCALE_MIN and c <= NEWTON_SCALE_MAX
    return in_range and mat3_ddot_inline(Z, Z) <= (3.0 + NEWTON_NORM_TOLERANCE) * (c * c)


@njit_inline
def newton_polar_settle(Z, c):
    """``(Z, inv, det, converged)``: the last two Newton steps of a stage from ``Z = c X_k``
    (``det = det Z``, of the input), ``X_k+2 = inv Z``, accepted (``converged``) when ``X_k+1``
    certifies ``X_k+2`` (``newton_polar_certifies``) and ``c`` lies within ``[NEWTON_SCALE_MIN,
    NEWTON_SCALE_MAX]``, where ``inv`` is a normal number.  Every stage ends with it.  ``X_k+2`` is
    left to the caller: the lane loop of ``kernels.blocked.corotated_block`` folds ``inv`` into the
    stress instead.

    The test reads ``X_k+1`` alone and is done before the last step: it replaced one on the last
    step's length, ``|X_k+2 - X_k+1|``, which had to keep both iterates and took 10 more multiplies
    or multiply-adds."""
    W, b, det = newton_polar_step(Z, c)             # W = b X_k+1
    certified = newton_polar_certifies(W, b)
    Z, c, _ = newton_polar_step(W, b)               # Z = c X_k+2
    converged = certified and c >= NEWTON_SCALE_MIN and c <= NEWTON_SCALE_MAX
    return Z, 1.0 / c, det, converged


@njit_inline
def newton_polar_start(F):
    """``(Z, inv, det, converged, overdone)``: the first ``NEWTON_FIRST_STEPS`` steps of Newton's
    polar iteration from ``X = F``, ``X_4 = inv Z``, accepted (``converged``) when det F > 0 and
    ``newton_polar_settle`` accepts it: the tets of a small strain; ``overdone`` when ``X_2``
    certifies ``X_3`` (three steps would have been accepted).  ``newton_polar_finish`` goes on from
    ``X_4`` and ``det = det F``."""
    Z, c, det = newton_polar_step(F, 1.0)
    Z, c, _ = newton_polar_step(Z, c)
    overdone = newton_polar_certifies(Z, c)
    Z, inv, _, converged = newton_polar_settle(Z, c)
    return Z, inv, det, det > 0.0 and converged, det > 0.0 and overdone


@njit_inline
def newton_polar_start_three(F):
    """``newton_polar_start`` with three steps, ``X_3 = inv Z``: the tets of a smaller strain (F =
    Q (I + a G), G standard normal, 4000 samples: all of them up to a = 5e-3, 93 % at 1e-2);
    ``overdone`` when ``X_1`` certifies ``X_2``."""
    Z, c, det = newton_polar_step(F, 1.0)
    overdone = newton_polar_certifies(Z, c)
    Z, inv, _, converged = newton_polar_settle(Z, c)
    return Z, inv, det, det > 0.0 and converged, det > 0.0 and overdone


@njit_inline
def newton_polar_start_two(F):
    """``newton_polar_start`` with two steps, ``X_2 = inv Z``: the tets of a still smaller strain, as
    in a steel part (99.6 % of them at a = 1e-4, 45 % at 2e-4).  Two steps are the fewest a block
    takes (``NEWTON_MIN_FIRST_STEPS``), so ``overdone`` is always False: one step is never
    certified (``newton_polar_certifies`` needs an iterate after the first)."""
    Z, inv, det, converged = newton_polar_settle(F, 1.0)
    return Z, inv, det, det > 0.0 and converged, False


@njit_inline
def newton_polar_finish(X, det):
    """``(Z, inv, converged)``: two more Newton steps from ``X = X_k`` of a first stage (``det = det
    F``), ``X_k+2 = inv Z``, accepted as there: from ``newton_polar_start``'s X_4, steps 5 and 6.
    Otherwise X_k+2 is meaningless (possibly NaN): inverted, nearly flat or strongly stretched F."""
    Z, inv, _, converged = newton_polar_settle(X, 1.0)
    return Z, inv, det > 0.0 and converged


@njit_inline
def newton_polar_rotation(F):
    """``(R, converged)``: Newton's polar iteration from ``X = F``, ``R = X_4`` where
    ``newton_polar_start`` accepts it, else ``X_6`` from ``newton_polar_finish``.

    ``R`` is the rotation of ``jacobi_rotation_and_stretch`` (to rounding) when ``converged``: det F
    > 0 (then the polar factor is that rotation) and the iterate before R certified it
    (``newton_polar_certifies``): R lies within ``NEWTON_ROTATION_ERROR`` of it (Frobenius).
    Otherwise R is meaningless (possibly NaN): inverted, nearly flat or strongly stretched F.
    The lane loop of ``kernels.blocked.corotated_block`` takes the same two stages in two passes.
    """
    Z, inv, det, converged, _ = newton_polar_start(F)
    X = mat3_scale_inline(Z, inv)
    if converged:
        return X, True
    Z, inv, converged = newton_polar_finish(X, det)
    return mat3_scale_inline(Z, inv), converged


@njit
def polar_rotation(F):
    """The rotation ``R`` (9-tuple) of the inversion-aware SVD of ``F`` (9-tuple): Newton's
    iteration where it converges, the Jacobi SVD elsewhere.  The blocked lane loops make the same
    choice per tet and agree to round-off (LLVM may fuse multiplies and adds at other places in a
    packed loop: ``jit.JIT_OPTIONS``)."""
    R, converged = newton_polar_rotation(F)
    if converged:
        return R
    R, _, _, _ = jacobi_rotation_and_stretch(F)
    return R


@njit
def jacobi_polar_rotation(F):
    """``jacobi_rotation_and_stretch`` as an ordinary jitted function (for tests)."""
    return jacobi_rotation_and_stretch(F)


@njit
def newton_polar_start_jit(F, steps=NEWTON_FIRST_STEPS):
    """``(R, converged, overdone)`` of ``newton_polar_start`` (``steps`` 4), ``newton_polar_start_three``
    (3) or ``newton_polar_start_two`` (2) as an ordinary jitted function (for tests)."""
    if steps == 2:
        Z, inv, _, converged, overdone = newton_polar_start_two(F)
    elif steps == 3:
        Z, inv, _, converged, overdone = newton_polar_start_three(F)
    else:
        Z, inv, _, converged, overdone = newton_polar_start(F)
    return mat3_scale_inline(Z, inv), converged, overdone


@njit
def newton_polar_rotation_jit(F):
    """``newton_polar_rotation`` as an ordinary jitted function (for tests)."""
    return newton_polar_rotation(F)


@njit
def newton_polar_certifies_jit(Z, c):
    """``newton_polar_certifies`` as an ordinary jitted function (for tests)."""
    return newton_polar_certifies(Z, c)
