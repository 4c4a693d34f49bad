"""Renumbering of vertices and tets for memory locality (Morton / Z-order space-filling curve).

Vertices close in space get close indices, so the corners of a tet and the tets of a vertex sit
near each other in memory.  The output writer maps back to the input order.
"""

import numpy as np


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


def renumber_for_locality(points, tets):
    """``(points, tets, vertex_order, tet_order)`` renumbered for locality.

    New vertex ``i`` is input vertex ``vertex_order[i]``; new tet ``e`` is input tet ``tet_order[e]``
    (tets sorted by their smallest new vertex index).
    """
    vertex_order = morton_order(points)
    new_index = np.empty_like(vertex_order)
    new_index[vertex_order] = np.arange(vertex_order.size)
    renumbered = new_index[tets]
    tet_order = np.lexsort((renumbered.max(axis=1), renumbered.min(axis=1)))
    return points[vertex_order], np.ascontiguousarray(renumbered[tet_order]), vertex_order, tet_order
