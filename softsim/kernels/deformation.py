"""Per-tetrahedron kinematics (Sifakis & Barbic 2012, section 4.1).

For a tetrahedron with rest corners ``X0..X3`` and current corners ``x0..x3`` the deformation
gradient is constant inside the element::

    F = Ds Dm^-1,   Ds = [x1-x0, x2-x0, x3-x0],   Dm = [X1-X0, X2-X0, X3-X0]

(columns are edge vectors).  All functions here are serial Numba functions on 9-tuples
(see ``mat3``) or on flat arrays for one element.
"""

from .jit import njit
from .mat3 import mat3_add_scaled, mat3_identity, mat3_mul, mat3_scale, mat3_transpose, mat3_transpose_mul


@njit
def edge_matrix(x, tets, e):
    """``Ds = [x1-x0, x2-x0, x3-x0]`` of tet ``e`` as a 9-tuple [m].

    x: (node_count, 3) current positions [m]; tets: (tet_count, 4) vertex indices.
    """
    i0 = tets[e, 0]
    i1 = tets[e, 1]
    i2 = tets[e, 2]
    i3 = tets[e, 3]
    return (x[i1, 0] - x[i0, 0], x[i2, 0] - x[i0, 0], x[i3, 0] - x[i0, 0],
            x[i1, 1] - x[i0, 1], x[i2, 1] - x[i0, 1], x[i3, 1] - x[i0, 1],
            x[i1, 2] - x[i0, 2], x[i2, 2] - x[i0, 2], x[i3, 2] - x[i0, 2])


@njit
def deformation_gradient(Ds, Dm_inv):
    """``F = Ds Dm^-1`` (dimensionless), both arguments and the result 9-tuples."""
    return mat3_mul(Ds, Dm_inv)


@njit
def green_strain(F):
    """Green-Lagrange strain ``E = 1/2 (F^T F - I)``; zero under any rigid motion."""
    C = mat3_transpose_mul(F, F)
    return mat3_add_scaled(mat3_scale(C, 0.5), mat3_identity(), -0.5)


@njit
def small_strain(F):
    """Infinitesimal strain ``eps = 1/2 (F + F^T) - I``; not zero under rotation."""
    Ft = mat3_transpose(F)
    S = mat3_add_scaled(F, Ft, 1.0)
    return mat3_add_scaled(mat3_scale(S, 0.5), mat3_identity(), -1.0)

