"""Renumbering of vertices and tets for memory locality and for the parallel scatter.

Vertices close in space get close indices (a Morton / Z-order curve), so the corners of a tet and
the tets of a vertex sit near each other in memory.  Before that, the vertices are cut into
``SLABS`` slabs of equal vertex count along the mesh's longest axis, slab after slab: the tets,
sorted by their first vertex, then follow the slabs too, and the ``SLABS`` parts into which
``kernels.blocked`` cuts them share vertices only with the parts next to them.  Two colours (even
and odd parts) of ``SLABS / 2`` equal parts each then scatter the forces with two barriers per
step, balanced on 1, 2 or 4 threads; in Morton order alone the parts needed 9 colours of 2 to 5
parts (100k-tet beam, 2 threads: 47.6 against 73.9 M tet-steps/s with slabs).  The output writer
maps back to the input order.
"""

import numba
import numpy as np

# Slabs along the longest axis (and parts of the colour scatter, ``kernels.blocked.slab_parts``): even,
# so that alternate slabs make two colours, and a multiple of 4, so that each colour's parts split
# evenly over 1, 2 or 4 threads; 8, or 2 per thread on machines with more than 4 (Numba's thread
# pool size), so that every thread has a part of each colour.  A slab thinner than about two elements lets
# non-neighbouring parts share vertices: the colouring then simply uses more colours.
SLABS = 8 * max(1, -(-numba.config.NUMBA_NUM_THREADS // 4))
# Thinner slabs per slab, visited in turn (see ``slab_order``).
SUBSLABS = 8


def _spread_bits(v):
    """Insert two zero bits after each of the low 21 bits of ``v`` (uint64)."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_order(points):
    """Permutation (node_count,) that sorts ``points`` (n, 3) along a 3D Z-order curve."""
    lo = points.min(axis=0)
    extent = np.maximum(points.max(axis=0) - lo, 1e-300)
    q = np.clip(((points - lo) / extent.max() * (2**21 - 1)), 0, 2**21 - 1).astype(np.uint64)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << np.uint64(1)) | (_spread_bits(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def slab_order(points, slabs=SLABS):
    """Permutation (node_count,) that sorts ``points`` (n, 3) slab by slab along their longest axis
    (``slabs`` slabs of equal vertex count), each slab in ``SUBSLABS`` thinner slabs in turn, in
    Morton order within those.  The thin slabs keep a slab's first and last tets next to its faces:
    Morton order alone starts a slab at its low (y, z) corner anywhere along x, so a block of tets
    straddling two slabs reached across the next one (measured: 3 colours instead of 2 on a cube)."""
    n = points.shape[0]
    axis = int(np.argmax(points.max(axis=0) - points.min(axis=0))) if n else 0
    by_axis = np.argsort(points[:, axis], kind="stable")
    thin = np.empty(n, dtype=np.int64)
    thin[by_axis] = np.arange(n) * (slabs * SUBSLABS) // max(n, 1)     # slab = thin // SUBSLABS
    morton_rank = np.empty(n, dtype=np.int64)
    morton_rank[morton_order(points)] = np.arange(n)
    return np.lexsort((morton_rank, thin))


def renumber_for_locality(points, tets, slabs=SLABS):
    """``(points, tets, vertex_order, tet_order)`` renumbered for locality (``slab_order``).

    New vertex ``i`` is input vertex ``vertex_order[i]``; new tet ``e`` is input tet ``tet_order[e]``
    (tets sorted by their smallest new vertex index).
    """
    vertex_order = slab_order(points, slabs)
    new_index = np.empty_like(vertex_order)
    new_index[vertex_order] = np.arange(vertex_order.size)
    renumbered = new_index[tets]
    tet_order = np.lexsort((renumbered.max(axis=1), renumbered.min(axis=1)))
    return points[vertex_order], np.ascontiguousarray(renumbered[tet_order]), vertex_order, tet_order
