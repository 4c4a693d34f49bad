"""Energies of a state [J]; evaluated once per frame, never per step.

The elastic energy is cut into ``CHUNKS`` fixed ranges of tets, summed in parallel, then added in
order: the same bits on any thread count and under any scheduling.  (A ``prange`` reduction adds
per-thread partial sums, and TBB hands the chunks of a loop to whichever thread is free: its totals
changed in the last bits from call to call.)  The kinetic and gravitational energies, a few
multiply-adds a vertex, are summed on one thread, in the same ``CHUNKS`` ranges (the same bits as
in parallel): compiled in parallel, the two took about 1.3 s more of a first run's compiling; at
370k vertices (2M tets) the two take 1.4 ms a frame serially, 0.7 ms in parallel.
"""

import numpy as np
from numba import prange

from ..materials.models import material_energy_density
from .deformation import deformation_gradient, edge_matrix
from .jit import njit, njit_parallel
from .mat3 import mat3_load

CHUNKS = 64


@njit_parallel
def elastic_energy(x, tets, Dm_inv, rest_volume, model, lam, mu):
    """``sum_e V0_e Psi(F_e)`` [J] for positions ``x`` (node_count, 3) [m]."""
    m = tets.shape[0]
    partial = np.zeros(CHUNKS)
    for c in prange(CHUNKS):
        total = 0.0
        for e in range(c * m // CHUNKS, (c + 1) * m // CHUNKS):
            F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
            total += rest_volume[e] * material_energy_density(model, F, lam, mu)
        partial[c] = total
    return ordered_sum(partial)


@njit
def kinetic_energy(v, mass):
    """``1/2 sum m |v|^2`` [J]; v (node_count, 3) [m/s], mass (node_count,) [kg]."""
    n = v.shape[0]
    partial = np.zeros(CHUNKS)
    for c in range(CHUNKS):
        total = 0.0
        for i in range(c * n // CHUNKS, (c + 1) * n // CHUNKS):
            total += 0.5 * mass[i] * (v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
        partial[c] = total
    return ordered_sum(partial)


@njit
def gravity_energy(x, mass, gravity):
    """Potential energy ``-sum m g . x`` [J] in the uniform field ``gravity`` (3,) [m/s^2]."""
    n = x.shape[0]
    partial = np.zeros(CHUNKS)
    for c in range(CHUNKS):
        total = 0.0
        for i in range(c * n // CHUNKS, (c + 1) * n // CHUNKS):
            total -= mass[i] * (gravity[0] * x[i, 0] + gravity[1] * x[i, 1] + gravity[2] * x[i, 2])
        partial[c] = total
    return ordered_sum(partial)


@njit
def ordered_sum(values):
    """``values[0] + values[1] + ...``, left to right."""
    total = 0.0
    for k in range(values.shape[0]):
        total += values[k]
    return total
