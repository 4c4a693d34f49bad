"""Per-element measures of the current configuration, for the guard's once-per-frame checks."""

from numba import prange

from .deformation import deformation_gradient, edge_matrix
from .jit import njit_parallel
from .mat3 import mat3_ddot, mat3_det, mat3_load


@njit_parallel
def element_volume_ratios_and_stretches(x, tets, Dm_inv, J, stretch):
    """Fill ``J = det F`` (m,) and the RMS stretch ``|F| / sqrt(3)`` (m,) of every tet at ``x`` (n, 3) [m]."""
    for e in prange(tets.shape[0]):
        F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
        J[e] = mat3_det(F)
        stretch[e] = (mat3_ddot(F, F) / 3.0) ** 0.5
