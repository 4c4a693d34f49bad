"""Memory bandwidth measured on the spot: the STREAM triad ``a = b + s c`` in Numba, in parallel.

The bound of the issue: a tet-step of the explicit StVK step must move at least 272 bytes (rest
state, corner indices, corner positions and forces, vertex state), so no code on this machine
exceeds ``triad bandwidth / 272`` tet-steps per second at sizes that do not fit in cache.
"""

import time

import numba
import numpy as np
from numba import prange

BYTES_PER_TET_STEP = 272
TRIAD_BYTES_PER_ELEMENT = 24        # read b and c, write a (STREAM's convention: no write-allocate)


@numba.njit(parallel=True, cache=True)
def triad(a, b, c, s):
    for i in prange(a.shape[0]):
        a[i] = b[i] + s * c[i]


class Stream:
    """Triad over three float64 arrays of ``elements`` (default 3 x 160 MB, far beyond any cache)."""

    name = "stream"

    def __init__(self, elements=20_000_000):
        self.a = np.zeros(elements)
        self.b = np.ones(elements)
        self.c = np.full(elements, 2.0)
        triad(self.a, self.b, self.c, 3.0)

    def bandwidth(self, repeats=5):
        """Best of ``repeats`` triads [bytes/s] (STREAM reports the best)."""
        best = 0.0
        for _ in range(repeats):
            start = time.perf_counter()
            triad(self.a, self.b, self.c, 3.0)
            best = max(best, TRIAD_BYTES_PER_ELEMENT * self.a.size / (time.perf_counter() - start))
        return best

    def bound(self, repeats=5):
        """The bandwidth bound [tet-steps/s]."""
        return self.bandwidth(repeats) / BYTES_PER_TET_STEP
