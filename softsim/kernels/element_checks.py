"""Per-element measures of the current configuration, and the finiteness of the state, for the
guard's checks (``integrators.guard``): once per frame and every ``RECHECK_STEPS`` steps.

Each is one compiled pass, in parallel.  Single-threaded passes of their own, run between the
steps of a run, took 2-6x as long there as timed alone (100k tets: the finiteness check in NumPy
0.18 against 0.03 ms, whether any tet moved 0.27 against 0.13 ms), likely because half of what
they read sat in the other core's cache."""

import numpy as np
from numba import prange

from .blocked import (BLOCK, REST_ROWS, ROW_J, ROW_STRETCH, SCRATCH_ROWS, TRIANGULAR_REST_ROWS, cache_aligned_scratch,
                      gathered_block, volume_ratio_and_stretch_block)
from .deformation import deformation_gradient, edge_matrix
from .energy import CHUNKS        # fixed ranges of blocks, a scratch buffer each
from .jit import njit_inline, njit_parallel
from .mat3 import mat3_ddot, mat3_det, mat3_load


@njit_inline
def moved(J, J_seen, stretch, stretch_seen, limit):
    """Whether a tet whose ``J = det F`` was ``J_seen`` and whose RMS stretch was ``stretch_seen``
    (> 0) at the guard's last look moved more than ``limit``: J by more than ``limit``, or the
    stretch by more than the fraction ``limit`` of itself.  A NaN counts as moved."""
    return not (abs(J - J_seen) <= limit and abs(stretch - stretch_seen) <= limit * stretch_seen)


@njit_parallel
def element_volume_ratios_and_stretches(x, tets, Dm_inv, J, stretch, J_seen, stretch_seen, limit):
    """Fill ``J = det F`` (m,) and the RMS stretch ``|F| / sqrt(3)`` (m,) of every tet at ``x`` (n, 3) [m];
    return whether any tet ``moved`` more than ``limit`` since ``J_seen``, ``stretch_seen`` (m,)."""
    m = tets.shape[0]
    chunks = min(CHUNKS, m)
    moved_in = np.zeros(chunks, np.bool_)
    for c in prange(chunks):
        any_moved = False
        for e in range(c * m // chunks, (c + 1) * m // chunks):
            F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
            J[e] = mat3_det(F)
            stretch[e] = (mat3_ddot(F, F) / 3.0) ** 0.5
            any_moved |= moved(J[e], J_seen[e], stretch[e], stretch_seen[e], limit)
        moved_in[c] = any_moved
    return moved_in.any()


@njit_parallel
def block_volume_ratios_and_stretches(x, block_tets, block_rest, triangular, tet_count, whole_rows, J, stretch,
                                      J_seen, stretch_seen, limit, rest_points=None):
    """``element_volume_ratios_and_stretches`` over the blocks of a ``kernels.blocked.BlockLayout``
    with float64 rest data (``block_tets``, ``block_rest``, ``tet_count``, ``whole_rows``; its tets
    in the model's order; ``triangular``: the layout's ``triangular`` as a
    ``kernels.jit.CompileTimeConstant``, so that only that form's lane loop is compiled): the
    corners gathered into a scratch buffer, F, J and the stretch in packed SIMD lanes, and whether
    any tet moved in the same pass.  At 100k tets, 2 threads: 0.35-0.41 ms
    against 0.7-1.3 ms tet by tet (a guard check every 32 steps); inside a run, the test of whether
    any tet moved took 0.27 ms more as a pass of its own over the four arrays.
    rest_points: None, or the rest positions (n, 3) [m], from which each block's rest data are
    computed as the step does (``BlockLayout.rest_from_points``: ``block_rest`` is then not read).
    """
    if block_rest.shape[2] != (TRIANGULAR_REST_ROWS if triangular else REST_ROWS):
        raise ValueError("block_rest is not in the form that triangular names")
    blocks = block_tets.shape[0]
    chunks = min(CHUNKS, blocks)
    moved_in = np.zeros(chunks, np.bool_)
    for c in prange(chunks):
        # the corners (the dtype of x), J and the stretch; the computed rest data after them
        buf = cache_aligned_scratch((SCRATCH_ROWS if rest_points is not None else ROW_STRETCH + 1) * BLOCK, x)
        any_moved = False
        for b in range(c * blocks // chunks, (c + 1) * blocks // chunks):
            volume_ratio_and_stretch_block(triangular, gathered_block(x, block_tets, block_rest, b, buf, whole_rows[b],
                                                                      rest_points), buf)
            e0 = b * BLOCK
            for j in range(min(BLOCK, tet_count - e0)):
                J[e0 + j] = buf[ROW_J * BLOCK + j]
                stretch[e0 + j] = buf[ROW_STRETCH * BLOCK + j]
                any_moved |= moved(J[e0 + j], J_seen[e0 + j], stretch[e0 + j], stretch_seen[e0 + j], limit)
        moved_in[c] = any_moved
    return moved_in.any()


@njit_parallel
def all_finite(x, v):
    """Whether every value of ``x`` and ``v`` (n, 3) is finite (neither NaN nor infinite): their sum
    of ``value * 0``, which is 0 unless one of them is not finite, in any order of adding (a
    ``prange`` reduction: compiled in about half the time of fixed chunks added in order)."""
    total = 0.0
    for i in prange(x.shape[0]):
        total += x[i, 0] * 0.0 + x[i, 1] * 0.0 + x[i, 2] * 0.0 + v[i, 0] * 0.0 + v[i, 1] * 0.0 + v[i, 2] * 0.0
    return total == 0.0
