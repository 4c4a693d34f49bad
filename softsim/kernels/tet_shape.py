"""Shape measures of every tet in one compiled pass: the smallest altitude and the range of the
dihedral angles (the mesh summary line, ``mesh.quality``; the finite-difference step of
``integrators.stability``), the signed volume and the mean edge length (``mesh.checks``).
NumPy's versions built (tet_count, 4, 3, 3) temporaries: at 1M tets hundreds of MiB, more than
the run's own arrays."""

import math

import numpy as np
from numba import prange

from .deformation import edge_matrix
from .jit import njit, njit_parallel
from .mat3 import mat3_det


@njit
def face_area_vector(x, a, b, c):
    """``1/2 (x_b - x_a) x (x_c - x_a)`` [m^2] as a 3-tuple: the area vector of triangle (a, b, c)."""
    ux, uy, uz = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
    wx, wy, wz = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
    return 0.5 * (uy * wz - uz * wy), 0.5 * (uz * wx - ux * wz), 0.5 * (ux * wy - uy * wx)


@njit
def tet_shape(x, tets, e):
    """``(altitude, cos_min, cos_max)`` of tet ``e`` at positions ``x`` (n, 3) [m]: its smallest
    altitude ``3 |V| / largest face area`` [m], and the cosines of its largest and smallest
    dihedral angles (``-n_a . n_b`` of the unit outward face normals; the faces of
    ``mesh.checks.OUTWARD_FACES``, outward for a positively oriented tet)."""
    i0, i1, i2, i3 = tets[e, 0], tets[e, 1], tets[e, 2], tets[e, 3]
    n0 = face_area_vector(x, i1, i2, i3)
    n1 = face_area_vector(x, i0, i3, i2)
    n2 = face_area_vector(x, i0, i1, i3)
    n3 = face_area_vector(x, i0, i2, i1)
    normals = (n0, n1, n2, n3)
    a0 = math.sqrt(n0[0] ** 2 + n0[1] ** 2 + n0[2] ** 2)
    a1 = math.sqrt(n1[0] ** 2 + n1[1] ** 2 + n1[2] ** 2)
    a2 = math.sqrt(n2[0] ** 2 + n2[1] ** 2 + n2[2] ** 2)
    a3 = math.sqrt(n3[0] ** 2 + n3[1] ** 2 + n3[2] ** 2)
    areas = (a0, a1, a2, a3)
    volume = abs(mat3_det(edge_matrix(x, tets, e))) / 6.0
    cos_min = np.inf
    cos_max = -np.inf
    for a in range(4):
        for b in range(a + 1, 4):
            na, nb = normals[a], normals[b]
            cos = -(na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]) / (areas[a] * areas[b])
            cos = min(1.0, max(-1.0, cos))
            cos_min = min(cos_min, cos)
            cos_max = max(cos_max, cos)
    return 3.0 * volume / max(a0, a1, a2, a3, 1e-300), cos_min, cos_max      # a tet shrunk to a point: 0


@njit_parallel
def tet_shapes(x, tets):
    """``tet_shape`` of every tet: ``(altitude, cos_min, cos_max)``, each (tet_count,)."""
    m = tets.shape[0]
    altitude = np.empty(m)
    cos_min = np.empty(m)
    cos_max = np.empty(m)
    for e in prange(m):
        altitude[e], cos_min[e], cos_max[e] = tet_shape(x, tets, np.int64(e))     # one specialisation (njit_parallel)
    return altitude, cos_min, cos_max


@njit
def signed_volumes(x, tets):
    """``det [x1 - x0, x2 - x0, x3 - x0] / 6`` of every tet (tet_count,) [m^3]; positive = right-handed.
    Checks of a mesh, on one thread (``kernels.jit.njit_parallel``)."""
    m = tets.shape[0]
    out = np.empty(m)
    for e in range(m):
        out[e] = mat3_det(edge_matrix(x, tets, e)) / 6.0
    return out


@njit
def mean_edge_lengths(x, tets):
    """Mean of the six edge lengths of every tet (tet_count,) [m].  Checks of a mesh, on one thread
    (``kernels.jit.njit_parallel``)."""
    m = tets.shape[0]
    out = np.empty(m)
    for e in range(m):
        total = 0.0
        for a in range(3):
            for b in range(a + 1, 4):
                i, j = tets[e, a], tets[e, b]
                total += math.sqrt((x[i, 0] - x[j, 0]) ** 2 + (x[i, 1] - x[j, 1]) ** 2 + (x[i, 2] - x[j, 2]) ** 2)
        out[e] = total / 6.0
    return out
