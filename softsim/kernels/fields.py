"""Per-tetrahedron output fields of a state: strain, Cauchy stress and its invariants, J.

Evaluated only at frame times and only for the fields a scene asks for (``output.fields``), never
per step.  Per tet ``e`` with ``F = Ds Dm^-1`` (Sifakis & Barbic 2012) and the model's first
Piola-Kirchhoff stress ``P(F)`` (``materials.models``):

- ``strain``: Green strain ``E = 1/2 (F^T F - I)``; for ``linear`` the small strain
  ``eps = 1/2 (F + F^T) - I`` the model uses [-], (m, 3, 3)
- ``stress``: Cauchy stress ``sigma = P F^T / J`` (for ``linear``, ``sigma = P``) [Pa], (m, 3, 3)
- ``pressure``: ``p = -tr(sigma) / 3``, positive in compression [Pa], (m,)
- ``deviatoric_stress``: ``s = sigma + p I`` (trace free) [Pa], (m, 3, 3)
- ``von_mises``: ``sqrt(3/2 s:s)`` [Pa], (m,)
- ``J``: ``det F``, volume ratio [-], (m,)

For an element squashed flat (``J = 0``) the Cauchy stress of a nonlinear model is not defined
and comes out non-finite; the stability guard stops a run before such a frame is written.
"""

import math

import numpy as np
from numba import prange

from ..materials.models import LINEAR, material_first_piola
from .deformation import deformation_gradient, edge_matrix, green_strain, small_strain
from .jit import njit_parallel
from .mat3 import mat3_det, mat3_load, mat3_mul_transpose_b, mat3_scale, mat3_trace

TET_FIELDS = ("strain", "stress", "pressure", "deviatoric_stress", "von_mises", "J")
# Per-tet shape of each field (after the tet axis).
TET_FIELD_SHAPES = {"strain": (3, 3), "stress": (3, 3), "pressure": (), "deviatoric_stress": (3, 3),
                    "von_mises": (), "J": ()}


@njit_parallel
def tet_fields_kernel(x, tets, Dm_inv, model, lam, mu, strain, stress, pressure, deviatoric, von_mises, J):
    """Fill the output arrays for every tet; an output of length 0 is not asked for and not computed.

    x (n, 3) [m]; tets (m, 4); Dm_inv (m, 3, 3) [1/m]; model id, lam, mu [Pa].
    Outputs: strain, stress, deviatoric (m, 3, 3) or (0, 3, 3); pressure, von_mises, J (m,) or (0,).
    """
    want_strain = strain.shape[0] > 0
    want_stress = stress.shape[0] > 0
    want_pressure = pressure.shape[0] > 0
    want_deviatoric = deviatoric.shape[0] > 0
    want_von_mises = von_mises.shape[0] > 0
    want_J = J.shape[0] > 0
    need_sigma = want_stress or want_pressure or want_deviatoric or want_von_mises
    for tet in prange(tets.shape[0]):
        e = np.int64(tet)             # one specialisation of the callees (``kernels.jit.njit_parallel``)
        F = deformation_gradient(edge_matrix(x, tets, e), mat3_load(Dm_inv, e))
        det = mat3_det(F)
        if want_J:
            J[e] = det
        if want_strain:
            E = small_strain(F) if model == LINEAR else green_strain(F)
            for r in range(3):
                for c in range(3):
                    strain[e, r, c] = E[3 * r + c]
        if need_sigma:
            P = material_first_piola(model, F, lam, mu)
            sigma = P if model == LINEAR else mat3_scale(mat3_mul_transpose_b(P, F), 1.0 / det)
            p = -mat3_trace(sigma) / 3.0
            if want_stress:
                for r in range(3):
                    for c in range(3):
                        stress[e, r, c] = sigma[3 * r + c]
            if want_pressure:
                pressure[e] = p
            if want_deviatoric or want_von_mises:
                ss = 0.0
                for r in range(3):
                    for c in range(3):
                        s_rc = sigma[3 * r + c] + (p if r == c else 0.0)
                        ss += s_rc * s_rc
                        if want_deviatoric:
                            deviatoric[e, r, c] = s_rc
                if want_von_mises:
                    von_mises[e] = math.sqrt(1.5 * ss)


def tet_fields(x, tets, Dm_inv, model, lam, mu, names):
    """``{name: array}`` of the per-tet fields ``names`` (a subset of ``TET_FIELDS``) at positions x.

    x (n, 3) [m]; tets (m, 4); Dm_inv (m, 3, 3) [1/m]; model: material id; lam, mu [Pa].  Arrays are
    in the order of ``tets``, float64, shapes ``(m, *TET_FIELD_SHAPES[name])``.  Returns ``{}`` (and
    runs no kernel) when ``names`` holds none of ``TET_FIELDS``.
    """
    wanted = [name for name in names if name in TET_FIELD_SHAPES]
    if not wanted:
        return {}
    m = tets.shape[0]
    out = {name: np.empty((m if name in wanted else 0, *shape)) for name, shape in TET_FIELD_SHAPES.items()}
    tet_fields_kernel(x, tets, Dm_inv, model, lam, mu, out["strain"], out["stress"], out["pressure"],
                      out["deviatoric_stress"], out["von_mises"], out["J"])
    return {name: out[name] for name in wanted}
