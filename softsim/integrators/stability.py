"""Symplectic Euler's exact stability limit from the largest eigenvalue of ``M^-1 K``.

Undamped symplectic Euler on ``M a = -K u`` is stable iff ``dt < 2 / omega_max`` with
``omega_max^2 = lambda_max(M^-1 K)``.  ``largest_frequency_squared`` finds ``lambda_max`` without
assembling anything:

- ``K`` is the tangent stiffness at positions ``x``, applied matrix-free as a central directional
  derivative of the elastic forces, ``K u = -(f(x + eps u) - f(x - eps u)) / (2 eps)``, with the
  time loop's blocked force kernels where the model steps in float64 with the colour scatter
  (``kernels.blocked``, every block in order on one thread:
  ``symplectic_euler.elastic_vertex_forces``), else the per-tet ones (``kernels.forces``), so it
  is the tangent of whichever material model the scene uses, at rest or at a deformed state.
  ``eps`` moves the fastest vertex by ``1e-6`` of the smallest element altitude at ``x`` (strains of about 1e-6:
  truncation error ~1e-12 relative, round-off ~1e-10 relative for metre-sized coordinates).  The
  guard's estimates (``tol`` 1e-2) take forward differences from the forces at ``x`` instead where
  no element is inverted, ``K u = -(f(x + eps u) - f(x)) / eps``: one force evaluation an
  application, truncation error ~1e-6 relative (measured within 6e-7 of the central value over
  the stress scenes of ``softsim stability``, the same iteration counts).  Where the forces jump
  (corotated's at an exact reflection) a difference of forces measures the jump, and the two forms
  disagree: the guard keeps the central one where an element is inverted.
- Held components (``model.held``, which includes every massless vertex) do not move: they are
  projected out, so the operator acts on the free components only.
- Eigenvalues are those of the symmetric form ``A = M^-1/2 K M^-1/2`` (same spectrum as
  ``M^-1 K``), found by Lanczos with full reorthogonalisation and explicit restarts from the best
  Ritz vector (at most ``cycle`` stored vectors, so memory stays ``cycle x 3n`` floats).  The
  start vector comes from a fixed-seed RNG: the same model gives the same bits.  Ritz values lie
  below ``lambda_max`` and converge to it from below; Lanczos targets the algebraically largest
  eigenvalue, so a deformed state whose tangent has negative eigenvalues (buckling) is handled.
- Ground: a vertex pressed into the ground feels a penalty spring of at most
  ``model.contact_stiffness_bound[i]`` [N/m] along z.  The worst case, every boundary vertex in
  contact at once, is added to ``A`` as the diagonal term ``contact_stiffness_bound[i] / mass[i]``
  on the z component of each free vertex.  Any real contact set has a subset of those springs, so
  its ``lambda_max`` is at most the one returned (and at most the elastic one plus
  ``max(contact_stiffness_bound / mass)``, the bound ``nodal_frequency_bound`` adds).

Rigorous bounds at rest, from each tet's own 12 x 12 Hooke stiffness ``K_e`` (no iteration):
``element_frequency_bound`` (Irons & Treharne 1971: ``max_e lambda_max(M_e^-1 K_e)`` with the tet's
share ``rho V / 4`` of each corner mass) and the tighter ``nodal_frequency_bound``
(``max_i sum_{e at i} lambda_max(K_e) / m_i``).  Both are >= ``lambda_max(M^-1 K)`` at rest; the
benchmark measured the nodal one 1.36x-3.7x above it (its step 1.17x-1.93x below the limit).  On
deformed states they use Hooke's law on the deformed geometry, which is not the models' tangent
and not a bound (stretched stvk / neohookean are stiffer).

Cost of ``largest_frequency_squared``: each operator application is two force evaluations
(central differences); 10-40 applications were needed on the meshes of ``benchmarks/stable_step_factor.py`` (0.02 s at
10k tets, 0.3-1.2 s at 100k tets on 2 cores, with the per-tet kernels).  The blocked kernels took
a force evaluation of a 90k-tet cube from 3.5 ms (the per-tet kernel on 2 threads and its CSR
gather) to 0.87 ms (one thread), and the guard's estimate (``iterations=80, tol=1e-2``, 10
applications) from 92 to 35 ms; the bouncing cube's 8 re-estimates at 12.6k tets from 0.10 to
0.07 s of a 0.35 s run.  Over the example's whole 1.5 s it bounces and rings, and the guard
re-estimated 119 times (10-15 applications each): 1.63 s of a 3.5 s run with central differences,
1.21 s with forward ones (the run 3.81 -> 3.29 s, medians of five alternating processes).
"""

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..kernels.blocked import cache_aligned_empty
from ..kernels.forces import compute_tet_corner_forces, gather_vertex_forces
from ..kernels.jit import njit
from ..kernels.polar3 import NEWTON_FIRST_STEPS
from ..kernels.stiffness import element_stiffness_maxima as stiffness_maxima
from ..kernels.tet_shape import tet_shapes
from ..materials.models import NEOHOOKEAN
from .symplectic_euler import SCRATCH, elastic_vertex_forces, force_buffer, step_arguments

