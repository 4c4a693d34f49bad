"""3x3 matrix algebra on 9-tuples, for use inside jitted per-element kernels.

A matrix ``A`` is the tuple ``(a00, a01, a02, a10, a11, a12, a20, a21, a22)`` (row-major).  Tuples
live in registers: no heap allocation per element, which matters in loops over millions of
tetrahedra.  Every function is a pure, serial Numba function.
"""

import numpy as np

from .jit import njit, njit_inline


@njit
def mat3_load(a, i):
    """Row-major 9-tuple of ``a[i]`` where ``a`` has shape (count, 3, 3)."""
    return (a[i, 0, 0], a[i, 0, 1], a[i, 0, 2],
            a[i, 1, 0], a[i, 1, 1], a[i, 1, 2],
            a[i, 2, 0], a[i, 2, 1], a[i, 2, 2])


@njit
def mat3_identity():
    return (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@njit
def mat3_mul(a, b):
    """Matrix product ``a @ b``."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
            a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
            a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
            a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@njit
def mat3_mul_transpose_b(a, b):
    """Matrix product ``a @ b.T``."""
    return (a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
            a[0] * b[3] + a[1] * b[4] + a[2] * b[5],
            a[0] * b[6] + a[1] * b[7] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[1] + a[5] * b[2],
            a[3] * b[3] + a[4] * b[4] + a[5] * b[5],
            a[3] * b[6] + a[4] * b[7] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[1] + a[8] * b[2],
            a[6] * b[3] + a[7] * b[4] + a[8] * b[5],
            a[6] * b[6] + a[7] * b[7] + a[8] * b[8])


@njit
def mat3_transpose_mul(a, b):
    """Matrix product ``a.T @ b``."""
    return (a[0] * b[0] + a[3] * b[3] + a[6] * b[6],
            a[0] * b[1] + a[3] * b[4] + a[6] * b[7],
            a[0] * b[2] + a[3] * b[5] + a[6] * b[8],
            a[1] * b[0] + a[4] * b[3] + a[7] * b[6],
            a[1] * b[1] + a[4] * b[4] + a[7] * b[7],
            a[1] * b[2] + a[4] * b[5] + a[7] * b[8],
            a[2] * b[0] + a[5] * b[3] + a[8] * b[6],
            a[2] * b[1] + a[5] * b[4] + a[8] * b[7],
            a[2] * b[2] + a[5] * b[5] + a[8] * b[8])


@njit
def mat3_mul_add(a, b, c):
    """``c + a @ b``, each entry's three products added onto ``c``'s in turn: with contraction,
    three fused multiply-adds (``c + (a @ b)`` takes a multiply, two multiply-adds and an add)."""
    return (((c[0] + a[0] * b[0]) + a[1] * b[3]) + a[2] * b[6],
            ((c[1] + a[0] * b[1]) + a[1] * b[4]) + a[2] * b[7],
            ((c[2] + a[0] * b[2]) + a[1] * b[5]) + a[2] * b[8],
            ((c[3] + a[3] * b[0]) + a[4] * b[3]) + a[5] * b[6],
            ((c[4] + a[3] * b[1]) + a[4] * b[4]) + a[5] * b[7],
            ((c[5] + a[3] * b[2]) + a[4] * b[5]) + a[5] * b[8],
            ((c[6] + a[6] * b[0]) + a[7] * b[3]) + a[8] * b[6],
            ((c[7] + a[6] * b[1]) + a[7] * b[4]) + a[8] * b[7],
            ((c[8] + a[6] * b[2]) + a[7] * b[5]) + a[8] * b[8])


@njit
def mat3_transpose_mul_add(a, b, c):
    """``c + a.T @ b``, summed as ``mat3_mul_add`` (the transpose only renames entries)."""
    return mat3_mul_add(mat3_transpose(a), b, c)


@njit
def mat3_transpose(a):
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit
def mat3_add_scaled(a, b, s):
    """``a + s * b``."""
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2],
            a[3] + s * b[3], a[4] + s * b[4], a[5] + s * b[5],
            a[6] + s * b[6], a[7] + s * b[7], a[8] + s * b[8])


@njit
def mat3_add(a, b):
    """``a + b``."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8])


@njit
def mat3_sub(a, b):
    """``a - b``."""
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5],
            a[6] - b[6], a[7] - b[7], a[8] - b[8])


@njit
def mat3_add_diagonal(a, s):
    """``a + s * I``: no literal constant, so a float32 ``a`` and ``s`` give float32 results."""
    return (a[0] + s, a[1], a[2], a[3], a[4] + s, a[5], a[6], a[7], a[8] + s)


@njit
def mat3_scale(a, s):
    return (s * a[0], s * a[1], s * a[2], s * a[3], s * a[4], s * a[5],
            s * a[6], s * a[7], s * a[8])


@njit
def mat3_trace(a):
    return a[0] + a[4] + a[8]


@njit
def mat3_ddot(a, b):
    """Frobenius inner product ``sum(a * b)``, summed as three rows: with fused multiply-adds a
    single chain of nine waited on each other (36 cycles); corotated's ``R : F`` and Neo-Hookean's
    ``F : F`` lie on their lane loops' critical path (100k beam, one process: 1.03 and 1.02x)."""
    return ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) + (a[3] * b[3] + a[4] * b[4] + a[5] * b[5])
            + (a[6] * b[6] + a[7] * b[7] + a[8] * b[8]))


@njit
def mat3_det(a):
    return (a[0] * (a[4] * a[8] - a[5] * a[7])
            - a[1] * (a[3] * a[8] - a[5] * a[6])
            + a[2] * (a[3] * a[7] - a[4] * a[6]))


@njit
def mat3_det_from_cofactor(a, cof):
    """``det a`` from ``a`` and its cofactor matrix ``cof`` (``mat3_cofactor``): the first row of
    ``a`` dotted with that of ``cof``, three products where ``mat3_det`` takes nine more."""
    return a[0] * cof[0] + a[1] * cof[1] + a[2] * cof[2]


@njit
def mat3_cofactor(a):
    """Cofactor matrix ``det(a) * inv(a).T`` = dJ/dF for ``J = det(F)``; defined for singular ``a``."""
    return (a[4] * a[8] - a[5] * a[7], a[5] * a[6] - a[3] * a[8], a[3] * a[7] - a[4] * a[6],
            a[2] * a[7] - a[1] * a[8], a[0] * a[8] - a[2] * a[6], a[1] * a[6] - a[0] * a[7],
            a[1] * a[5] - a[2] * a[4], a[2] * a[3] - a[0] * a[5], a[0] * a[4] - a[1] * a[3])


@njit
def mat3_to_array(a):
    """A new (3, 3) array holding the 9-tuple ``a`` (for tests and Python callers)."""
    out = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            out[r, c] = a[3 * r + c]
    return out


# The same functions always inlined by LLVM (``jit.njit_inline``), for the lane loops of
# ``kernels.blocked`` and ``kernels.polar3``: as ordinary calls LLVM finds them too large to inline,
# and a loop with a call in it does not vectorise.
mat3_mul_inline = njit_inline(mat3_mul.py_func)
mat3_mul_transpose_b_inline = njit_inline(mat3_mul_transpose_b.py_func)
mat3_scale_inline = njit_inline(mat3_scale.py_func)
mat3_add_scaled_inline = njit_inline(mat3_add_scaled.py_func)
mat3_ddot_inline = njit_inline(mat3_ddot.py_func)
mat3_det_inline = njit_inline(mat3_det.py_func)
mat3_cofactor_inline = njit_inline(mat3_cofactor.py_func)
