"""Validity checks and repairs of a tetrahedral mesh, before anything is simulated.

- Orientation: every tet gets a positive rest volume; reversed ones are re-wound and counted.
- Degeneracy: a tet with ``|V| < DEGENERATE_VOLUME_FRACTION * l^3``, ``l`` its mean edge length,
  is refused (a regular tet has ``V = l^3 / (6 sqrt 2) ~ 0.118 l^3``).
- Tangling: every face is shared by at most two tets, and two tets sharing a face lie on opposite
  sides of it (the face appears once with each orientation).  Otherwise the mesh is refused.
- Vertices no tet uses are kept (a user's vertex numbers stay valid); the model holds them.
"""

import numpy as np

from ..errors import MeshError
from ..kernels.rest_state import signed_volumes

DEGENERATE_VOLUME_FRACTION = 1e-6

# Faces of a positively oriented tet (0, 1, 2, 3), each wound so its normal points outward.
OUTWARD_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def mean_edge_lengths(points, tets):
    """Mean of the six edge lengths of each tet [m], shape (tet_count,)."""
    X = points[tets]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    return sum(np.linalg.norm(X[:, a] - X[:, b], axis=1) for a, b in pairs) / 6.0


def orient_positively(points, tets):
    """``(tets, reversed_count)``: a copy of ``tets`` re-wound so every signed volume is >= 0."""
    tets = np.array(tets, dtype=np.int64, copy=True)
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return tets, int(negative.sum())


def check_not_degenerate(points, tets, source):
    """Raise ``MeshError`` if a tet's volume is below the degeneracy threshold."""
    volume = np.abs(signed_volumes(points, tets))
    threshold = DEGENERATE_VOLUME_FRACTION * mean_edge_lengths(points, tets) ** 3
    bad = np.flatnonzero(~(volume >= threshold))   # also catches NaN
    if bad.size:
        e = int(bad[0])
        raise MeshError(
            f"{source}: {bad.size} degenerate tetrahedra (first: tet {e}, volume {volume[e]:.3g} m^3); "
            f"allowed: |V| >= {DEGENERATE_VOLUME_FRACTION:g} x (mean edge length)^3"
        )


def oriented_faces(tets):
    """All 4 * tet_count outward-wound faces, shape (4 m, 3), with the tet each belongs to (4 m,)."""
    faces = tets[:, OUTWARD_FACES].reshape(-1, 3)
    owner = np.repeat(np.arange(tets.shape[0]), 4)
    return faces, owner


def boundary_faces(tets, source="mesh", with_tets=False):
    """Outward-wound boundary faces (b, 3) of positively oriented ``tets``; refuses tangled meshes.
    with_tets: return ``(faces, face_tets)``, face_tets (b,) the tet of each face.

    A face is keyed by its sorted vertex triple; its winding parity tells from which side a tet
    sees it.  An interior face must appear exactly twice with opposite parity.
    """
    faces, owner = oriented_faces(tets)
    order = np.argsort(faces, axis=1)
    keys = np.take_along_axis(faces, order, axis=1)
    # parity of the permutation that sorts the face: even = same cyclic winding as sorted
    parity = ((order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2])
              + (order[:, 1] > order[:, 2])) % 2
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if counts.max(initial=0) > 2:
        f = int(np.flatnonzero(counts[inverse] > 2)[0])
        raise MeshError(f"{source}: tangled mesh: face {keys[f].tolist()} is shared by {counts[inverse[f]]} tetrahedra")
    parity_sum = np.bincount(inverse, weights=parity, minlength=counts.size)
    same_side = (counts == 2) & (parity_sum != 1)
    if same_side.any():
        f = int(np.flatnonzero(same_side[inverse])[0])
        tets_of_face = owner[inverse == inverse[f]].tolist()
        raise MeshError(
            f"{source}: tangled mesh: tetrahedra {tets_of_face} share face {keys[f].tolist()} on the same side of it"
        )
    boundary = counts[inverse] == 1
    return (faces[boundary], owner[boundary]) if with_tets else faces[boundary]