log = logging.getLogger("softsim")

# Displacement of the fastest vertex in the finite difference, as a fraction of the smallest
# element altitude at x, and at least this fraction of the largest coordinate (round-off).
FD_RELATIVE_STEP = 1e-6
FD_COORDINATE_FLOOR = 1e-9
SEED = 20240607
# Lanczos steps taken before the residual test may stop it (a cheap guard against stopping on a
# Ritz value that is not yet the top one).
MIN_STEPS = 8


@dataclass(frozen=True)
class FrequencyEstimate:
    """Result of ``frequency_analysis``.

    lambda_max: largest eigenvalue of ``M^-1 K`` [1/s^2] (the Ritz value; see ``converged``).
    residual: ``|A y - lambda_max y|`` of the unit Ritz vector y [1/s^2]; an eigenvalue of A lies
    within it of ``lambda_max``.
    matvecs: operator applications (two force evaluations each with central differences, one with
    forward ones).
    converged: residual <= tol * lambda_max.
    mode: (n, 3) unit eigenvector of the symmetric form (zero on held components).
    """

    lambda_max: float
    residual: float
    matvecs: int
    converged: bool
    mode: np.ndarray


def _min_altitude(x, tets):
    """Smallest altitude [m] (3 V / largest face area) over the tets at positions ``x``."""
    return float(tet_shapes(x, tets)[0].min()) if tets.shape[0] else 0.0


def _blocked_force_arguments(model):
    """``(blocks, vertex_forces, buf)`` for ``elastic_vertex_forces`` where ``model`` steps in float64
    with the colour scatter (its blocks hold float64 rest data); None elsewhere (float32, csr, or a
    model built without blocks), whose forces come from the per-tet kernel.  The blocked kernels
    are the step's (``block_range_forces``), compiled as a function of their own, and 3-7x as fast
    as the per-tet one."""
    layout = model.blocks
    if layout is None or layout.scatter != "colour" or layout.rest.dtype != np.float64:
        return None
    forces = force_buffer(model)
    return step_arguments(model, forces)[0], forces, cache_aligned_empty(SCRATCH, np.float64)


