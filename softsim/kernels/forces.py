"""Elastic vertex forces from the first Piola-Kirchhoff stress (Sifakis & Barbic 2012, section 4.3).

Per tet: ``H = -V0 P(F) Dm^-T``; its columns are the forces on corners 1, 2, 3 and
``f0 = -(h1 + h2 + h3)``.  Forces are written per (tet, corner) into a buffer and then gathered per
vertex through a CSR map: no two threads write the same memory, and every vertex sums its
contributions in the same order on every run (deterministic bits).
"""

import numpy as np
from numba import prange

from ..materials.models import material_first_piola
from .deformation import deformation_gradient, edge_matrix
from .jit import njit, njit_parallel
from .mat3 import mat3_load, mat3_mul_transpose_b


@njit
def tet_corner_forces(x, tets, Dm_inv, rest_volume, e, model, lam, mu, out):
    """Write the elastic forces [N] on the 4 corners of tet ``e`` into ``out[e]`` (4, 3).

    x: (node_count, 3) positions [m]; Dm_inv: (tet_count, 3, 3) [1/m]; rest_volume: (tet_count,) [m^3];
    lam, mu: Lame parameters of the model [Pa].
    """
    Dmi = mat3_load(Dm_inv, e)
    F = deformation_gradient(edge_matrix(x, tets, e), Dmi)
    P = material_first_piola(model, F, lam, mu)
    H = mat3_mul_transpose_b(P, Dmi)          # P Dm^-T
    w = -rest_volume[e]
    for c in range(3):
        h0 = w * H[c]
        h1 = w * H[3 + c]
        h2 = w * H[6 + c]
        out[e, c + 1, 0] = h0
        out[e, c + 1, 1] = h1
        out[e, c + 1, 2] = h2
    for k in range(3):
        out[e, 0, k] = -(out[e, 1, k] + out[e, 2, k] + out[e, 3, k])


@njit_parallel
def compute_tet_corner_forces(x, tets, Dm_inv, rest_volume, model, lam, mu, out):
    """Corner forces [N] of every tet into ``out`` (tet_count, 4, 3), in parallel over tets."""
    for e in prange(tets.shape[0]):
        tet_corner_forces(x, tets, Dm_inv, rest_volume, np.int64(e), model, lam, mu, out)   # (njit_parallel)


@njit
def gather_vertex_force(corner_forces, offsets, slots, i):
    """Sum of the corner forces [N] on vertex ``i``, as a 3-tuple, in CSR order."""
    fx = 0.0
    fy = 0.0
    fz = 0.0
    flat = corner_forces.reshape(-1, 3)
    for k in range(offsets[i], offsets[i + 1]):
        s = slots[k]
        fx += flat[s, 0]
        fy += flat[s, 1]
        fz += flat[s, 2]
    return fx, fy, fz


@njit_parallel
def gather_vertex_forces(corner_forces, offsets, slots, out):
    """Vertex forces [N] into ``out`` (node_count, 3) from ``corner_forces`` (tet_count, 4, 3)."""
    for i in prange(out.shape[0]):
        fx, fy, fz = gather_vertex_force(corner_forces, offsets, slots, np.int64(i))     # (njit_parallel)
        out[i, 0] = fx
        out[i, 1] = fy
        out[i, 2] = fz


def elastic_forces(x, tets, Dm_inv, rest_volume, model, lam, mu, offsets, slots):
    """Elastic vertex forces [N], shape (node_count, 3), for positions ``x`` (node_count, 3) [m].

    Convenience for tests and one-off evaluation; the time loop calls the kernels directly.
    """
    corner = np.empty((tets.shape[0], 4, 3))
    compute_tet_corner_forces(x, tets, Dm_inv, rest_volume, model, lam, mu, corner)
    out = np.empty_like(x)
    gather_vertex_forces(corner, offsets, slots, out)
    return out
