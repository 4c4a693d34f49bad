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
from ..kernels.faces import sorted_face_triples
from ..kernels.rest_state import signed_volumes
from ..kernels.tet_shape import mean_edge_lengths as tet_mean_edge_lengths

DEGENERATE_VOLUME_FRACTION = 1e-6

# Faces of a positively oriented tet (0, 1, 2, 3), each wound so its normal points outward.
OUTWARD_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def mean_edge_lengths(points, tets):
    """Mean of the six edge lengths of each tet [m], shape (tet_count,) (one compiled pass)."""
    return tet_mean_edge_lengths(np.ascontiguousarray(points, dtype=np.float64), np.asarray(tets))


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


def boundary_faces(tets, source="mesh", with_tets=False):
    """Outward-wound boundary faces (b, 3) of positively oriented ``tets``; refuses tangled meshes.
    with_tets: return ``(faces, face_tets)``, face_tets (b,) the tet of each face."""
    return faces_of_slots(tets, boundary_face_slots(tets, source), with_tets)


def boundary_face_slots(tets, source="mesh"):
    """The boundary faces of positively oriented ``tets`` as face slots ``4 e + k`` (face k,
    ``OUTWARD_FACES``, of tet e), increasing; refuses tangled meshes.

    A face is keyed by its sorted vertex triple; its winding parity tells from which side a tet
    sees it.  An interior face must appear exactly twice with opposite parity.  Face ``4 e + k`` is
    face k of tet e (``kernels.faces.sorted_face_triples``).
    """
    tets = np.ascontiguousarray(tets, dtype=np.int64)
    low, middle, high, parity = sorted_face_triples(tets, OUTWARD_FACES)
    inverse, counts = face_groups(low, middle, high)
    if counts.max(initial=0) > 2:
        f = int(np.flatnonzero(counts[inverse] > 2)[0])
        raise MeshError(f"{source}: tangled mesh: face {[int(low[f]), int(middle[f]), int(high[f])]} is shared "
                        f"by {counts[inverse[f]]} tetrahedra")
    parity_sum = np.bincount(inverse, weights=parity, minlength=counts.size)
    same_side = (counts == 2) & (parity_sum != 1)
    if same_side.any():
        f = int(np.flatnonzero(same_side[inverse])[0])
        tets_of_face = (np.flatnonzero(inverse == inverse[f]) // 4).tolist()
        raise MeshError(
            f"{source}: tangled mesh: tetrahedra {tets_of_face} share face "
            f"{[int(low[f]), int(middle[f]), int(high[f])]} on the same side of it"
        )
    return np.flatnonzero(counts[inverse] == 1)


def faces_of_slots(tets, slots, with_tets=False):
    """The outward-wound faces (b, 3) of the face slots ``4 e + k`` (``boundary_face_slots``) of
    ``tets``; with_tets: ``(faces, face_tets)``."""
    owner = slots // 4
    faces = np.asarray(tets)[owner[:, None], OUTWARD_FACES[slots % 4]]
    return (faces, owner) if with_tets else faces


def renumbered_face_slots(slots, tet_order):
    """Face slots of a mesh whose tets were reordered, new tet ``e`` being old tet ``tet_order[e]``
    (``mesh.reorder.renumber_for_locality``: the corners of each tet keep their order), increasing:
    what ``boundary_face_slots`` gives for the reordered tets."""
    new_tet = np.empty_like(tet_order)
    new_tet[tet_order] = np.arange(tet_order.size)
    return np.sort(4 * new_tet[slots // 4] + slots % 4)


# Vertex indices below this pack into one int64 sort key per face (three 21-bit fields).
PACKED_FACE_KEY_LIMIT = 2**21


def face_groups(low, middle, high):
    """``(inverse, counts)`` of the faces with sorted vertex triples ``(low, middle, high)`` (each
    (f,) int64): ``inverse[i]`` numbers face i's triple among the distinct ones, ``counts[k]`` how
    many faces have triple k.  One sort of a packed int64 key where the indices fit
    (``PACKED_FACE_KEY_LIMIT``), else a lexicographic sort of the three: ``np.unique(axis=0)``
    took 6 s and 700 MiB for the 4M faces of a 1M-tet mesh."""
    if low.size and 0 <= low.min() and high.max() < PACKED_FACE_KEY_LIMIT:
        key = (low << 42) | (middle << 21) | high
        order = np.argsort(key)
        key = key[order]
        new = np.ones(key.size, dtype=bool)
        new[1:] = key[1:] != key[:-1]
    else:
        order = np.lexsort((high, middle, low))
        new = np.zeros(order.size, dtype=bool)
        new[:1] = True
        for column in (low, middle, high):
            sorted_column = column[order]
            new[1:] |= sorted_column[1:] != sorted_column[:-1]
    group = new.astype(np.int64).cumsum() - 1      # (a cumsum of the bools casts each one: 30x slower)
    inverse = np.empty(order.size, dtype=np.int64)
    inverse[order] = group
    return inverse, np.bincount(group, minlength=int(group[-1]) + 1 if group.size else 0)
