"""Elastic constants: Lame parameters from Young's modulus and Poisson's ratio."""

from ..errors import ConfigError


def lame_parameters(youngs_modulus, poissons_ratio):
    """Lame ``(lambda, mu)`` [Pa] of isotropic Hooke's law from ``E`` [Pa] and ``nu`` (-1 < nu < 0.5).

    ``lambda = E nu / ((1 + nu)(1 - 2 nu))``, ``mu = E / (2 (1 + nu))``: the constants of the
    notes' 6x6 Hooke matrix.
    """
    E = float(youngs_modulus)
    nu = float(poissons_ratio)
    if not E > 0.0:
        raise ConfigError(f"material.youngs_modulus = {youngs_modulus!r}: must be a positive number of pascals")
    if not -1.0 < nu < 0.5:
        raise ConfigError(f"material.poissons_ratio = {poissons_ratio!r}: must be greater than -1 and less than 0.5")
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    mu = E / (2.0 * (1.0 + nu))
    return lam, mu


def stable_neohookean_parameters(lam, mu):
    """Smith et al. 2018 (section 3.4) remapping of Lame parameters for stable Neo-Hookean.

    With ``mu' = 4/3 mu`` and ``lambda' = lambda + 5/6 mu`` the energy linearises at rest to Hooke's
    law with the given ``lambda``, ``mu``: the model then has the user's E and nu at small strain.
    """
    return lam + 5.0 * mu / 6.0, 4.0 * mu / 3.0
