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

import numpy as np
from numba import types
from numba.extending import overload

from ..kernels.deformation import green_strain, small_strain
from ..kernels.jit import njit
from ..kernels.mat3 import (
    mat3_add,
    mat3_add_diagonal,
    mat3_add_scaled,
    mat3_add_scaled_inline,
    mat3_cofactor,
    mat3_ddot,
    mat3_ddot_inline,
    mat3_det,
    mat3_det_from_cofactor,
    mat3_mul,
    mat3_mul_add,
    mat3_scale,
    mat3_scale_inline,
    mat3_sub,
    mat3_trace,
    mat3_transpose,
    mat3_transpose_mul,
    mat3_transpose_mul_add,
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
# Models whose stress turns with the rest frame, P(F Q^T) = P(F) Q^T for every rotation Q (objective
# and isotropic): their float64 step reads R^-1 of Dm = Q R instead of Dm^-1 (``kernels.rotated_rest``).
# An objective but anisotropic law belongs in ROTATION_INVARIANT and not here.
REST_FRAME_INVARIANT = ("stvk", "corotated", "neohookean")
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
    """``lam tr(strain) I + 2 mu strain``: Cauchy stress for ``linear``, 2nd Piola-Kirchhoff for ``stvk``.
    The trace term is added to the diagonal alone: ``+ s I`` as nine multiply-adds left six of them
    adding ``s * 0`` in the lane loops (LLVM may not drop them: ``s`` might be infinite)."""
    return mat3_add_diagonal(mat3_scale(strain, 2.0 * mu), lam * mat3_trace(strain))


@njit
def hooke_energy_density(strain, lam, mu):
    """``mu strain:strain + lam/2 tr(strain)^2`` [J/m^3]."""
    tr = mat3_trace(strain)
    return mu * mat3_ddot(strain, strain) + 0.5 * lam * tr * tr


# ---------------------------------------------------------------------------------------------
# linear


@njit
def linear_first_piola(F, lam, mu):
    return linear_weighted_first_piola(F, 1.0, lam, mu)


@njit
def linear_weighted_first_piola(F, weight, lam, mu):
    """``weight P`` of ``linear_first_piola``: Hooke's law with ``weight lam`` and ``weight mu``."""
    return hooke_stress(small_strain(F), weight * lam, weight * mu)


@njit
def linear_energy_density(F, lam, mu):
    return hooke_energy_density(small_strain(F), lam, mu)


# ---------------------------------------------------------------------------------------------
# St. Venant-Kirchhoff


@njit
def stvk_first_piola(F, lam, mu):
    return stvk_weighted_first_piola(F, 1.0, lam, mu)


@njit
def stvk_weighted_first_piola(F, weight, lam, mu):
    """``weight P`` [Pa times weight's unit] of ``stvk_first_piola``: ``F S'``, ``S' = weight mu G +
    weight lam/2 tr(G) I`` with ``G = F^T F - I = 2E``: the weight costs two multiplies a lane and
    E's 1/2 none.  The lane loops of ``kernels.blocked`` pass ``weight = -V0``."""
    G = mat3_add_diagonal(mat3_transpose_mul(F, F), -1.0)
    return mat3_mul(F, mat3_add_diagonal(mat3_scale(G, weight * mu), weight * (0.5 * lam) * mat3_trace(G)))


@njit
def stvk_energy_density(F, lam, mu):
    return hooke_energy_density(green_strain(F), lam, mu)


# ---------------------------------------------------------------------------------------------
# corotated (inversion-aware)


@njit
def corotated_stress(F, R, lam, mu):
    """``P = 2 mu (F - R) + lam tr(R^T F - I) R`` [Pa] for ``F`` and its rotation ``R`` (9-tuples)."""
    return corotated_weighted_stress(F, R, 1.0, 1.0, lam, mu)


@njit
def corotated_weighted_stress(F, Z, inv, weight, lam, mu):
    """``weight P`` [Pa times weight's unit] of ``corotated_stress`` with ``R = inv Z``: ``2 mu
    weight F + weight (lam (inv Z : F - 3) - 2 mu) inv Z``, the factors gathered into two scalars.
    The lane loops of ``kernels.blocked`` pass Newton's scaled iterate (``polar3``) and ``weight =
    -V0``, so that they form neither R nor ``V0 P``: 18 multiplies a tet fewer.  Written with
    ``mat3``'s ``*_inline`` helpers: inlined into a lane loop, it called the ordinary ones as
    functions there, and the loop compiled to scalar code (54.7 against 7.7 ns a tet)."""
    k = lam * (inv * mat3_ddot_inline(Z, F) - 3.0) - 2.0 * mu
    return mat3_add_scaled_inline(mat3_scale_inline(F, 2.0 * mu * weight), Z, weight * k * inv)


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
    return neohookean_weighted_first_piola(F, 1.0, lam, mu)


@njit
def neohookean_weighted_first_piola(F, weight, lam, mu):
    """``weight P`` [Pa times weight's unit]: ``weight mu (1 - 1/(Ic + 1)) F + weight lam (J - alpha)
    cof F``, the weight folded into the two scalars (``weight = -V0`` in ``kernels.blocked``)."""
    Ic = mat3_ddot(F, F)
    J = mat3_det(F)
    alpha = 1.0 + 0.75 * mu / lam
    return mat3_add_scaled(mat3_scale(F, weight * mu * (1.0 - 1.0 / (Ic + 1.0))), mat3_cofactor(F),
                           weight * lam * (J - alpha))


@njit
def neohookean_energy_density(F, lam, mu):
    Ic = mat3_ddot(F, F)
    J = mat3_det(F)
    alpha = 1.0 + 0.75 * mu / lam
    rest = 0.5 * lam * (1.0 - alpha) ** 2 - 0.5 * mu * math.log(4.0)   # Psi(I): shifted to zero
    return 0.5 * mu * (Ic - 3.0) + 0.5 * lam * (J - alpha) ** 2 - 0.5 * mu * math.log(Ic + 1.0) - rest


# ---------------------------------------------------------------------------------------------
# displacement form: the same stresses as functions of H = F - I (the float32 step)
#
# In float32, ``F`` near ``I`` keeps about 7 digits: a steel strain of 1e-6 would be lost in the
# rounding of F's diagonal, and a stress that is a difference of O(1) terms (``F S``, Neo-Hookean's
# ``mu F`` against ``lam alpha cof F``) would cancel to noise.  These forms take the displacement
# gradient ``H = Du Dm^-1`` (``u = x - X``, small where the strain is small) and are written so that
# every term that must vanish at rest is a product of entries of ``H``.  Their constants are float32
# (``np.float32``): a float64 literal would promote a float32 lane loop to float64; in a float64
# call they promote exactly.  Corotated has no such form here: its ``F - R`` cancels.

_ONE = np.float32(1.0)
_TWO = np.float32(2.0)
_FOUR = np.float32(4.0)
_HALF = np.float32(0.5)
_THREE_QUARTERS = np.float32(0.75)

DISPLACEMENT_FORM_MODELS = ("linear", "stvk", "neohookean")


@njit
def linear_first_piola_displacement(H, lam, mu):
    """``lam tr(H) I + mu (H + H^T)`` [Pa]: ``linear_first_piola`` at ``F = I + H``."""
    return linear_weighted_first_piola_displacement(H, _ONE, lam, mu)


@njit
def linear_weighted_first_piola_displacement(H, weight, lam, mu):
    """``weight P`` of ``linear_first_piola_displacement``, the weight in the two scalars (the lane
    loops of ``kernels.blocked`` pass ``weight = -V0``)."""
    return mat3_add_diagonal(mat3_scale(mat3_add(H, mat3_transpose(H)), weight * mu), weight * lam * mat3_trace(H))


@njit
def stvk_first_piola_displacement(H, lam, mu):
    """``P = S + H S`` with ``G = H + H^T + H^T H`` (= 2E), ``S = lam/2 tr(G) I + mu G`` [Pa]:
    ``stvk_first_piola`` at ``F = I + H``."""
    return stvk_weighted_first_piola_displacement(H, _ONE, lam, mu)


@njit
def stvk_weighted_first_piola_displacement(H, weight, lam, mu):
    """``weight P`` of ``stvk_first_piola_displacement``: ``S' + H S'`` with ``S' = weight S``, the
    weight in S's two scalars."""
    G = mat3_transpose_mul_add(H, H, mat3_add(H, mat3_transpose(H)))
    S = mat3_add_diagonal(mat3_scale(G, weight * mu), weight * (_HALF * lam) * mat3_trace(G))
    return mat3_mul_add(H, S, S)


@njit
def neohookean_first_piola_displacement(H, lam, mu):
    """``neohookean_first_piola`` at ``F = I + H`` [Pa], rearranged so that nothing cancels at rest
    (``neohookean_weighted_first_piola_displacement``)."""
    return neohookean_weighted_first_piola_displacement(H, _ONE, lam, mu)


@njit
def neohookean_weighted_first_piola_displacement(H, weight, lam, mu):
    """``weight P`` of ``neohookean_first_piola`` at ``F = I + H`` [Pa times weight's unit].

    With ``Ic / (Ic + 1) = 3/4 + s``, ``s = (Ic - 3) / (4 (Ic + 1))``, and ``alpha = 1 + 3 mu / (4
    lam)``, the law is ``P = (a + b) F + (c - a) cof F`` with ``a = 3/4 mu``, ``b = mu s``, ``c = lam
    (J - 1)``.  Put ``F = I + H`` and ``cof F = (1 + tr H) I - H^T + cof H`` in it:

        ``P = (a + b) H + (c - a) (cof H - H^T) + (b + c + (c - a) tr H) I``,

    where ``b``, ``c`` and ``tr H`` vanish at rest, ``Ic - 3 = 2 tr H + H:H`` and ``J - 1 = tr H +
    tr(cof H) + det H``: no O(1) terms cancel.  The weight goes into the three scalars.
    """
    tr = mat3_trace(H)
    cof_H = mat3_cofactor(H)
    J_minus_1 = tr + mat3_trace(cof_H) + mat3_det_from_cofactor(H, cof_H)
    Ic_minus_3 = _TWO * tr + mat3_ddot(H, H)
    a = _THREE_QUARTERS * mu
    b = mu * (Ic_minus_3 / (_FOUR * (_FOUR + Ic_minus_3)))
    c = lam * J_minus_1
    c_minus_a = c - a
    diagonal = weight * (b + c + c_minus_a * tr)
    return mat3_add_scaled(mat3_add_diagonal(mat3_scale(H, weight * (a + b)), diagonal),
                           mat3_sub(cof_H, mat3_transpose(H)), weight * c_minus_a)


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


# The same in the per-frame kernels, whose callers pass the model id as a compile-time constant
# (``kernels.jit.CompileTimeConstant``): a kernel then compiles its scene's law alone (corotated's
# polar decomposition took 20-30 s of a StVK scene's cold start).  A plain int compiles them all.

def material_first_piola(model, F, lam, mu):
    """``first_piola``; compiled code only (``_material_law``)."""
    raise NotImplementedError("material_first_piola runs in compiled code only")


def material_energy_density(model, F, lam, mu):
    """``energy_density``; compiled code only (``_material_law``)."""
    raise NotImplementedError("material_energy_density runs in compiled code only")


def _material_law(every_model, laws):
    """The overload of a law taking ``(model, F, lam, mu)``: ``laws[model]`` alone for a constant
    ``model`` (compiled before the implementation calling it is typed, as ``kernels.blocked``'s
    lane loops are), ``every_model`` for an int."""
    def implementation(model, F, lam, mu):
        if not isinstance(model, types.IntegerLiteral):
            return lambda model, F, lam, mu: every_model(model, F, lam, mu)
        law = laws[model.literal_value]
        law.compile((F, lam, mu))
        return lambda model, F, lam, mu: law(F, lam, mu)
    return implementation


overload(material_first_piola, prefer_literal=True, inline="always")(_material_law(first_piola, {
    STVK: stvk_first_piola, NEOHOOKEAN: neohookean_first_piola, COROTATED: corotated_first_piola,
    LINEAR: linear_first_piola}))
overload(material_energy_density, prefer_literal=True, inline="always")(_material_law(energy_density, {
    STVK: stvk_energy_density, NEOHOOKEAN: neohookean_energy_density, COROTATED: corotated_energy_density,
    LINEAR: linear_energy_density}))
