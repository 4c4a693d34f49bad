"""The faces of every tet as sorted vertex triples, in one compiled pass (``mesh.checks.boundary_faces``).

Face ``4 e + k`` is face k of tet e, wound as ``mesh.checks.OUTWARD_FACES[k]``: ``(1, 2, 3)``,
``(0, 3, 2)``, ``(0, 1, 3)``, ``(0, 2, 1)``.  NumPy built the (4 m, 3) faces by fancy indexing
and sorted each row: at 2M tets about 3 s a call, most of it in faulting in the fresh pages of
its temporaries.
"""

import numpy as np
from numba import prange

from .jit import njit_parallel


@njit_parallel
def sorted_face_triples(tets):
    """``(low, middle, high, parity)`` (4 m,) each: the vertices of every face sorted, and the parity
    (0 or 1, int8) of the permutation that sorts the face as wound: even = the same cyclic winding."""
    m = tets.shape[0]
    low = np.empty(4 * m, dtype=np.int64)
    middle = np.empty(4 * m, dtype=np.int64)
    high = np.empty(4 * m, dtype=np.int64)
    parity = np.empty(4 * m, dtype=np.int8)
    for e in prange(m):
        t0, t1, t2, t3 = tets[e, 0], tets[e, 1], tets[e, 2], tets[e, 3]
        for k in range(4):
            if k == 0:
                a, b, c = t1, t2, t3
            elif k == 1:
                a, b, c = t0, t3, t2
            elif k == 2:
                a, b, c = t0, t1, t3
            else:
                a, b, c = t0, t2, t1
            f = 4 * e + k
            low[f] = min(a, b, c)
            high[f] = max(a, b, c)
            middle[f] = a + b + c - low[f] - high[f]
            parity[f] = ((a > b) + (a > c) + (b > c)) % 2
    return low, middle, high, parity
