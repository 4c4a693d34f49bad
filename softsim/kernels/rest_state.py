"""Rest-state quantities, computed once before a run (NumPy, vectorised; the signed volumes in a
compiled pass, ``tet_shape``).

Sifakis & Barbic 2012, section 4.2: ``Dm = [X1-X0, X2-X0, X3-X0]``, ``W = |det Dm| / 6``;
the step then only forms ``F = Ds Dm^-1``.
"""

import numpy as np

from .tet_shape import signed_volumes as tet_signed_volumes


def rest_shape_matrices(points, tets):
    """``Dm`` per tet [m], shape (tet_count, 3, 3), columns the edges ``X1-X0, X2-X0, X3-X0``.

    points: (node_count, 3) rest positions [m]; tets: (tet_count, 4) vertex indices.
    """
    X = points[tets]                           # (m, 4, 3)
    edges = X[:, 1:, :] - X[:, :1, :]          # (m, 3 edges, 3 coords)
    return np.ascontiguousarray(np.transpose(edges, (0, 2, 1)))


def signed_volumes(points, tets):
    """Signed volume ``det(Dm) / 6`` per tet [m^3], shape (tet_count,); positive = right-handed
    (one compiled pass, ``tet_shape.signed_volumes``)."""
    return tet_signed_volumes(np.ascontiguousarray(points, dtype=np.float64), np.asarray(tets))


def rest_state(points, tets):
    """``(Dm_inv, rest_volume)``: (tet_count, 3, 3) [1/m] and (tet_count,) [m^3], float64.

    The tets must be positively oriented and non-degenerate (``mesh.checks`` ensures it).
    """
    Dm = rest_shape_matrices(points, tets)
    rest_volume = np.linalg.det(Dm) / 6.0
    return np.ascontiguousarray(np.linalg.inv(Dm)), rest_volume


def lumped_masses(tets, rest_volume, density, node_count):
    """Lumped vertex masses [kg], shape (node_count,): each tet gives a quarter of ``rho V0`` per corner."""
    mass = np.zeros(node_count)
    np.add.at(mass, tets.ravel(), np.repeat(density * rest_volume / 4.0, 4))
    return mass


def vertex_tet_csr(tets, node_count):
    """CSR map from each vertex to the (tet, corner) slots that touch it.

    Returns ``offsets`` (node_count + 1,) and ``slots`` (4 * tet_count,), int64, where the slots of
    vertex ``i`` are ``slots[offsets[i]:offsets[i+1]]`` and a slot is ``4 * tet + corner``, in
    increasing order, so a gather over them sums in a fixed order: the same run gives the same bits.
    Works the same for any cells of k corners, e.g. boundary triangles (slot ``3 * face + corner``).
    """
    flat = tets.ravel()
    slots = np.argsort(flat, kind="stable").astype(np.int64)
    counts = np.bincount(flat, minlength=node_count)
    offsets = np.zeros(node_count + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, slots