class _SymmetricOperator:
    """``y -> (M^-1/2 K M^-1/2 + D) y`` on the free components, K by differences of the forces:
    central (two force evaluations an application), or forward from the forces at ``x``, evaluated
    once, at the first application (one an application; raises ``_NotFinite`` where those are not
    finite)."""

    def __init__(self, model, x, forward=False):
        self.model = model
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        free = ~np.asarray(model.held, dtype=np.bool_) & (model.inv_mass > 0.0)[:, None]
        self.free = free
        self.scale = np.where(free, np.sqrt(model.inv_mass)[:, None], 0.0)       # M^-1/2 P
        diagonal = np.zeros_like(self.x)
        if model.has_ground:
            diagonal[:, 2] = model.contact_stiffness_bound * model.inv_mass
        self.diagonal = np.where(free, diagonal, 0.0)
        h = _min_altitude(self.x, model.tets)
        self.step = max(FD_RELATIVE_STEP * h, FD_COORDINATE_FLOOR * float(np.abs(self.x).max(initial=0.0)))
        self.blocked = _blocked_force_arguments(model)
        self.corner = np.empty((model.tet_count, 4, 3)) if self.blocked is None else None
        self.f_plus = np.empty_like(self.x)
        self.f_minus = None if forward else np.empty_like(self.x)
        self.forward = forward
        self.f_x = None               # forward: the forces at x, evaluated at the first application

    def _forces(self, x, out):
        m = self.model
        if self.blocked is not None:
            blocks, vertex_forces, buf = self.blocked
            blocks[12][:] = NEWTON_FIRST_STEPS       # each evaluation as the step's first: the same law
            elastic_vertex_forces(x, blocks, m.material_id, m.lam, m.mu, vertex_forces, buf)
            out[...] = vertex_forces[:, :3]
            return out
        compute_tet_corner_forces(x, m.tets, m.Dm_inv, m.rest_volume, m.material_id, m.lam, m.mu, self.corner)
        gather_vertex_forces(self.corner, m.csr_offsets, m.csr_slots, out)
        return out

    def _forces_at_x(self):
        """The forces at ``x``, evaluated once; raises ``_NotFinite`` where they are not finite."""
        if self.f_x is None:
            f_x = self._forces(self.x, np.empty_like(self.x))
            if not np.isfinite(f_x).all():
                raise _NotFinite
            self.f_x = f_x
        return self.f_x

    def apply(self, y):
        """``A y`` for ``y`` (n, 3), zero on held components; returns a new (n, 3) array."""
        u = self.scale * y
        largest = float(np.abs(u).max(initial=0.0))
        if largest == 0.0:
            return self.diagonal * y
        eps = self.step / largest
        self._forces(self.x + eps * u, self.f_plus)
        if self.forward:
            Ku = (self._forces_at_x() - self.f_plus) / eps
        else:
            self._forces(self.x - eps * u, self.f_minus)
            Ku = (self.f_minus - self.f_plus) / (2.0 * eps)
        return self.scale * Ku + self.diagonal * y


class _NotFinite(Exception):
    """The operator gave a non-finite vector (the state's forces overflow)."""


def _largest_ritz(alpha, beta):
    """Largest eigenvalue and its eigenvector of the symmetric tridiagonal (alpha, beta[:-1])."""
    k = len(alpha)
    T = np.diag(alpha)
    if k > 1:
        off = beta[: k - 1]
        T += np.diag(off, 1) + np.diag(off, -1)
    w, S = np.linalg.eigh(T)
    return float(w[-1]), S[:, -1]


