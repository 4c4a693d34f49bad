"""Analytic answers of the verification cases, from a scene's own parameters, and the arithmetic of
refinement studies (observed orders, Richardson extrapolation).

Every function takes SI values [m, Pa, kg/m^3, m/s^2] and returns SI values; nothing here knows
about meshes or the time loop.
"""

import math

import numpy as np

# First root of the clamped-free beam's frequency equation cos(bL) cosh(bL) = -1.
CANTILEVER_BETA1_L = 1.8751040687119611


def rectangle_shear_coefficient(poissons_ratio):
    """Timoshenko shear coefficient ``kappa = 10 (1 + nu) / (12 + 11 nu)`` of a rectangular section
    (Cowper 1966)."""
    nu = poissons_ratio
    return 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)


def cantilever_tip_deflection(length, width, thickness, youngs_modulus, poissons_ratio, density, gravity):
    """Static tip deflection [m] of a cantilever of rectangular section under its own weight.

    Returns ``(euler_bernoulli, timoshenko)``: ``q L^4 / (8 E I)`` with ``q = rho g A`` and
    ``I = w t^3 / 12``, and that plus the shear deflection ``q L^2 / (2 kappa G A)``.
    """
    area = width * thickness
    inertia = width * thickness ** 3 / 12.0
    q = density * gravity * area
    bending = q * length ** 4 / (8.0 * youngs_modulus * inertia)
    shear_modulus = youngs_modulus / (2.0 * (1.0 + poissons_ratio))
    shear = q * length ** 2 / (2.0 * rectangle_shear_coefficient(poissons_ratio) * shear_modulus * area)
    return bending, bending + shear


def cantilever_frequency(length, thickness, youngs_modulus, density):
    """First bending frequency [rad/s] of an Euler-Bernoulli cantilever (bending across ``thickness``):
    ``(beta_1 L)^2 sqrt(E I / (rho A L^4))`` with ``I / A = t^2 / 12``."""
    return CANTILEVER_BETA1_L ** 2 * math.sqrt(youngs_modulus * thickness ** 2 / (12.0 * density)) / length ** 2


def bar_wave_speed(youngs_modulus, density):
    """Bar (1D) wave speed ``sqrt(E / rho)`` [m/s]."""
    return math.sqrt(youngs_modulus / density)


def fixed_free_bar_period(length, youngs_modulus, density):
    """Period [s] of the first axial mode of a fixed-free bar, ``4 L / sqrt(E / rho)``."""
    return 4.0 * length / bar_wave_speed(youngs_modulus, density)


def uniaxial_small_strain(length, width, youngs_modulus, poissons_ratio, stress):
    """``(elongation, contraction)`` [m] of a bar under axial stress ``stress`` [Pa], small strain:
    ``sigma L / E`` and ``nu sigma w / E`` (contraction counted positive)."""
    strain = stress / youngs_modulus
    return strain * length, poissons_ratio * strain * width


def free_fall_drop(gravity, time):
    """Distance [m] a body released from rest falls in ``time`` [s]: ``g t^2 / 2``."""
    return 0.5 * gravity * time ** 2


def centrifugal_strain(youngs_modulus, density, angular_speed, radius):
    """The strain scale ``rho omega^2 R^2 / E`` of a body of size ``radius`` spinning at ``omega``."""
    return density * angular_speed ** 2 * radius ** 2 / youngs_modulus


# ---------------------------------------------------------------------------------------------
# Refinement studies


def observed_orders(parameters, errors):
    """Observed order ``log(e_{i-1} / e_i) / log(p_{i-1} / p_i)`` of each rung after the first
    (None where an error is zero or the parameter did not change), for a ladder ordered from
    coarse to fine."""
    orders = [None]
    for (p0, e0), (p1, e1) in zip(zip(parameters, errors), zip(parameters[1:], errors[1:])):
        if e0 > 0.0 and e1 > 0.0 and p0 != p1:
            orders.append(math.log(e0 / e1) / math.log(p0 / p1))
        else:
            orders.append(None)
    return orders


def self_convergence_orders(parameters, values):
    """Order from successive differences of the computed values, without the exact answer: with
    ``q(p) = q* + C p^k``, ``k`` solves ``(q0 - q1) / (q1 - q2) = (p0^k - p1^k) / (p1^k - p2^k)``.

    One entry per rung (None for the first two, or where the differences change sign or vanish).
    """
    orders = [None] * min(2, len(values))
    for i in range(2, len(values)):
        orders.append(_three_point_order(parameters[i - 2:i + 1], values[i - 2:i + 1]))
    return orders


