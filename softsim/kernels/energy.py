"""Energies of a state [J], reduced in parallel; evaluated once per frame, never per step."""

import numpy as np
from numba import prange

from ..materials.models import energy_density
from .deformation import deformation_gradient, edge_matrix
from .jit import njit_parallel
from .mat3 import mat3_load


@njit_parallel
def elastic_energy(x, tets, Dm_inv, rest_volume, model, lam, mu):
    """``sum_e V0_e Psi(F_e)`` [J] for positions ``x`` (node_count, 3) [m]."""
    total = 0.0
    for e in prange(tets.shape[0]):
        F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
        total += rest_volume[e] * energy_density(model, F, lam, mu)
    return total


@njit_parallel
def kinetic_energy(v, mass):
    """``1/2 sum m |v|^2`` [J]; v (node_count, 3) [m/s], mass (node_count,) [kg]."""
    total = 0.0
    for i in prange(v.shape[0]):
        total += 0.5 * mass[i] * (v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
    return total


@njit_parallel
def gravity_energy(x, mass, gravity):
    """Potential energy ``-sum m g . x`` [J] in the uniform field ``gravity`` (3,) [m/s^2]."""
    total = 0.0
    for i in prange(x.shape[0]):
        total -= mass[i] * (gravity[0] * x[i, 0] + gravity[1] * x[i, 1] + gravity[2] * x[i, 2])
    return total
