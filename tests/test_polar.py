"""The corotated model's rotation (``kernels.polar3``: Newton's polar iteration, the Jacobi SVD where
it does not converge) against ``numpy.linalg.svd`` with the reflection moved into the smallest
singular value (``naive.polar_rotation``), and the corotated lane loop of ``kernels.blocked``
against the per-tet law, on blocks whose lanes take either path.

Families of F: random, near a rotation, large rotations, stretch ratios up to 1e3, inverted,
nearly repeated and nearly zero singular values, and exactly singular ones.  The rotation of an
inverted F is ill-conditioned as ``s1 - |s2|`` goes to zero, of any F as ``s1 + s2`` does (signed
s): errors are checked against ``eps / (s1 + s2)`` relative to ``s0``.
"""

import numpy as np
import pytest

import naive
from softsim.kernels.blocked import (BLOCK, FALLBACK_VECTOR_MIN_LANES, NEWTON_VECTOR_MIN_LANES, ROW_F,
                                     ROW_STAGE, ROW_TRIANGULAR_VOLUME, ROW_X, ROWS, STAGE_JACOBI,
                                     TRIANGULAR_REST_ROWS, corotated_block, lanes_per_group)
from softsim.kernels.polar3 import (NEWTON_NORM_TOLERANCE, NEWTON_ROTATION_ERROR, jacobi_polar_rotation,
                                   newton_polar_certifies_jit, newton_polar_finish, newton_polar_rotation_jit,
                                   newton_polar_start_jit, polar_rotation)
from softsim.kernels.rotated_rest import triangular_rest_inverses
from softsim.materials.models import corotated_energy_density, corotated_first_piola, model_lame_parameters
from test_blocked_kernels import Body

EPS = np.finfo(np.float64).eps
LAM, MU = model_lame_parameters("corotated", 1.0e6, 0.3)


def rotation(rng, min_angle=0.0):
    """Rodrigues rotation about a random axis by an angle in [min_angle, pi]."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(min_angle, np.pi)
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def with_singular_values(rng, s):
    return rotation(rng) @ np.diag(s) @ rotation(rng)


def family(name, rng):
    """One random F of family ``name``."""
    if name == "random":
        return rng.normal(size=(3, 3))
    if name == "near rotation":
        return rotation(rng) @ (np.eye(3) + 1e-3 * rng.normal(size=(3, 3)))
    if name == "large rotation":
        return rotation(rng, 0.9 * np.pi) @ (np.eye(3) + 0.3 * rng.normal(size=(3, 3)))
    if name == "stretch ratio up to 1e3":
        return with_singular_values(rng, np.exp(rng.uniform(np.log(1e-3), 0.0, 3)) * np.exp(rng.uniform(-2, 2)))
    if name == "inverted":
        return with_singular_values(rng, [rng.uniform(0.5, 2.0), rng.uniform(0.3, 1.0), -rng.uniform(0.01, 0.25)])
    if name == "inverted, stretch ratio up to 1e3":
        return with_singular_values(rng, np.exp(rng.uniform(np.log(1e-3), 0.0, 3)) * [1.0, 1.0, -1.0])
    if name == "nearly repeated":
        d = 10.0 ** rng.uniform(-12, -6)
        return with_singular_values(rng, [1.0 + d, 1.0, 1.0 - d])
    if name == "nearly flat":
        return with_singular_values(rng, [rng.uniform(0.5, 2.0), rng.uniform(0.1, 0.5),
                                          10.0 ** rng.uniform(-12, -4) * rng.choice([-1.0, 1.0])])
    raise ValueError(name)


FAMILIES = ("random", "near rotation", "large rotation", "stretch ratio up to 1e3", "inverted",
            "inverted, stretch ratio up to 1e3", "nearly repeated", "nearly flat")
# Well-conditioned families, P not near zero: P must match the reference to 1e-9 relative.
WELL_CONDITIONED = ("random", "near rotation", "large rotation", "inverted")


def as_matrix(t):
    return np.array(t, dtype=np.float64).reshape(3, 3)


def rotation_of(F):
    """softsim's R (3, 3) for F (3, 3)."""
    return as_matrix(polar_rotation(tuple(F.ravel())))


def P_of(F):
    return as_matrix(corotated_first_piola(tuple(F.ravel()), LAM, MU))