def _three_point_order(p, q):
    d1, d2 = q[0] - q[1], q[1] - q[2]
    if d1 == 0.0 or d2 == 0.0 or (d1 > 0) != (d2 > 0):
        return None
    target = d1 / d2

    def ratio(k):
        return (p[0] ** k - p[1] ** k) / (p[1] ** k - p[2] ** k)

    lo, hi = 0.05, 8.0
    if not (ratio(lo) - target) * (ratio(hi) - target) < 0.0:
        return None
    for _ in range(100):               # ratio(k) increases with k for p0 > p1 > p2
        mid = 0.5 * (lo + hi)
        if (ratio(mid) - target) * (ratio(lo) - target) > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def richardson_limit(parameters, values, order=None):
    """Extrapolated ``q(p -> 0)`` from the last rungs of a ladder, with ``q = q* + C p^k``.

    order None: ``k`` from the last three rungs (``self_convergence_orders``), falling back to 2
    where that is undefined.  Returns ``(limit, k, spread)``: ``spread`` is how far the limit moves
    between the fitted ``k`` and ``k = 2`` and between the last two pairs of rungs, a rough
    uncertainty of the limit itself [same unit as q].
    """
    p = [float(v) for v in parameters]
    q = [float(v) for v in values]
    if len(q) < 2:
        raise ValueError("richardson_limit needs at least two rungs")

    def two_point(i, k):
        r = (p[i - 1] / p[i]) ** k
        return q[i] + (q[i] - q[i - 1]) / (r - 1.0)

    k = order
    if k is None:
        k = _three_point_order(p[-3:], q[-3:]) if len(q) >= 3 else None
        k = 2.0 if k is None else k
    limit = two_point(len(q) - 1, k)
    others = [two_point(len(q) - 1, 2.0)]
    if len(q) >= 3:
        others.append(two_point(len(q) - 2, k))
    spread = max(abs(limit - other) for other in others)
    return limit, k, spread


def fitted_order(parameters, errors):
    """Slope of ``log error`` against ``log parameter`` (least squares, numpy.polyfit) over the
    rungs with a positive error; None with fewer than two."""
    pairs = [(p, e) for p, e in zip(parameters, errors) if e is not None and e > 0.0 and p > 0.0]
    if len(pairs) < 2 or len({p for p, _ in pairs}) < 2:
        return None
    x = np.log([p for p, _ in pairs])
    y = np.log([e for _, e in pairs])
    return float(np.polyfit(x, y, 1)[0])


# ---------------------------------------------------------------------------------------------
# The exact homogeneous uniaxial stretch of each material law (NumPy, independent of the kernels)


def _diagonal_first_piola(model, a, b, lam, mu):
    """``(P11, P22)`` [Pa] of ``F = diag(a, b, b)`` for material law ``model`` with its Lame
    parameters ``lam``, ``mu`` (as ``softsim.materials.models.model_lame_parameters`` gives them)."""
    if model == "linear":
        trace = (a - 1.0) + 2.0 * (b - 1.0)
        return lam * trace + 2.0 * mu * (a - 1.0), lam * trace + 2.0 * mu * (b - 1.0)
    if model == "stvk":
        e1, e2 = 0.5 * (a * a - 1.0), 0.5 * (b * b - 1.0)
        trace = e1 + 2.0 * e2
        return a * (lam * trace + 2.0 * mu * e1), b * (lam * trace + 2.0 * mu * e2)
    if model == "corotated":            # R = I for a diagonal F with positive entries
        trace = (a - 1.0) + 2.0 * (b - 1.0)
        return 2.0 * mu * (a - 1.0) + lam * trace, 2.0 * mu * (b - 1.0) + lam * trace
    if model == "neohookean":           # Smith et al. 2018, P = mu (1 - 1/(Ic + 1)) F + lam (J - alpha) cof F
        ic = a * a + 2.0 * b * b
        J = a * b * b
        alpha = 1.0 + 0.75 * mu / lam
        scale = mu * (1.0 - 1.0 / (ic + 1.0))
        return scale * a + lam * (J - alpha) * b * b, scale * b + lam * (J - alpha) * a * b
    raise ValueError(f"unknown material model {model!r}")


def uniaxial_stretches(model, lam, mu, stress):
    """Axial and lateral stretches ``(a, b)`` of the homogeneous state ``F = diag(a, b, b)`` with
    nominal stress ``P11 = stress``, ``P22 = P33 = 0`` under material law ``model`` (Newton on the
    two equations, from the small-strain answer)."""
    E = mu * (3.0 * lam + 2.0 * mu) / (lam + mu)
    nu = lam / (2.0 * (lam + mu))
    if model == "neohookean":       # small strain of the remapped constants: undo Smith's remapping
        mu0 = 0.75 * mu
        lam0 = lam - 5.0 * mu0 / 6.0
        E, nu = mu0 * (3.0 * lam0 + 2.0 * mu0) / (lam0 + mu0), lam0 / (2.0 * (lam0 + mu0))
    x = np.array([1.0 + stress / E, 1.0 - nu * stress / E])
    scale = max(abs(stress), 1e-300)
    for _ in range(60):
        residual = np.array(_diagonal_first_piola(model, x[0], x[1], lam, mu)) - np.array([stress, 0.0])
        if np.abs(residual).max() <= 1e-14 * scale:
            break
        jacobian = np.empty((2, 2))
        for k in range(2):
            h = 1e-7 * x[k]
            up, down = x.copy(), x.copy()
            up[k] += h
            down[k] -= h
            jacobian[:, k] = (np.array(_diagonal_first_piola(model, *up, lam, mu))
                              - np.array(_diagonal_first_piola(model, *down, lam, mu))) / (2.0 * h)
        x = x - np.linalg.solve(jacobian, residual)
    return float(x[0]), float(x[1])
