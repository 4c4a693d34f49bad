"""Per-element shape measures of the current configuration, for the once-per-frame checks."""

from numba import prange

from .deformation import deformation_gradient, edge_matrix
from .jit import njit, njit_parallel
from .mat3 import mat3_ddot, mat3_det, mat3_load


@njit
def _cross_norm(ax, ay, az, bx, by, bz):
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return (cx * cx + cy * cy + cz * cz) ** 0.5


@njit
def tet_altitude(x, tets, e):
    """Smallest altitude [m] of tet ``e`` at positions ``x``: 3 |V| / largest face area."""
    Ds = edge_matrix(x, tets, e)                     # columns: x1-x0, x2-x0, x3-x0
    six_volume = abs(mat3_det(Ds))
    e1 = (Ds[0], Ds[3], Ds[6])
    e2 = (Ds[1], Ds[4], Ds[7])
    e3 = (Ds[2], Ds[5], Ds[8])
    a0 = _cross_norm(e1[0], e1[1], e1[2], e2[0], e2[1], e2[2])     # twice the face areas
    a1 = _cross_norm(e1[0], e1[1], e1[2], e3[0], e3[1], e3[2])
    a2 = _cross_norm(e2[0], e2[1], e2[2], e3[0], e3[1], e3[2])
    a3 = _cross_norm(e2[0] - e1[0], e2[1] - e1[1], e2[2] - e1[2],
                     e3[0] - e1[0], e3[1] - e1[1], e3[2] - e1[2])
    largest = max(max(a0, a1), max(a2, a3))
    if largest == 0.0:
        return 0.0
    return six_volume / largest                      # 3 (6V/6) / (2A/2) = 6V / 2A


@njit_parallel
def element_altitudes_and_volume_ratios(x, tets, Dm_inv, altitude, J):
    """Fill ``altitude`` (m,) [m] and ``J = det F`` (m,) of every tet at positions ``x`` (n, 3) [m]."""
    for e in prange(tets.shape[0]):
        altitude[e] = tet_altitude(x, tets, e)
        J[e] = mat3_det(deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e)))


@njit_parallel
def element_volume_ratios_and_stretches(x, tets, Dm_inv, J, stretch):
    """Fill ``J = det F`` (m,) and the RMS stretch ``|F| / sqrt(3)`` (m,) of every tet at ``x`` (n, 3) [m]."""
    for e in prange(tets.shape[0]):
        F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
        J[e] = mat3_det(F)
        stretch[e] = (mat3_ddot(F, F) / 3.0) ** 0.5
