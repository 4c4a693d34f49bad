"""Per-element measures of the current configuration, for the guard's once-per-frame checks."""

from numba import prange

from .blocked import BLOCK, ROW_J, ROW_STRETCH, cache_aligned_scratch, gather_corners, volume_ratio_and_stretch_block
from .deformation import deformation_gradient, edge_matrix
from .energy import CHUNKS        # fixed ranges of blocks, a scratch buffer each
from .jit import njit, njit_parallel
from .mat3 import mat3_ddot, mat3_det, mat3_load


@njit_parallel
def element_volume_ratios_and_stretches(x, tets, Dm_inv, J, stretch):
    """Fill ``J = det F`` (m,) and the RMS stretch ``|F| / sqrt(3)`` (m,) of every tet at ``x`` (n, 3) [m]."""
    for e in prange(tets.shape[0]):
        F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
        J[e] = mat3_det(F)
        stretch[e] = (mat3_ddot(F, F) / 3.0) ** 0.5


@njit_parallel
def block_volume_ratios_and_stretches(x, block_tets, block_rest, tet_count, whole_rows, J, stretch):
    """``element_volume_ratios_and_stretches`` over the blocks of a ``kernels.blocked.BlockLayout``
    with float64 rest data (``block_tets``, ``block_rest``, ``tet_count``, ``whole_rows``; its tets
    in the model's order): the corners gathered into a scratch buffer, F, J and the stretch in packed SIMD lanes.
    At 100k tets, 2 threads: 0.35-0.41 ms against 0.7-1.3 ms tet by tet (a guard check every 32 steps)."""
    blocks = block_tets.shape[0]
    chunks = min(CHUNKS, blocks)
    for c in prange(chunks):
        buf = cache_aligned_scratch((ROW_STRETCH + 1) * BLOCK, x)   # the corners (the dtype of x), J and the stretch
        for b in range(c * blocks // chunks, (c + 1) * blocks // chunks):
            gather_corners(x, block_tets, b, buf, whole_rows[b])
            volume_ratio_and_stretch_block(block_rest[b], buf)
            e0 = b * BLOCK
            for j in range(min(BLOCK, tet_count - e0)):
                J[e0 + j] = buf[ROW_J * BLOCK + j]
                stretch[e0 + j] = buf[ROW_STRETCH * BLOCK + j]


@njit
def moved_more_than(J, J_seen, stretch, stretch_seen, limit):
    """Whether any tet's ``J`` moved more than ``limit`` from ``J_seen``, or its stretch by more than
    the fraction ``limit`` of ``stretch_seen`` (> 0) (each (m,)) [-]: whether the guard must compute
    the stable step again.  A NaN counts as moved.  One pass without temporaries, leaving at the
    first tet that moved: the NumPy expression it replaced (the largest change, six array
    operations) took 0.7 ms at 100k tets, this 0.25 ms (its four arrays come from memory; counting
    the tets within the limit, branch-free, took as long), a check every 32 steps."""
    for e in range(J.shape[0]):
        if not (abs(J[e] - J_seen[e]) <= limit and abs(stretch[e] - stretch_seen[e]) <= limit * stretch_seen[e]):
            return True
    return False
