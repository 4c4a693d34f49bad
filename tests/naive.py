"""Naive NumPy reference implementations of the FEM formulas, for checking the Numba kernels.

Written from the seed notes (``/work/shared/seed/elastic_solids_notes.md``) and Sifakis & Barbic
2012, not from ``softsim``: plain per-tet loops, ``np.linalg`` and full (3, 3) arrays, no 9-tuples
and no hand-written SVD.  Slow and obvious on purpose (stumpy's ``tests/naive.py`` pattern).

The models take the Lame parameters ``lam``, ``mu`` [Pa] that the model uses internally (for
``neohookean`` the remapped ones), exactly as the kernels do.
"""

import numpy as np

I3 = np.eye(3)

# Vertex triples of the 4 faces of a tet, and the vertex opposite each.
FACES = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
OPPOSITE = (0, 1, 2, 3)


# ---------------------------------------------------------------------------------------------
# Hooke's law as written in the notes (6x6 matrix on Voigt vectors)


def hooke_matrix(E, nu):
    """The notes' isotropic 6x6 Hooke matrix, Voigt order (11, 22, 33, 23, 13, 12), engineering shear."""
    C = np.zeros((6, 6))
    C[:3, :3] = nu
    C[0, 0] = C[1, 1] = C[2, 2] = 1.0 - nu
    C[3, 3] = C[4, 4] = C[5, 5] = (1.0 - 2.0 * nu) / 2.0
    return E / ((1.0 + nu) * (1.0 - 2.0 * nu)) * C


def notes_stress(strain, E, nu):
    """Stress (3, 3) from a symmetric strain (3, 3) through the notes' 6x6 matrix."""
    e = strain
    voigt = np.array([e[0, 0], e[1, 1], e[2, 2], 2.0 * e[1, 2], 2.0 * e[0, 2], 2.0 * e[0, 1]])
    s = hooke_matrix(E, nu) @ voigt
    return np.array([[s[0], s[5], s[4]],
                     [s[5], s[1], s[3]],
                     [s[4], s[3], s[2]]])


# ---------------------------------------------------------------------------------------------
# kinematics


def shape_matrix(P, tet):
    """Edge matrix ``[p1-p0, p2-p0, p3-p0]`` (columns) of one tet from positions ``P`` (n, 3)."""
    p = P[list(tet)]
    return np.column_stack([p[1] - p[0], p[2] - p[0], p[3] - p[0]])


def deformation_gradients(x, X, tets):
    """``F = Ds Dm^-1`` per tet, shape (m, 3, 3)."""
    out = np.empty((len(tets), 3, 3))
    for e, tet in enumerate(tets):
        out[e] = shape_matrix(x, tet) @ np.linalg.inv(shape_matrix(X, tet))
    return out


def rest_volumes(X, tets):
    """Signed rest volume per tet, ``det(Dm) / 6``."""
    return np.array([np.linalg.det(shape_matrix(X, tet)) / 6.0 for tet in tets])


# ---------------------------------------------------------------------------------------------
# material laws: energy density psi(F) and first Piola-Kirchhoff stress P(F) = dpsi/dF


def polar_rotation(F):
    """``(R, s)``: R = U V^T from ``np.linalg.svd`` with any reflection moved into the smallest
    singular value (Irving et al. 2004), so R is a proper rotation and s[2] < 0 iff det F < 0."""
    U, s, Vt = np.linalg.svd(F)          # s descending, all >= 0
    s = s.copy()
    if np.linalg.det(U) < 0:
        U = U.copy()
        U[:, 2] *= -1.0
        s[2] *= -1.0
    if np.linalg.det(Vt) < 0:
        Vt = Vt.copy()
        Vt[2, :] *= -1.0
        s[2] *= -1.0
    return U @ Vt, s


def _neohookean_alpha(lam, mu):
    # Smith, de Goes & Kim 2018: alpha makes P(I) = 0:  mu (1 - 1/4) + lam (1 - alpha) = 0.
    return 1.0 + mu / lam - mu / (4.0 * lam)