@njit
def _dot(a, b):
    """``a . b`` of two flat float64 vectors, on this thread.  numpy's ``@`` calls OpenBLAS, whose
    own threads spin against Numba's on a busy 2-core machine (a 100k-tet estimate: 9 s, not 0.85)."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


@njit
def _orthogonalise(w, basis, count):
    """``w -= (q . w) q`` for the first ``count`` rows q of ``basis``, twice (full
    reorthogonalisation: twice is enough), in place."""
    for _ in range(2):
        for r in range(count):
            c = _dot(basis[r], w)
            for i in range(w.shape[0]):
                w[i] -= c * basis[r, i]


def _lanczos_largest(apply, v0, dimension, iterations, tol, cycle):
    """Largest eigenpair of the symmetric operator ``apply`` on flat vectors, from ``v0``.

    Restarted Lanczos: cycles of at most ``cycle`` steps with full (twice repeated) Gram-Schmidt,
    each restarted from the best Ritz vector; the basis grows only as far as it is used.  Stops
    when the Ritz residual is below ``tol * |theta|``, when the Krylov space is invariant, or
    after ``iterations`` applications.  Returns ``(theta, residual, matvecs, converged, vector)``.
    """
    v = np.ascontiguousarray(v0, dtype=np.float64) / math.sqrt(_dot(v0, v0))
    matvecs = 0
    while True:
        m = max(1, min(cycle, dimension, iterations - matvecs))
        basis = np.empty((m, v.shape[0]))
        basis[0] = v
        alpha = []
        beta = []
        converged = False
        for j in range(m):
            w = np.ascontiguousarray(apply(basis[j]), dtype=np.float64)
            matvecs += 1
            alpha.append(_dot(basis[j], w))
            w -= alpha[j] * basis[j]
            if j > 0:
                w -= beta[j - 1] * basis[j - 1]
            _orthogonalise(w, basis, j + 1)
            beta.append(math.sqrt(_dot(w, w)))
            theta, s = _largest_ritz(np.array(alpha), np.array(beta))
            residual = abs(beta[j] * s[-1])
            scale = max(abs(theta), max(abs(a) for a in alpha), 1e-300)
            if beta[j] <= 1e-13 * scale or (residual <= tol * abs(theta) and matvecs >= MIN_STEPS):
                converged = True                      # invariant subspace, or converged
                break
            if j + 1 < m:
                basis[j + 1] = w / beta[j]
        vector = s @ basis[:len(s)]                   # (k,) x (k, dim): a small gemv
        vector /= math.sqrt(_dot(vector, vector))
        if converged or matvecs >= iterations:
            return theta, residual, matvecs, converged, vector
        v = vector


def frequency_analysis(model, x=None, iterations=400, tol=1e-4, cycle=60, differences="central"):
    """``FrequencyEstimate`` of the largest eigenvalue of ``M^-1 K`` at positions ``x`` (default: rest).

    iterations: most operator applications; tol: relative Ritz residual to stop at;
    cycle: Lanczos vectors kept before a restart (memory at most ``cycle x 3 node_count`` floats);
    differences: ``"central"`` (two force evaluations an application, K exactly symmetric to
    round-off) or ``"forward"`` (one, from the forces at ``x``: K off by about ``FD_RELATIVE_STEP``
    relative, for estimates to ``tol`` 1e-2 such as the guard's).

    The start is always the same generic (fixed-seed random) vector.  Warm-starting from an earlier
    call's ``mode`` is deliberately not offered: on a deformed state the old top mode can be close
    to an eigenvector that is no longer the top one, and Lanczos then converges, with a small
    residual, to that lower eigenvalue (measured: 5 % low on a gmsh box stretched by 5 %).
    """
    if differences not in ("central", "forward"):
        raise ValueError(f"differences must be 'central' or 'forward', got {differences!r}")
    x = model.rest_points if x is None else np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    op = _SymmetricOperator(model, x, forward=differences == "forward")
    free = op.free.ravel()
    dimension = int(free.sum())
    if dimension == 0:
        return FrequencyEstimate(0.0, 0.0, 0, True, np.zeros((n, 3)))
    rng = np.random.default_rng(SEED)
    v0 = np.where(free, rng.standard_normal(3 * n), 0.0)

    def apply(flat):
        out = op.apply(flat.reshape(n, 3)).ravel()
        if not np.isfinite(out).all():
            raise _NotFinite
        return out

    try:
        theta, residual, matvecs, converged, vector = _lanczos_largest(apply, v0, dimension, iterations, tol, cycle)
    except _NotFinite:          # forces overflow at x: no finite step is stable there
        return FrequencyEstimate(math.inf, 0.0, 0, True, np.zeros((n, 3)))
    return FrequencyEstimate(lambda_max=float(theta), residual=float(residual), matvecs=matvecs,
                             converged=bool(converged), mode=vector.reshape(n, 3))


def largest_frequency_squared(model, x=None, iterations=400, tol=1e-4, differences="central"):
    """Largest eigenvalue [1/s^2] of ``M^-1 K`` (plus the ground's worst-case penalty springs) at ``x``.

    model: a ``softsim.model.Model``; x: (n, 3) positions [m] in internal order, default the rest
    positions.  Held components are fixed.  If Lanczos does not reach ``tol`` within
    ``iterations`` operator applications, the Ritz value plus its residual is returned (an upper
    estimate) and a warning is logged.
    """
    result = frequency_analysis(model, x, iterations=iterations, tol=tol, differences=differences)
    if result.converged:
        return max(result.lambda_max, 0.0)
    log.warning("largest eigenvalue of M^-1 K not converged after %d iterations (relative residual %.2g); "
                "using the Ritz value plus its residual", result.matvecs,
                result.residual / max(abs(result.lambda_max), 1e-300))
    return max(result.lambda_max + result.residual, 0.0)


def exact_stable_step(model, x=None, **kwargs):
    """Symplectic Euler's stability limit ``2 / sqrt(lambda_max(M^-1 K))`` [s] at positions ``x``.

    ``math.inf`` when nothing can oscillate (every component held).  Keyword arguments go to
    ``largest_frequency_squared``.
    """
    lam = largest_frequency_squared(model, x, **kwargs)
    return 2.0 / math.sqrt(lam) if lam > 0.0 else math.inf


def hooke_lame_parameters(model):
    """``(lambda, mu)`` [Pa] of the Hooke's law every model linearises to at rest (undoing the
    stable Neo-Hookean remapping ``mu' = 4/3 mu``, ``lambda' = lambda + 5/6 mu``)."""
    if model.material_id == NEOHOOKEAN:
        mu = 0.75 * model.mu
        return model.lam - 5.0 * mu / 6.0, mu
    return model.lam, model.mu


def element_stiffness_maxima(model, x=None):
    """Largest eigenvalue [N/m] of each tet's 12 x 12 stiffness ``K_e``, shape (tet_count,).

    ``K_e`` is linear elasticity (Hooke's law with the model's small-strain constants) on the tet's
    geometry at ``x`` (default rest): with corner gradients ``b_a`` and volume ``V``,
    ``K_ab = V (lambda b_a b_b^T + mu (b_a . b_b) I + mu b_b b_a^T)``; its largest eigenvalue from
    two 3 x 3 problems (``kernels.stiffness``), not LAPACK's on the assembled matrices.
    """
    x = model.rest_points if x is None else np.ascontiguousarray(x, dtype=np.float64)
    lam, mu = hooke_lame_parameters(model)
    return stiffness_maxima(x, model.tets, float(lam), float(mu))


def element_frequency_bound(model, x=None):
    """Largest ``lambda_max(K_e) / (rho V0_e / 4)`` over the tets [1/s^2] (Irons & Treharne 1971).

    At rest an upper bound of ``lambda_max(M^-1 K)`` (held components and the ground aside): each
    tet's corner masses are part of its vertices' lumped masses.
    """
    density = float(model.mass.sum() / model.rest_volume.sum())        # masses are rho V0 / 4 per corner
    return float(np.max(element_stiffness_maxima(model, x) / (0.25 * density * model.rest_volume)))


def nodal_frequency_bound(model, x=None):
    """``max_i sum_{e at i} lambda_max(K_e) / m_i`` over the free vertices [1/s^2], plus the ground term.

    At rest an upper bound of ``lambda_max(M^-1 K)``: ``u^T K u = sum_e u_e^T K_e u_e <=
    sum_e lambda_max(K_e) |u_e|^2 = sum_i |u_i|^2 sum_{e at i} lambda_max(K_e)``.  It is a mass-weighted
    average of the per-element bounds at each vertex, so never above ``element_frequency_bound``.
    The ground adds ``max(contact_stiffness_bound / mass)`` (Weyl), as in ``largest_frequency_squared``.
    """
    k = element_stiffness_maxima(model, x)
    per_vertex = np.zeros(model.node_count)
    np.add.at(per_vertex, model.tets.ravel(), np.repeat(k, 4))
    free = (~np.asarray(model.held).all(axis=1)) & (model.inv_mass > 0.0)
    if not free.any():
        return 0.0
    bound = float(np.max(per_vertex[free] * model.inv_mass[free]))
    if model.has_ground:
        ground = model.contact_stiffness_bound * model.inv_mass
        bound += float(np.max(np.where(free & ~np.asarray(model.held)[:, 2], ground, 0.0)))
    return bound