def assert_proper_rotation(R):
    assert np.all(np.isfinite(R))
    np.testing.assert_allclose(R.T @ R, np.eye(3), rtol=0, atol=1e-13)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-13)


# ---------------------------------------------------------------------------------------------
# the two paths against numpy.linalg.svd


@pytest.mark.parametrize("name", FAMILIES)
def test_jacobi_svd_matches_numpy_svd(name):
    """R within ``1000 eps / (s1 + s2)`` of the reference (measured: at most 450 in 10^6 samples
    per family), the signed singular values within ``100 eps s0``, det R = +1, s2 < 0 iff det F < 0."""
    rng = np.random.default_rng(FAMILIES.index(name))
    for _ in range(300):
        F = family(name, rng)
        R_ref, s_ref = naive.polar_rotation(F)
        R, s0, s1, s2 = jacobi_polar_rotation(tuple(F.ravel()))
        R = as_matrix(R)
        assert_proper_rotation(R)
        conditioning = (s_ref[1] + s_ref[2]) / s_ref[0]
        assert np.abs(R - R_ref).max() * conditioning < 1000.0 * EPS, (F, R, R_ref)
        np.testing.assert_allclose([s0, s1, s2], s_ref, rtol=0, atol=100.0 * EPS * s_ref[0])
        assert (s2 < 0) == (np.linalg.det(F) < 0)


@pytest.mark.parametrize("name", FAMILIES)
def test_newton_rotation_is_the_reference_where_it_converges(name):
    """Accepted Newton results are within 1e-13 of the reference (measured: 1e-14); it accepts every
    F near a rotation and no inverted or nearly flat one."""
    rng = np.random.default_rng(100 + FAMILIES.index(name))
    accepted = 0
    for _ in range(300):
        F = family(name, rng)
        R, converged = newton_polar_rotation_jit(tuple(F.ravel()))
        if converged:
            accepted += 1
            R_ref, _ = naive.polar_rotation(F)
            np.testing.assert_allclose(as_matrix(R), R_ref, rtol=0, atol=1e-13)
        if np.linalg.det(F) <= 0.0 or name == "nearly flat":
            assert not converged
    if name in ("near rotation", "nearly repeated"):
        assert accepted == 300


def long_double_newton(F, steps):
    """Newton's polar iterates ``X_1 .. X_steps`` of F (3, 3) in long double (x86's extended
    precision rounds at about 1e-19, a quad long double finer still: far below the truncation
    errors of 5e-15 measured here):
    ``X <- (X + cof(X) / det X) / 2``."""
    X = np.array(F, dtype=np.longdouble)
    iterates = []
    for _ in range(steps):
        C = np.array([np.cross(X[1], X[2]), np.cross(X[2], X[0]), np.cross(X[0], X[1])])
        X = (X + C / np.sum(X[0] * C[0])) / 2
        iterates.append(X)
    return iterates


@pytest.mark.skipif(np.finfo(np.longdouble).eps > 1e-18, reason="needs a long double finer than float64")
def test_an_iterate_whose_norm_passes_certifies_the_next_one():
    """``newton_polar_certifies``: where ``X_k`` (k >= 1) passes, ``X_k+1`` lies within
    ``NEWTON_ROTATION_ERROR`` of the polar factor, its truncation error measured in long double
    against the iteration run to convergence.  Strains from 1e-5 to 1e-2 put ``|X_k|^2 - 3`` on
    both sides of the tolerance for k = 1 to 3; some certified iterates come within a factor 10 of
    the bound (a tolerance 10x looser certifies errors 100x larger and fails).  ``X_0 = F`` is not
    covered: ``diag(1 + a, 1 - a, 1)`` passes for ``a = 1e-4`` while ``X_1`` is 1e6 times further
    off than the bound."""
    rng = np.random.default_rng(120)
    certified = near_bound = 0
    for a in 10.0 ** rng.uniform(-5.0, -2.0, 400):
        F = rotation(rng) @ (np.eye(3) + a * rng.normal(size=(3, 3)))
        iterates = long_double_newton(F, 12)
        R = iterates[-1]
        for k in (1, 2, 3):
            if newton_polar_certifies_jit(tuple(iterates[k - 1].astype(np.float64).ravel()), 1.0):
                error = float(np.sqrt(np.sum((iterates[k] - R) ** 2)))
                assert error <= NEWTON_ROTATION_ERROR * (1 + 1e-6), (a, k, error)
                certified += 1
                near_bound += error > NEWTON_ROTATION_ERROR / 10
            else:
                assert float(np.sum(iterates[k - 1] ** 2)) - 3 > NEWTON_NORM_TOLERANCE * (1 - 1e-6)
    assert certified > 300 and near_bound > 10, (certified, near_bound)
    F = np.diag([1.0 + 1e-4, 1.0 - 1e-4, 1.0])
    assert newton_polar_certifies_jit(tuple(F.ravel()), 1.0)
    assert float(np.sqrt(np.sum((long_double_newton(F, 1)[0] - np.eye(3)) ** 2))) > 1e6 * NEWTON_ROTATION_ERROR


