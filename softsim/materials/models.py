"""Hyperelastic material laws: energy density ``Psi(F)`` [J/m^3] and first Piola-Kirchhoff stress
``P(F) = dPsi/dF`` [Pa] for each model a scene can choose.

All laws take the deformation gradient ``F`` as a 9-tuple (row-major, see ``kernels.mat3``) and the
Lame parameters ``lam``, ``mu`` [Pa] that ``model_lame_parameters`` returns for that model.  At small
strain all four reduce to isotropic Hooke's law with the scene's E and nu.

- ``linear``: small strain ``eps = (F + F^T)/2 - I``, ``P = sigma = lam tr(eps) I + 2 mu eps``.
  Not rotation invariant: a rotated body sees spurious stress.
- ``stvk`` (St. Venant-Kirchhoff): Green strain ``E``, ``S = lam tr(E) I + 2 mu E``, ``P = F S``.
  Softens and can collapse under strong compression.
- ``corotated``: ``Psi = mu |F - R|^2 + lam/2 tr(R^T F - I)^2`` with the rotation ``R`` of the
  inversion-aware SVD (Irving et al. 2004), ``kernels.polar3.polar_rotation``;
  ``P = 2 mu (F - R) + lam tr(R^T F - I) R``.
- ``neohookean``: stable Neo-Hookean, Smith, de Goes & Kim 2018,
  ``Psi = mu/2 (I_C - 3) + lam/2 (J - alpha)^2 - mu/2 log(I_C + 1)``, ``alpha = 1 + 3 mu / (4 lam)``,
  with the Lame remapping of ``lame.stable_neohookean_parameters``; finite for inverted elements.
  The constant ``Psi(I)`` is subtracted so that every model's energy is zero at rest.
"""

import math

from ..kernels.deformation import green_strain, small_strain
from ..kernels.jit import njit
from ..kernels.mat3 import (
    mat3_add_scaled,
    mat3_cofactor,
    mat3_ddot,
    mat3_det,
    mat3_identity,
    mat3_mul,
    mat3_scale,
    mat3_trace,
)
from ..kernels.polar3 import polar_rotation
from .lame import lame_parameters, stable_neohookean_parameters

LINEAR = 0
STVK = 1
COROTATED = 2
NEOHOOKEAN = 3

MODEL_IDS = {"linear": LINEAR, "stvk": STVK, "corotated": COROTATED, "neohookean": NEOHOOKEAN}

# Models whose energy is invariant under rotation (they conserve angular momentum).
ROTATION_INVARIANT = ("stvk", "corotated", "neohookean")
# Models that push an inverted element back to positive volume.
INVERSION_SAFE = ("corotated", "neohookean")


def model_lame_parameters(model, youngs_modulus, poissons_ratio):
    """``(lam, mu)`` [Pa] that model ``model`` (a name of ``MODEL_IDS``) uses internally."""
    lam, mu = lame_parameters(youngs_modulus, poissons_ratio)
    if model == "neohookean":
        return stable_neohookean_parameters(lam, mu)
    return lam, mu


# ---------------------------------------------------------------------------------------------
# Hooke's law (isotropic)


@njit
def hooke_stress(strain, lam, mu):
    """``lam tr(strain) I + 2 mu strain``: Cauchy stress for ``linear``, 2nd Piola-Kirchhoff for ``stvk``."""
    return mat3_add_scaled(mat3_scale(strain, 2.0 * mu), mat3_identity(), lam * mat3_trace(strain))


@njit
def hooke_energy_density(strain, lam, mu):
    """``mu strain:strain + lam/2 tr(strain)^2`` [J/m^3]."""
    tr = mat3_trace(strain)
    return mu * mat3_ddot(strain, strain) + 0.5 * lam * tr * tr


# ---------------------------------------------------------------------------------------------
# linear


@njit
def linear_first_piola(F, lam, mu):
    return hooke_stress(small_strain(F), lam, mu)


@njit
def linear_energy_density(F, lam, mu):
    return hooke_energy_density(small_strain(F), lam, mu)


# ---------------------------------------------------------------------------------------------
# St. Venant-Kirchhoff


@njit
def stvk_first_piola(F, lam, mu):
    return mat3_mul(F, hooke_stress(green_strain(F), lam, mu))


@njit
def stvk_energy_density(F, lam, mu):
    return hooke_energy_density(green_strain(F), lam, mu)


# ---------------------------------------------------------------------------------------------
# corotated (inversion-aware)


@njit
def corotated_stress(F, R, lam, mu):
    """``P = 2 mu (F - R) + lam tr(R^T F - I) R`` [Pa] for ``F`` and its rotation ``R`` (9-tuples)."""
    volumetric = lam * (mat3_ddot(R, F) - 3.0)
    return mat3_add_scaled(mat3_scale(F, 2.0 * mu), R, volumetric - 2.0 * mu)


@njit
def corotated_first_piola(F, lam, mu):
    return corotated_stress(F, polar_rotation(F), lam, mu)


@njit
def corotated_energy_density(F, lam, mu):
    R = polar_rotation(F)
    D = mat3_add_scaled(F, R, -1.0)
    tr = mat3_ddot(R, F) - 3.0
    return mu * mat3_ddot(D, D) + 0.5 * lam * tr * tr


# ---------------------------------------------------------------------------------------------
# stable Neo-Hookean (Smith, de Goes & Kim 2018)


@njit
def neohookean_first_piola(F, lam, mu):
    Ic = mat3_ddot(F, F)
    J = mat3_det(F)
    alpha = 1.0 + 0.75 * mu / lam
    return mat3_add_scaled(mat3_scale(F, mu * (1.0 - 1.0 / (Ic + 1.0))), mat3_cofactor(F), lam * (J - alpha))


@njit
def neohookean_energy_density(F, lam, mu):
    Ic = mat3_ddot(F, F)
    J = mat3_det(F)
    alpha = 1.0 + 0.75 * mu / lam
    rest = 0.5 * lam * (1.0 - alpha) ** 2 - 0.5 * mu * math.log(4.0)   # Psi(I): shifted to zero
    return 0.5 * mu * (Ic - 3.0) + 0.5 * lam * (J - alpha) ** 2 - 0.5 * mu * math.log(Ic + 1.0) - rest


# ---------------------------------------------------------------------------------------------
# dispatch by model id (a loop-invariant branch inside the element loops)


@njit
def first_piola(model, F, lam, mu):
    """First Piola-Kirchhoff stress [Pa] of model ``model`` (one of LINEAR..NEOHOOKEAN)."""
    if model == STVK:
        return stvk_first_piola(F, lam, mu)
    elif model == NEOHOOKEAN:
        return neohookean_first_piola(F, lam, mu)
    elif model == COROTATED:
        return corotated_first_piola(F, lam, mu)
    return linear_first_piola(F, lam, mu)


@njit
def energy_density(model, F, lam, mu):
    """Elastic energy density [J/m^3] of model ``model``."""
    if model == STVK:
        return stvk_energy_density(F, lam, mu)
    elif model == NEOHOOKEAN:
        return neohookean_energy_density(F, lam, mu)
    elif model == COROTATED:
        return corotated_energy_density(F, lam, mu)
    return linear_energy_density(F, lam, mu)
