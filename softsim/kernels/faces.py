"""The faces of every tet as sorted vertex triples, in one compiled pass (``mesh.checks.boundary_faces``).

Face ``4 e + k`` is face k of tet e, wound as ``mesh.checks.OUTWARD_FACES[k]`` (passed in).
NumPy built the (4 m, 3) faces by fancy indexing and sorted each row: at 2M tets about 3 s a
call, most of it in faulting in the fresh pages of its temporaries.
"""

import numpy as np

from .jit import njit


@njit
def sorted_face_triples(tets, face_corners):
    """``(low, middle, high, parity)`` (4 m,) each: the vertices of every face sorted, and the parity
    (0 or 1, int8) of the permutation that sorts the face as wound: even = the same cyclic winding.
    face_corners (4, 3): the corners of each face of a tet, wound (``mesh.checks.OUTWARD_FACES``).
    Once per mesh, on one thread (``kernels.jit.njit_parallel``)."""
    m = tets.shape[0]
    low = np.empty(4 * m, dtype=np.int64)
    middle = np.empty(4 * m, dtype=np.int64)
    high = np.empty(4 * m, dtype=np.int64)
    parity = np.empty(4 * m, dtype=np.int8)
    for e in range(m):
        for k in range(4):
            a = tets[e, face_corners[k, 0]]
            b = tets[e, face_corners[k, 1]]
            c = tets[e, face_corners[k, 2]]
            f = 4 * e + k
            low[f] = min(a, b, c)
            high[f] = max(a, b, c)
            middle[f] = a + b + c - low[f] - high[f]
            parity[f] = ((a > b) + (a > c) + (b > c)) % 2
    return low, middle, high, parity