def test_newton_carries_its_scale_safely_over_every_size_of_F():
    """``F = a Q (I + 1e-3 G)``, a from 1e-30 to 1e30: Newton's scaled iterates (``Z_4 = c_4 X_4``,
    ``c_4`` about ``2^85 a^192``) converge from a = 0.5 to 2 and are accurate wherever accepted, out
    of range they are declined (never a result of overflowed numbers), and the Jacobi SVD gives
    the rotation of every other F."""
    rng = np.random.default_rng(110)
    for a in 10.0 ** np.arange(-30.0, 30.01, 0.25):
        F = a * (rotation(rng) @ (np.eye(3) + 1e-3 * rng.normal(size=(3, 3))))
        R_ref, _ = naive.polar_rotation(F)
        R, converged = newton_polar_rotation_jit(tuple(F.ravel()))
        if 0.5 <= a <= 2.0:
            assert converged, a
        if converged:
            np.testing.assert_allclose(as_matrix(R), R_ref, rtol=0, atol=1e-13)
        np.testing.assert_allclose(rotation_of(F), R_ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", WELL_CONDITIONED)
def test_corotated_stress_matches_the_reference(name):
    """``P = 2 mu (F - R) + lam tr(R^T F - I) R`` within 1e-9 of ``naive.pk1`` (relative)."""
    rng = np.random.default_rng(200 + FAMILIES.index(name))
    for _ in range(300):
        F = family(name, rng)
        s = np.linalg.svd(F, compute_uv=False)
        if name == "random" and (s[2] < 0.05 * s[0] or s[1] - s[2] < 0.05 * s[0]):
            continue                                    # keep the random ones well-conditioned
        P_ref = naive.pk1("corotated", F, LAM, MU)
        assert np.linalg.norm(P_of(F) - P_ref) <= 1e-9 * np.linalg.norm(P_ref)


# ---------------------------------------------------------------------------------------------
# rotations, inversion, degenerate F


def test_a_rotation_is_its_own_rotation_and_feels_no_stress():
    rng = np.random.default_rng(300)
    axis = np.array([0.0, 0.6, 0.8])
    half_turn = 2.0 * np.outer(axis, axis) - np.eye(3)              # rotation by pi
    for Q in [np.eye(3), half_turn] + [rotation(rng) for _ in range(50)]:
        np.testing.assert_allclose(rotation_of(Q), Q, rtol=0, atol=1e-15)
        assert np.abs(P_of(Q)).max() < 1e-14 * (LAM + MU)
        assert abs(corotated_energy_density(tuple(Q.ravel()), LAM, MU)) < 1e-24 * (LAM + MU)


def test_inverted_F_gives_a_proper_rotation_and_the_reference_stress():
    """The reflection goes into the smallest singular value: R is the reference's proper rotation,
    not the improper polar factor, and P points back towards positive volume."""
    rng = np.random.default_rng(301)
    for _ in range(100):
        F = family("inverted", rng)
        R = rotation_of(F)
        assert_proper_rotation(R)
        R_ref, _ = naive.polar_rotation(F)
        np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-12)
        P = P_of(F)
        P_ref = naive.pk1("corotated", F, LAM, MU)
        assert np.linalg.norm(P - P_ref) <= 1e-9 * np.linalg.norm(P_ref)
        # dJ/dt along -P: the volume grows (J = det F < 0 rises towards 0)
        cofactor = np.linalg.det(F) * np.linalg.inv(F).T
        assert np.sum(cofactor * -P) > 0.0
    mirror = np.diag([1.0, 1.0, -1.0])
    assert_proper_rotation(rotation_of(mirror))
    assert np.all(np.isfinite(P_of(mirror)))