def psi(model, F, lam, mu):
    """Energy density [J/m^3] of ``model`` at ``F`` (3, 3), zero at ``F = I``."""
    if model == "linear":
        eps = 0.5 * (F + F.T) - I3
        return mu * np.sum(eps * eps) + 0.5 * lam * np.trace(eps) ** 2
    if model == "stvk":
        E = 0.5 * (F.T @ F - I3)
        return mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2
    if model == "corotated":
        R, _ = polar_rotation(F)
        return mu * np.sum((F - R) ** 2) + 0.5 * lam * np.trace(R.T @ F - I3) ** 2
    if model == "neohookean":
        alpha = _neohookean_alpha(lam, mu)

        def raw(G):
            Ic = np.sum(G * G)
            J = np.linalg.det(G)
            return 0.5 * mu * (Ic - 3.0) + 0.5 * lam * (J - alpha) ** 2 - 0.5 * mu * np.log(Ic + 1.0)

        return raw(F) - raw(I3)
    raise ValueError(model)


def pk1(model, F, lam, mu):
    """First Piola-Kirchhoff stress [Pa], (3, 3)."""
    if model == "linear":
        eps = 0.5 * (F + F.T) - I3
        return lam * np.trace(eps) * I3 + 2.0 * mu * eps
    if model == "stvk":
        E = 0.5 * (F.T @ F - I3)
        return F @ (lam * np.trace(E) * I3 + 2.0 * mu * E)
    if model == "corotated":
        R, _ = polar_rotation(F)
        return 2.0 * mu * (F - R) + lam * np.trace(R.T @ F - I3) * R
    if model == "neohookean":
        alpha = _neohookean_alpha(lam, mu)
        Ic = np.sum(F * F)
        J = np.linalg.det(F)
        dJdF = J * np.linalg.inv(F).T
        return mu * (1.0 - 1.0 / (Ic + 1.0)) * F + lam * (J - alpha) * dJdF
    raise ValueError(model)


# ---------------------------------------------------------------------------------------------
# assembly


def elastic_energy(x, X, tets, model, lam, mu):
    """``sum_e V0_e psi(F_e)`` [J]."""
    Fs = deformation_gradients(x, X, tets)
    V0 = rest_volumes(X, tets)
    return float(sum(V0[e] * psi(model, Fs[e], lam, mu) for e in range(len(tets))))


def elastic_forces(x, X, tets, model, lam, mu):
    """Vertex forces (n, 3) [N]: per tet ``H = -V0 P Dm^-T``, columns on corners 1..3, f0 = -sum."""
    f = np.zeros_like(x, dtype=np.float64)
    for tet in tets:
        Dm = shape_matrix(X, tet)
        V0 = np.linalg.det(Dm) / 6.0
        F = shape_matrix(x, tet) @ np.linalg.inv(Dm)
        H = -V0 * pk1(model, F, lam, mu) @ np.linalg.inv(Dm).T
        f[tet[1]] += H[:, 0]
        f[tet[2]] += H[:, 1]
        f[tet[3]] += H[:, 2]
        f[tet[0]] -= H[:, 0] + H[:, 1] + H[:, 2]
    return f


def face_recipe_forces(x, tets, cauchy):
    """The notes' per-face recipe: for each face (i, j, k) with its normal pointing away from the
    opposite vertex in the *deformed* configuration, ``F_ijk = 1/2 sigma [(xj - xi) x (xk - xi)]``
    (= area * sigma n), and a third of it added to each of i, j, k.  ``cauchy``: (m, 3, 3)."""
    f = np.zeros_like(x, dtype=np.float64)
    for e, tet in enumerate(tets):
        for face, opp in zip(FACES, OPPOSITE):
            i, j, k = (tet[a] for a in face)
            area_vector = 0.5 * np.cross(x[j] - x[i], x[k] - x[i])
            if np.dot(area_vector, x[tet[opp]] - x[i]) > 0.0:   # points inward: flip
                area_vector = -area_vector
            face_force = cauchy[e] @ area_vector
            for v in (i, j, k):
                f[v] += face_force / 3.0
    return f