def test_singular_F_gives_a_finite_stress():
    """Zero, rank 1, rank 2 and nearly flat F: a proper rotation and finite P; for rank 2 the
    rotation is unique and matches the reference."""
    rng = np.random.default_rng(302)
    cases = [np.zeros((3, 3)), np.outer(rng.normal(size=3), rng.normal(size=3)), np.diag([1.0, 0.0, 0.0]),
             np.diag([0.0, 0.0, 1e-300])]
    for _ in range(20):
        rank2 = with_singular_values(rng, [rng.uniform(0.5, 2.0), rng.uniform(0.1, 0.5), 0.0])
        cases.append(rank2)
        R_ref, _ = naive.polar_rotation(rank2)
        np.testing.assert_allclose(rotation_of(rank2), R_ref, rtol=0, atol=1e-12)
        cases.append(family("nearly flat", rng))
    for F in cases:
        assert_proper_rotation(rotation_of(F))
        P = P_of(F)
        assert np.all(np.isfinite(P))
        assert np.abs(P).max() < 10.0 * (LAM + MU) * max(1.0, np.abs(F).max())


# ---------------------------------------------------------------------------------------------
# the lane loop


def block_of(Fs, Dms=None):
    """The rest rows and scratch buffer of a block whose lane j has deformation gradient exactly
    ``Fs[j]``, with V0 = 1 and corner 0 at the origin: corners 1..3 at the columns of ``F Dm``, the
    rest rows those of ``Dm = Dms[j]`` in the triangular form (``R^-1``, ``rotated_rest``; None:
    ``Dm = I``, so that the lane's corner forces are exactly ``-P``, columns on corners 1..3)."""
    lanes = lanes_per_group(np.float64)
    Dms = np.broadcast_to(np.eye(3), Fs.shape) if Dms is None else Dms
    a = triangular_rest_inverses(np.linalg.inv(Dms))               # (BLOCK, 6): R^-1 00, 01, 02, 11, 12, 22
    rest = np.zeros((BLOCK // lanes, TRIANGULAR_REST_ROWS, lanes))
    rest[:, :6] = a.reshape(BLOCK // lanes, lanes, 6).transpose(0, 2, 1)
    rest[:, ROW_TRIANGULAR_VOLUME] = 1.0
    buf = np.zeros(ROWS * BLOCK)
    Ds = Fs @ Dms
    for c in range(1, 4):
        for k in range(3):
            buf[(ROW_X + 3 * c + k) * BLOCK:(ROW_X + 3 * c + k + 1) * BLOCK] = Ds[:, k, c - 1]
    return rest, buf


def newton_tolerance(F, A=np.eye(3)):
    """How far apart the corner forces ``-P(F) A^T`` may lie when the lane loop's R and the per-tet
    law's come from different counts of Newton's steps (``corotated_block``'s first steps): each R
    is within ``NEWTON_ROTATION_ERROR`` of the polar factor, so they differ by ``eps = 2
    NEWTON_ROTATION_ERROR`` at most, and ``P = 2 mu (F - R) + lam tr(R^T F - I) R`` by at most
    ``(2 mu + lam (sqrt(3) |F| + |tr(R^T F) - 3|)) eps`` (Frobenius); the forces by that times |A|."""
    R = rotation_of(F)
    eps = 2.0 * NEWTON_ROTATION_ERROR
    dP = (2.0 * MU + LAM * (np.sqrt(3.0) * np.linalg.norm(F) + abs(np.trace(R.T @ F) - 3.0))) * eps
    return dP * np.linalg.norm(A, 2)


def second_stage_F(rng):
    """An F that Newton's first four steps do not settle and its last two do (strain ~0.12)."""
    while True:
        F = rotation(rng) @ (np.eye(3) + 0.12 * rng.normal(size=(3, 3)))
        t = tuple(F.ravel())
        if not newton_polar_start_jit(t)[1] and newton_polar_rotation_jit(t)[1]:
            return F


def newton_settles(F, first_steps):
    """Whether Newton's ``first_steps`` first steps and, where they do not settle F, its two last
    ones, settle F (per tet): the lanes of ``corotated_block`` that it does not leave to the Jacobi
    SVD."""
    X, converged, _ = newton_polar_start_jit(tuple(F.ravel()), first_steps)
    return converged or newton_polar_finish(X, np.linalg.det(F))[2]


@pytest.mark.parametrize("rest_frame", [False, True])
@pytest.mark.parametrize("second_stage, fallbacks, first_steps", [
    (0, 0, 4), (3, 0, 4), (NEWTON_VECTOR_MIN_LANES + 1, 0, 4), (0, 3, 4), (5, 3, 4),
    (NEWTON_VECTOR_MIN_LANES + 1, 3, 4),
    (3, FALLBACK_VECTOR_MIN_LANES + 1, 4), (NEWTON_VECTOR_MIN_LANES + 1, FALLBACK_VECTOR_MIN_LANES + 1, 4),
    (0, BLOCK, 4), (BLOCK, 0, 4),
    (0, 0, 3), (5, 3, 3), (NEWTON_VECTOR_MIN_LANES + 1, FALLBACK_VECTOR_MIN_LANES + 1, 3),
    (0, 0, 2), (5, 3, 2), (NEWTON_VECTOR_MIN_LANES + 1, FALLBACK_VECTOR_MIN_LANES + 1, 2)])
def test_lane_loop_gives_the_per_tet_law(second_stage, fallbacks, rest_frame, first_steps):
    """A block with ``second_stage`` lanes that need Newton's last two steps and ``fallbacks`` lanes
    that Newton cannot do (inverted, nearly flat, strongly stretched), each through its scalar
    and its packed loop, among near-rest lanes: every lane's forces are -P of
    ``corotated_first_piola``, whichever path the block took, to round-off, after ``first_steps``
    first steps too (fewer send more lanes on, to the second stage or to the Jacobi SVD).  The block
    asks for one first step more where lanes were sent to the second stage.  Not bit for bit:
    LLVM fuses multiplies and adds (``jit.JIT_OPTIONS``) where it chooses, not always at the
    same places in a packed loop as in a scalar function, and the packed Newton paths form the
    stress from the scaled iterate (``blocked.lane_store_corotated_forces``); a few ulps of R show
    in ``F - R``: up to 6.7e-16 of ``(lam + mu) |F|`` (measured).  With ``rest_frame`` each lane
    has a random rest shape, left-handed ones among them, so that the lane loop takes ``F_r = F Q``
    for a rotation Q of its own (``rotated_rest``): its forces are ``-P(F_r) R^-T`` of the per-tet
    law, to 1e-13 of the lane's largest force.  (That these are ``-P(F) Dm^-T`` is
    ``test_rotated_rest``'s: for an inverted F near ``s1 = |s2|`` the rotation, and so P, is
    ill-conditioned, and the two differ by round-off amplified: up to 1e-14 of the force.)"""
    rng = np.random.default_rng(303 + second_stage)
    hard = ("inverted", "nearly flat", "inverted, stretch ratio up to 1e3")
    Fs = np.array([family(hard[j % 3], rng) if j < fallbacks
                   else second_stage_F(rng) if j < fallbacks + second_stage
                   else rotation(rng) @ (np.eye(3) + 0.02 * rng.normal(size=(3, 3))) for j in range(BLOCK)])
    Fs = Fs[rng.permutation(BLOCK)]
    assert sum(not newton_polar_rotation_jit(tuple(F.ravel()))[1] for F in Fs) == fallbacks
    assert sum(not newton_polar_start_jit(tuple(F.ravel()))[1] for F in Fs) == fallbacks + second_stage
    Dms = np.broadcast_to(np.eye(3), Fs.shape)
    if rest_frame:
        Dms = np.eye(3) + 0.3 * rng.normal(size=Fs.shape)
        Dms[::4] = Dms[::4][:, :, [1, 0, 2]]                 # every fourth one left-handed
    rest, buf = block_of(Fs, Dms)
    # typed as the step calls it on a mesh that does not prefetch (a uint8 count): no compile of its own
    next_steps = corotated_block(rest, buf, LAM, MU, None, np.uint8(first_steps))
    if second_stage > 0 or first_steps < 4:        # lanes of strain 0.02 are not settled by 3 steps
        assert next_steps == min(first_steps + 1, 4)
    a = triangular_rest_inverses(np.linalg.inv(Dms))
    for j in range(BLOCK):
        A = np.array([[a[j, 0], a[j, 1], a[j, 2]], [0.0, a[j, 3], a[j, 4]], [0.0, 0.0, a[j, 5]]])
        F_r = Fs[j] @ Dms[j] @ A                             # F Q: what the lane loop sees
        # the second stage went on from the first stage's iterate: had it not, the lane would
        # have gone on to the Jacobi SVD, whose forces are as right
        assert (buf[ROW_STAGE * BLOCK + j] == STAGE_JACOBI) == (not newton_settles(F_r, first_steps)), j
        H = P_of(F_r) @ A.T
        # with a rest frame, F_r is formed in the lane (with FMAs) and in NumPy to round-off apart,
        # which an inverted lane's ill-conditioned rotation amplifies: 1e-14 of the force measured
        tolerance = (1e-13 * np.abs(H).max() if rest_frame else 1e-14 * (LAM + MU) * np.abs(Fs[j]).max())
        if first_steps < 4:
            tolerance = max(tolerance, newton_tolerance(F_r, A))
        for c in range(1, 4):
            for k in range(3):
                assert abs(buf[(ROW_F + 3 * c + k) * BLOCK + j] + H[k, c - 1]) <= tolerance, (j, c, k)


@pytest.mark.parametrize("strain, settles", [(1e-5, 2), (1e-3, 3), (0.03, 4)])
def test_a_block_takes_as_few_first_steps_as_settle_it(strain, settles):
    """Blocks of a steady strain, stepped again and again from each first-step count: each comes to
    the fewest first steps of Newton's iteration that settle all its lanes (2 at a steel-like
    strain of 1e-5, 3 at 1e-3, 4 at 0.03), and stays there; the forces stay the per-tet law's."""
    rng = np.random.default_rng(305)
    Fs = np.array([rotation(rng) @ (np.eye(3) + strain * rng.normal(size=(3, 3))) for _ in range(BLOCK)])
    fewest = next(k for k in (2, 3, 4) if all(newton_polar_start_jit(tuple(F.ravel()), k)[1] for F in Fs))
    assert fewest == settles
    rest, buf = block_of(Fs)
    expected = np.array([-P_of(F) for F in Fs])
    for start in (4, 3, 2):
        steps, taken = start, []
        for _ in range(4):
            steps = corotated_block(rest, buf, LAM, MU, None, np.uint8(steps))
            taken.append(steps)
            forces = np.array([[[buf[(ROW_F + 3 * c + k) * BLOCK + j] for c in range(1, 4)] for k in range(3)]
                               for j in range(BLOCK)])
            for j in range(BLOCK):
                assert np.abs(forces[j] - expected[j]).max() <= newton_tolerance(Fs[j]), (start, j)
        assert taken[-2:] == [settles, settles], (start, taken)


@pytest.mark.parametrize("inverted", [False, True])
def test_blocked_corotated_forces_are_minus_the_energy_gradient(inverted):
    """One tet through the vectorised step (Newton path, or the Jacobi fallback when inverted):
    forces against central differences of the reference energy ``naive.elastic_energy``."""
    rng = np.random.default_rng(304)
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    tets = np.array([[0, 1, 2, 3]])
    body = Body(X, tets, "csr")
    for _ in range(3):
        x = X @ rotation(rng).T + 0.1 * rng.normal(size=(4, 3))
        if inverted:
            x[3] = x[0] - 0.6 * (x[3] - x[0]) + 0.05 * rng.normal(size=3)     # through the opposite face
        volume = np.linalg.det((x[1:] - x[0]).T)
        assert (volume < 0) == inverted
        f = body.forces(x, "corotated", LAM, MU)
        h = 1e-6
        f_fd = np.empty_like(x)
        for i in range(4):
            for k in range(3):
                xp, xm = x.copy(), x.copy()
                xp[i, k] += h
                xm[i, k] -= h
                f_fd[i, k] = -(naive.elastic_energy(xp, X, tets, "corotated", LAM, MU)
                               - naive.elastic_energy(xm, X, tets, "corotated", LAM, MU)) / (2.0 * h)
        assert np.linalg.norm(f - f_fd) < 1e-6 * np.linalg.norm(f)
