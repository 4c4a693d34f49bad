"""The vectorised step (``kernels.blocked`` driven by ``integrators.symplectic_euler.advance``)
against the naive NumPy forces of ``tests/naive.py``, for both ways of summing the corner forces
(colour scatter and CSR gather), on meshes whose tet count is not a multiple of the block size;
the block colouring; bitwise determinism on any thread count.

The forces are read from one step with ``dt = 1``, unit inverse masses, no loads and ``v = 0``,
so that the velocity after the step is the elastic force.
"""

import dataclasses

import numba
import numpy as np
import pytest

import naive
from softsim.integrators.symplectic_euler import advance, force_buffer, step_arguments, work_buffer
from softsim.kernels import blocked
from softsim.kernels.blocked import (BLOCK, PREFETCH_BLOCKS_AHEAD, PREFETCH_FROM_BYTES, REST_ROWS, ROW_F, ROW_REST,
                                     SCRATCH_ROWS, TRIANGULAR_REST_ROWS, block_layout, build_block_layout,
                                     cache_aligned_scratch, first_uses, gather_corners, owned_vertex_runs,
                                     prefetching, rest_from_corners_block, triangular_rest_from_corners_block,
                                     uses_triangular_rest)
from softsim.kernels.jit import CompileTimeConstant
from softsim.kernels.rest_state import rest_state, vertex_tet_csr
from softsim.kernels.simd import CACHE_LINE_BYTES
from softsim.materials.models import MODEL_IDS, model_lame_parameters
from softsim.mesh.generate import structured_box
from softsim.mesh.reorder import renumber_for_locality

E_PA = 1.0e6
NU = 0.3

# The csr scatter is no scene's: it is the benchmark suite's comparison row (float64 StVK, its rest
# data stored, prefetched above 100k tets).  Its forces against the naive ones (every law), its bits
# on any thread count and its StVK prefetch run in every test run; its variants that no benchmark
# compiles (rest data computed in the step, the full-form prefetch, the vertex moves within the
# parts, float32), each a step compiled for it alone, only with SOFTSIM_SLOW=1.
CSR_SLOW = pytest.param("csr", marks=pytest.mark.slow)


class Body:
    """Just the ``Model`` attributes ``step_arguments`` and ``work_buffer`` read."""

    precision = "float64"

    def __init__(self, points, tets, scatter, rest_from_points=False, model="stvk"):
        self.X = np.ascontiguousarray(points, dtype=np.float64)
        self.rest_points = self.X
        self.tets = np.ascontiguousarray(tets, dtype=np.int64)
        self.node_count, self.tet_count = len(self.X), len(self.tets)
        self.Dm_inv, self.V0 = rest_state(self.X, self.tets)
        self.csr_offsets, self.csr_slots = vertex_tet_csr(self.tets, self.node_count)
        self.scatter, self.rest_from_points = scatter, rest_from_points
        self.use_model(model)

    def use_model(self, model):
        """Lay the tets out for the step of ``model`` (its form of rest data, ``uses_triangular_rest``);
        rest_from_points: what a mesh above REST_FROM_POINTS_BYTES gets, no rest data stored."""
        self.material_id = MODEL_IDS[model]
        self.blocks = build_block_layout(self.tets, self.Dm_inv, self.V0, self.node_count, self.scatter,
                                         rest_from_points=self.rest_from_points, model=self.material_id)

    def forces(self, x, model, lam, mu, inv_mass=None, gravity=(0.0, 0.0, 0.0), external_accel=None, chunks=None):
        """The elastic forces at ``x`` [N] from one step of ``advance`` with ``dt = 1`` and ``v = 0``
        (plus the external accelerations, and divided by the masses, where given); chunks: the
        ``threads`` argument of ``advance`` (None: Numba's thread count)."""
        if MODEL_IDS[model] != self.material_id:
            self.use_model(model)
        n = self.node_count
        x = np.array(x, dtype=np.float64)
        v = np.zeros_like(x)
        blocks, colour_offsets, scatter, offsets, slots, vf, corner = step_arguments(self, work_buffer(self))
        no_hold = np.zeros((n, 3), dtype=np.bool_)
        advance(x, None, v, 0, 1, 1.0, blocks, colour_offsets, scatter, CompileTimeConstant(MODEL_IDS[model]), lam,
                mu, offsets, slots, vf, corner, np.ones(n) if inv_mass is None else inv_mass, gravity,
                external_accel, no_hold, x.copy(), np.zeros((n, 3)), None, None, None,
                numba.get_num_threads() if chunks is None else chunks, True)
        return v


def mesh(cells):
    """A structured box of ``cells`` (5 tets per cell), randomly deformed."""
    points, tets = structured_box(tuple(float(c) for c in cells), (0.0, 0.0, 0.0), 1.0)
    rng = np.random.default_rng(sum(cells))
    x = points @ (np.eye(3) + 0.2 * rng.normal(size=(3, 3))).T + 0.05 * rng.normal(size=points.shape)
    return points, tets, x


@pytest.mark.parametrize("scatter", ["colour", "csr"])
@pytest.mark.parametrize("model", tuple(MODEL_IDS))
def test_blocked_forces_match_naive_numpy(model, scatter):
    points, tets, x = mesh((7, 5, 3))                     # 525 tets: 9 blocks, the last one partly padding
    assert len(tets) % BLOCK != 0
    body = Body(points, tets, scatter)
    lam, mu = model_lame_parameters(model, E_PA, NU)
    f = body.forces(x, model, lam, mu)
    f_naive = naive.elastic_forces(x, body.X, body.tets, model, lam, mu)
    np.testing.assert_allclose(f, f_naive, rtol=0, atol=1e-11 * np.abs(f_naive).max())


@pytest.mark.parametrize("scatter", ["colour", CSR_SLOW])
@pytest.mark.parametrize("model", tuple(MODEL_IDS))
def test_rest_data_computed_in_the_step_give_the_stored_forces(model, scatter):
    """A layout with ``rest_from_points`` (float64 meshes above ``REST_FROM_POINTS_BYTES``) computes
    each block's ``Dm^-1`` and ``V0`` from the corners' rest positions: the forces of the naive
    formulas, and those of the stored rest data to round-off, padding block included."""
    points, tets, x = mesh((7, 5, 3))
    lam, mu = model_lame_parameters(model, E_PA, NU)
    computed = Body(points, tets, scatter, rest_from_points=True)
    assert step_arguments(computed, work_buffer(computed))[0][11] is not None
    assert computed.blocks.rest.shape[0] == 0         # none stored: the step cannot read them
    f = computed.forces(x, model, lam, mu)
    f_naive = naive.elastic_forces(x, computed.X, computed.tets, model, lam, mu)
    np.testing.assert_allclose(f, f_naive, rtol=0, atol=1e-11 * np.abs(f_naive).max())
    f_stored = Body(points, tets, scatter).forces(x, model, lam, mu)
    np.testing.assert_allclose(f, f_stored, rtol=0, atol=1e-13 * np.abs(f_stored).max())


@pytest.mark.parametrize("triangular", [False, True])
def test_rest_from_corners_block_is_the_stored_rest_data(triangular):
    """``rest_from_corners_block`` against ``kernels.rest_state`` (LU) on a block of distorted tets:
    every ``Dm^-1`` entry and volume to round-off, in the layout of ``BlockLayout.rest``; in the
    triangular form (``triangular_rest_from_corners_block``), every entry of ``R^-1`` against the
    layout's, found from ``Dm^-1``."""
    points, tets, _ = mesh((4, 4, 4))
    X = points + 0.1 * np.random.default_rng(5).normal(size=points.shape)
    tets = tets[:BLOCK]
    Dm_inv, V0 = rest_state(X, tets)
    assert V0.min() > 0
    block_tets, block_rest = block_layout(tets, Dm_inv, V0, triangular=triangular)
    assert block_rest.shape[2] == (TRIANGULAR_REST_ROWS if triangular else REST_ROWS)
    buf = np.zeros(SCRATCH_ROWS * BLOCK)
    gather_corners(X, block_tets, 0, buf, False, ROW_F)
    (triangular_rest_from_corners_block if triangular else rest_from_corners_block)(buf)
    computed = buf[ROW_REST * BLOCK:ROW_REST * BLOCK + block_rest[0].size].reshape(block_rest[0].shape)
    scale = np.abs(block_rest[0]).max(axis=(0, 2), keepdims=True)       # per row: Dm^-1 entries, volumes
    assert (np.abs(computed - block_rest[0]) <= 1e-13 * scale).all()


def test_gravity_alone_gives_the_bits_of_a_per_vertex_acceleration_array():
    """Without tractions the step reads ``gravity`` and no per-vertex array (``external_accel``
    None): the same velocities, to the bit, as the array of gravity in every row."""
    points, tets, x = mesh((7, 5, 3))
    body = Body(points, tets, "colour")
    lam, mu = model_lame_parameters("stvk", E_PA, NU)
    inv_mass = np.random.default_rng(3).uniform(0.5, 2.0, body.node_count)
    gravity = (0.1, -0.2, -9.81)
    alone = body.forces(x, "stvk", lam, mu, inv_mass, gravity, None)
    rows = body.forces(x, "stvk", lam, mu, inv_mass, gravity, np.tile(gravity, (body.node_count, 1)))
    assert np.array_equal(alone, rows)
    still = body.forces(x, "stvk", lam, mu, inv_mass, (0.0, 0.0, 0.0), None)
    assert np.abs(alone - still - np.array(gravity)).max() < 1e-9 * np.abs(still).max()


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_rest_data_vertex_forces_and_scratch_start_at_a_cache_line(dtype):
    """The rest data (rows of one cache line), the colour scatter's vertex forces (a vector row per
    vertex) and the step's scratch buffer start at a cache line, whatever NumPy's and Numba's
    allocators give (16 and 32 bytes); the vertex forces start zeroed."""
    points, tets, _ = mesh((7, 5, 3))
    body = Body(points, tets, "colour")
    layout = build_block_layout(body.tets, body.Dm_inv, body.V0, body.node_count, dtype=dtype, model=MODEL_IDS["stvk"])
    assert layout.rest.ctypes.data % CACHE_LINE_BYTES == 0 and layout.rest.flags.c_contiguous
    body.precision = np.dtype(dtype).name
    forces = force_buffer(body, dtype)
    assert forces.ctypes.data % CACHE_LINE_BYTES == 0 and forces.dtype == dtype and not forces.any()
    for size in (1, 37 * BLOCK, 1000):
        buf = scratch_address(size, np.zeros(1, dtype))
        assert buf[0] % CACHE_LINE_BYTES == 0 and buf[1] == size


@numba.njit
def scratch_address(size, like):
    buf = cache_aligned_scratch(size, like)
    return buf.ctypes.data, buf.size


def test_fewer_tets_than_a_block():
    points, tets, x = mesh((1, 1, 1))
    for scatter in ("colour", "csr"):
        body = Body(points, tets, scatter)
        lam, mu = model_lame_parameters("stvk", E_PA, NU)
        f_naive = naive.elastic_forces(x, body.X, body.tets, "stvk", lam, mu)
        np.testing.assert_allclose(body.forces(x, "stvk", lam, mu), f_naive, rtol=0,
                                   atol=1e-11 * np.abs(f_naive).max())


def test_parts_of_one_colour_share_no_vertex():
    points, tets, _ = mesh((9, 6, 4))
    layout = Body(points, tets, "colour").blocks
    block_count = layout.tets.shape[0]
    part_count = layout.part_offsets.shape[0] - 1
    assert layout.colour_count >= 2
    assert np.array_equal(np.sort(layout.colour_parts), np.arange(part_count))
    lanes = np.arange(block_count * BLOCK).reshape(-1, BLOCK)
    for c in range(layout.colour_count):
        seen = set()
        for p in layout.colour_parts[layout.colour_offsets[c]:layout.colour_offsets[c + 1]]:
            vertices = set()
            for b in range(layout.part_offsets[p], layout.part_offsets[p + 1]):
                vertices |= set(layout.tets[b][:, lanes[b] < len(tets)].ravel().tolist())
            assert not (seen & vertices)
            seen |= vertices


@pytest.mark.parametrize("cells", [(40, 10, 10), (24, 24, 24), (64, 6, 30)])
def test_slab_order_makes_two_colours_of_equal_parts(cells):
    """Renumbered slab by slab (``mesh.reorder``), a beam, a cube and a plate, their slabs two cells
    thick or more, give the colour scatter two colours of four parts: two barriers per step,
    balanced on 1, 2 or 4 threads.  The parts hold equal block counts, to one block (cut at the
    slabs' equal vertex counts, the last held a third fewer tets: its end plane starts none).  In
    plain Morton order the beam needs 9 colours."""
    points, tets = structured_box(tuple(float(c) for c in cells), (0.0, 0.0, 0.0), 1.0)
    points, tets, _, _ = renumber_for_locality(points, tets, slabs=8)
    body = Body(points, tets, "colour")
    layout = build_block_layout(body.tets, body.Dm_inv, body.V0, body.node_count, "colour", slabs=8,
                                model=MODEL_IDS["stvk"])
    assert np.diff(layout.colour_offsets).tolist() == [4, 4]
    sizes = np.diff(layout.part_offsets)
    assert sizes.size == 8 and sizes.max() - sizes.min() <= 1


@pytest.mark.parametrize("scatter", ["colour", "csr"])
def test_blocked_forces_are_bitwise_deterministic_on_any_thread_count(scatter):
    points, tets, x = mesh((9, 6, 4))
    body = Body(points, tets, scatter)
    lam, mu = model_lame_parameters("neohookean", E_PA, NU)
    f1 = body.forces(x, "neohookean", lam, mu)
    assert f1.tobytes() == body.forces(x, "neohookean", lam, mu).tobytes()
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert f1.tobytes() == body.forces(x, "neohookean", lam, mu).tobytes()
        # more chunks than threads: one thread runs them in turn, the first taking every part
        assert f1.tobytes() == body.forces(x, "neohookean", lam, mu, chunks=4).tobytes()
    finally:
        numba.set_num_threads(threads)
    assert np.abs(f1.sum(axis=0)).max() < 1e-9 * np.abs(f1).max()     # Newton's third law


def with_prefetch(layout, ahead, node_count):
    """``layout`` as a large mesh's: fetching rest data and first-used vertex rows ``ahead`` blocks ahead."""
    return prefetching(layout, node_count, ahead)


# the two forms of rest data (triangular, full); the other laws' lane loops share the prefetch code
# but each compiles a step of its own (corotated: about two minutes)
@pytest.mark.parametrize("model, scatter", [
    ("stvk", "colour"), ("linear", "colour"), ("stvk", "csr"),
    *(pytest.param(model, scatter, marks=pytest.mark.slow)
      for model, scatter in [("linear", "csr"), ("neohookean", "colour"), ("neohookean", "csr"),
                             ("corotated", "colour"), ("corotated", "csr")])])
def test_prefetching_changes_no_bit(model, scatter):
    """A large mesh's step fetches the rest data of later blocks into L2 (``BlockLayout.prefetch``),
    and the rows of the vertices they use first; forced onto a small mesh (whose own layout has
    none), it computes the same bits, up to the last block, where the block ahead is clamped to
    the last."""
    points, tets, x = mesh((9, 6, 4))
    body = Body(points, tets, scatter)
    assert body.blocks.prefetch is None and body.blocks.first_vertices.size == 0
    lam, mu = model_lame_parameters(model, E_PA, NU)
    plain = body.forces(x, model, lam, mu)
    layout = body.blocks
    for ahead in (1, PREFETCH_BLOCKS_AHEAD):
        body.blocks = with_prefetch(layout, ahead, body.node_count)
        assert body.blocks.first_vertices.size > 0
        assert body.forces(x, model, lam, mu).tobytes() == plain.tobytes()
    # rest data computed in the step: the prefetch (of the rest positions' rows too) changes no bit either
    body.blocks = dataclasses.replace(layout, rest_from_points=True)
    computed = body.forces(x, model, lam, mu)
    body.blocks = dataclasses.replace(with_prefetch(layout, PREFETCH_BLOCKS_AHEAD, body.node_count), rest_from_points=True)
    assert body.forces(x, model, lam, mu).tobytes() == computed.tobytes()


def test_first_uses_list_each_vertex_of_a_part_once_at_the_block_that_uses_it_first():
    """Checked against a plain walk over each part's blocks in order."""
    points, tets, _ = mesh((9, 6, 4))
    layout = Body(points, tets, "colour").blocks
    first_offsets, first_vertices = first_uses(layout.tets, layout.part_offsets, len(points))
    assert first_vertices.dtype == np.uint32 and first_offsets[-1] == first_vertices.size
    for p in range(layout.part_offsets.shape[0] - 1):
        seen = set()
        for b in range(layout.part_offsets[p], layout.part_offsets[p + 1]):
            used = set(layout.tets[b].ravel().tolist())
            listed = first_vertices[first_offsets[b]:first_offsets[b + 1]].tolist()
            assert listed == sorted(used - seen)
            seen |= used


def test_only_meshes_whose_rest_data_outgrow_the_cache_prefetch():
    """The threshold is on the bytes of rest data: about 100k tets in float64 (``linear``: 80 B a
    tet; 150k in the triangular form's 56), twice that in float32."""
    linear, stvk = MODEL_IDS["linear"], MODEL_IDS["stvk"]
    tets_over = PREFETCH_FROM_BYTES // (10 * 8) + BLOCK
    tets = np.zeros((tets_over, 4), dtype=np.int64)
    Dm_inv, V0 = np.zeros((tets_over, 3, 3)), np.zeros(tets_over)
    large = build_block_layout(tets, Dm_inv, V0, 1, model=linear)
    assert large.prefetch == PREFETCH_BLOCKS_AHEAD and large.measure_prefetch    # the run times it against none
    unprefetched = large.unprefetched
    assert unprefetched is large.unprefetched                                     # made once
    assert unprefetched.prefetch is None and unprefetched.first_vertices.size == 0 and not unprefetched.measure_prefetch
    assert not prefetching(large, 1, PREFETCH_BLOCKS_AHEAD).measure_prefetch     # forced: always
    parts = large.part_offsets[:-1]                 # one vertex, first used by each part's first block
    assert large.first_vertices.tolist() == [0] * parts.size and np.diff(large.first_offsets)[parts].tolist() == [1] * parts.size
    assert build_block_layout(tets, Dm_inv, V0, 1, dtype=np.float32, model=linear).prefetch is None
    assert build_block_layout(tets[:tets_over // 2], Dm_inv[:tets_over // 2], V0[:tets_over // 2], 1,
                              model=linear).prefetch is None
    Dm_inv[:] = np.eye(3)                      # the triangular form factors Dm: it must be invertible
    assert build_block_layout(tets, Dm_inv, V0, 1, model=stvk).prefetch is None
    triangular_over = PREFETCH_FROM_BYTES // (7 * 8) + BLOCK
    tets, Dm_inv, V0 = np.zeros((triangular_over, 4), np.int64), np.tile(np.eye(3), (triangular_over, 1, 1)), np.zeros(triangular_over)
    assert build_block_layout(tets, Dm_inv, V0, 1, model=stvk).prefetch == PREFETCH_BLOCKS_AHEAD


@pytest.mark.parametrize("model", ["stvk", "linear"])      # rest data in the triangular form, and the full one
def test_only_float64_meshes_whose_rest_data_outgrow_the_threshold_compute_them_in_the_step(monkeypatch, model):
    """``BlockLayout.rest_from_points`` above ``REST_FROM_POINTS_BYTES`` of rest data, in float64
    only (float32 steps hold displacements, and its rest data are half the bytes) and in the full
    form only (the triangular form is slower computed than read); the layout keeps the form the
    step reads, also where asked to compute them."""
    points, tets, _ = mesh((4, 3, 3))
    Dm_inv, V0 = rest_state(points, tets)
    model = MODEL_IDS[model]
    triangular = uses_triangular_rest(model, np.float64)
    rest_bytes = block_layout(tets, Dm_inv, V0, triangular=triangular)[1].nbytes
    for threshold, expected in ((rest_bytes - 1, True), (rest_bytes, False)):
        monkeypatch.setattr(blocked, "REST_FROM_POINTS_BYTES", threshold)
        layout = build_block_layout(tets, Dm_inv, V0, len(points), model=model)
        expected &= not triangular
        assert layout.rest_from_points is expected
        assert layout.rest.shape[0] == (0 if expected else layout.tets.shape[0])     # stored only where read
        assert layout.rest.dtype == np.float64 and layout.triangular is triangular
    monkeypatch.setattr(blocked, "REST_FROM_POINTS_BYTES", 0)
    assert not build_block_layout(tets, Dm_inv, V0, len(points), dtype=np.float32, model=model).rest_from_points
    stored = build_block_layout(tets, Dm_inv, V0, len(points), rest_from_points=False, model=model)   # asked for: stored
    assert not stored.rest_from_points and stored.rest.nbytes == rest_bytes
    computing = build_block_layout(tets, Dm_inv, V0, len(points), rest_from_points=True, model=model)
    assert computing.rest_from_points and computing.rest.shape[0] == 0 and computing.triangular is triangular


@pytest.mark.parametrize("model, dtype, triangular", [
    ("stvk", np.float64, True), ("neohookean", np.float64, True), ("corotated", np.float64, True),
    ("linear", np.float64, False), ("stvk", np.float32, False), ("linear", np.float32, False)])
def test_the_objective_laws_take_the_triangular_rest_data_in_float64_and_the_step_checks_the_form(model, dtype,
                                                                                                   triangular):
    """Float64 StVK, neo-Hookean and corotated read ``R^-1`` and ``V0`` (7 rows a group); ``linear``
    (not invariant under a turn of the rest frame) and float32 (displacements) ``Dm^-1`` and ``V0``
    (10).  A step given the other form refuses it, naming both."""
    points, tets, _ = mesh((4, 3, 3))
    Dm_inv, V0 = rest_state(points, tets)
    assert uses_triangular_rest(MODEL_IDS[model], dtype) is triangular
    layout = build_block_layout(tets, Dm_inv, V0, len(points), dtype=dtype, model=MODEL_IDS[model])
    assert layout.triangular is triangular
    assert layout.rest.shape[2] == (TRIANGULAR_REST_ROWS if triangular else REST_ROWS)
    other = "linear" if triangular else "stvk"
    with pytest.raises(ValueError, match="triangular" if not triangular else "full"):
        layout.check_model(MODEL_IDS[other], np.float64)
    layout.check_model(MODEL_IDS[model], dtype)
    if dtype == np.float64:                        # the step itself: a linear_block over 7 rows would read past them
        body = Body(points, tets, "colour", model=model)
        step_arguments(body, work_buffer(body))
        body.material_id = MODEL_IDS[other]
        with pytest.raises(ValueError, match="this step needs float64 in the"):
            step_arguments(body, work_buffer(body))


def test_the_step_refuses_a_layout_that_neither_holds_nor_computes_its_rest_data():
    points, tets, _ = mesh((4, 3, 3))
    body = Body(points, tets, "colour", rest_from_points=True)
    body.blocks = dataclasses.replace(body.blocks, rest_from_points=False)
    with pytest.raises(ValueError, match="no rest data"):
        step_arguments(body, work_buffer(body))


def test_prefetching_sets_the_distance_and_lists_the_first_uses_only_with_vertex_rows():
    """``prefetching`` forces a layout's prefetch on or off; the first-use lists come only with a
    distance and ``vertex_rows``, else they are empty (nothing to fetch, one offset per block)."""
    points, tets, _ = mesh((9, 6, 4))
    layout = Body(points, tets, "colour").blocks
    blocks = layout.tets.shape[0]
    full = prefetching(layout, len(points), 2)
    expected = first_uses(layout.tets, layout.part_offsets, len(points))
    assert full.prefetch == 2
    assert full.first_offsets.tolist() == expected[0].tolist() and full.first_vertices.tolist() == expected[1].tolist()
    for ahead, rows in ((2, False), (None, True)):
        bare = prefetching(full, len(points), ahead, vertex_rows=rows)
        assert bare.prefetch == ahead and bare.first_vertices.size == 0
        assert bare.first_offsets.shape == (blocks + 1,) and not bare.first_offsets.any()


def test_small_meshes_step_on_fewer_threads():
    """A thread per ``TETS_PER_THREAD`` tets on TBB (per ``TETS_PER_THREAD_OTHER_LAYERS`` on other
    threading layers), at least one, at most those available."""
    from softsim.integrators.symplectic_euler import TETS_PER_THREAD, TETS_PER_THREAD_OTHER_LAYERS, step_threads

    assert step_threads(0, 2) == 1
    assert step_threads(2 * TETS_PER_THREAD - 1, 2) == 1
    assert step_threads(2 * TETS_PER_THREAD, 2) == 2
    assert step_threads(10 ** 7, 2) == 2
    assert step_threads(10 ** 7, 16) == 16
    assert step_threads(5 * TETS_PER_THREAD, 16) == 5
    assert step_threads(2 * TETS_PER_THREAD, 2, "omp") == 1            # tens of microseconds a region
    assert step_threads(2 * TETS_PER_THREAD_OTHER_LAYERS, 2, "workqueue") == 2


def test_owned_vertices_are_cut_into_runs_of_consecutive_indices_within_each_part():
    run_offsets, runs = owned_vertex_runs(np.array([0, 4, 4, 7]), np.array([0, 1, 3, 4, 2, 5, 6]))
    assert run_offsets.tolist() == [0, 2, 2, 4] and runs.tolist() == [[0, 2], [3, 5], [2, 3], [5, 7]]
    run_offsets, runs = owned_vertex_runs(np.array([0, 2, 4]), np.arange(4))     # consecutive across parts
    assert run_offsets.tolist() == [0, 1, 2] and runs.tolist() == [[0, 2], [2, 4]]
    run_offsets, runs = owned_vertex_runs(np.array([0, 0]), np.empty(0, np.int64))
    assert run_offsets.tolist() == [0, 0] and runs.shape == (0, 2)


def test_each_vertex_is_moved_by_the_first_part_in_colour_order_that_uses_it():
    points, tets = structured_box((24.0, 6.0, 6.0), (0.0, 0.0, 0.0), 1.0)
    points, tets, _, _ = renumber_for_locality(points, tets, slabs=8)
    points = np.vstack([points, [[99.0, 99.0, 99.0]]])          # a vertex no tet uses
    body = Body(points, tets, "colour")
    layout = body.blocks
    owner = np.full(body.node_count, -1)
    for p in range(layout.part_offsets.shape[0] - 1):
        runs = layout.owned_runs[layout.run_offsets[p]:layout.run_offsets[p + 1]].astype(np.int64)
        assert layout.owned_runs.dtype == np.uint64 and (runs[:, 1] > runs[:, 0]).all()
        mine = np.concatenate([np.arange(a, b) for a, b in runs]) if len(runs) else np.empty(0, np.int64)
        assert (np.diff(mine) > 0).all() and (runs[1:, 0] > runs[:-1, 1]).all()     # runs as long as they go
        assert (owner[mine] == -1).all()
        owner[mine] = p
    assert (owner >= 0).all()                                   # every vertex exactly once
    rank = {p: r for r, p in enumerate(layout.colour_parts)}
    lanes = np.arange(layout.tets.shape[0] * BLOCK).reshape(-1, BLOCK)
    for p in range(layout.part_offsets.shape[0] - 1):
        for b in range(layout.part_offsets[p], layout.part_offsets[p + 1]):
            used = layout.tets[b][:, lanes[b] < len(tets)].ravel()
            assert all(rank[owner[i]] <= rank[p] for i in used)
    assert owner[-1] == layout.colour_parts[0]


def numpy_steps(model, state, dt, steps, damping):
    """``steps`` symplectic-Euler steps in plain NumPy (``tests/naive.py`` forces): the reference for
    the compiled step's order of updates (forces of step s from the positions of step s, each vertex
    moved once a step), with the ground's penalty contact and friction."""
    x, v = state.x.copy(), state.v.copy()
    faces = model.boundary_faces
    name = {1: "stvk"}[model.material_id]
    for s in range(state.step, state.step + steps):
        f = naive.elastic_forces(x, model.rest_points, model.tets, name, model.lam, model.mu)
        v += dt * (f * model.inv_mass[:, None] + model.external_accel)
        if model.has_ground:
            p = x[faces]
            share = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                     - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])) / 6.0
            area_z = np.zeros(len(x))
            np.add.at(area_z, faces.ravel(), np.repeat(share, 3))
            depth = model.ground_height - x[:, 2]
            touching = depth > 0.0
            dv = dt * model.ground_stiffness * depth * np.maximum(0.0, -area_z) * model.inv_mass
            dv = np.where(touching, dv, 0.0)
            v[:, 2] += dv
            vt = np.hypot(v[:, 0], v[:, 1])
            stop = touching & (vt <= model.ground_friction * dv)
            scale = np.where(touching & ~stop, 1.0 - model.ground_friction * dv / np.where(vt > 0, vt, 1.0), 1.0)
            v[:, :2] *= np.where(stop, 0.0, scale)[:, None]
        v *= np.exp(-damping * dt)
        x += dt * v
        t = (s + 1) * dt
        x = np.where(model.held, state.held_start + model.held_velocity * t, x)
        v = np.where(model.held, model.held_velocity, v)
    return x, v


@pytest.mark.parametrize("scatter", ["colour", CSR_SLOW])
@pytest.mark.parametrize("ground", [False, True])
def test_moving_vertices_inside_the_parts_matches_a_numpy_step(ground, scatter, monkeypatch):
    """The colour scatter moves each part's vertices at the start of the part's next step (and,
    with a ground, sums the boundary faces' areas per part): over several calls, with damping, a
    driven face and a ground the beam presses into, it follows a plain NumPy step to round-off,
    with the same bits on 1 and 2 threads, the parts of a call in one region or in a region per
    colour and step (``PartSchedule``).  The csr scatter (a vertex loop of its own) too."""
    from softsim import simulation
    from softsim.config import parse_scene
    from softsim.model import initial_state

    monkeypatch.setattr(simulation, "step_threads", lambda tets, available, layer: available)
    scene = {"mesh": {"shape": "box", "size": [1.0, 0.25, 0.25], "element_size": 0.05, "structured": True},
             "material": {"model": "stvk", "youngs_modulus": 1e6, "poissons_ratio": 0.3, "density": 1000.0},
             "fixed": [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]},
                       {"min": [1 - 1e-6, -1, -1], "max": [2, 1, 1], "axes": ["y"], "velocity": [0, 0.5, 0]}],
             "initial_velocity": [0.0, 0.0, -2.0], "damping": 3.0, "time": {"duration": 1.0}}
    if ground:
        scene["ground"] = {"height": 0.0005, "stiffness": 1e7, "friction": 0.3}
    prepared = simulation.prepare(parse_scene(scene))
    model = prepared.model
    assert model.blocks.colour_count == 2
    if scatter == "csr":
        model = dataclasses.replace(model, blocks=build_block_layout(model.tets, model.Dm_inv, model.rest_volume,
                                                                     model.node_count, "csr",
                                                                     model=model.material_id))
    dt = prepared.plan.dt
    results = []
    for threads, one_region in ((1, True), (2, True), (2, False)):
        numba_threads = numba.get_num_threads()
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        monkeypatch.setattr(simulation.PART_SCHEDULE, "one_region", lambda: one_region)
        try:
            state = initial_state(prepared.scene, model)
            work = simulation.work_buffer(model)
            for count in (7, 1, 12):
                simulation.step(model, state, dt, count, prepared.scene.damping, work)
            results.append((state.x.copy(), state.v.copy()))
        finally:
            numba.set_num_threads(numba_threads)
    for x, v in results[1:]:
        assert results[0][0].tobytes() == x.tobytes() and results[0][1].tobytes() == v.tobytes()
    x_ref, v_ref = numpy_steps(model, initial_state(prepared.scene, model), dt, 20, prepared.scene.damping)
    moved = np.abs(x_ref - model.rest_points).max()
    assert moved > 1e-4
    if ground:
        assert (x_ref[:, 2] < 0.0005).sum() > 10              # the beam is in contact
    np.testing.assert_allclose(results[0][0], x_ref, rtol=0, atol=1e-9 * moved)
    np.testing.assert_allclose(results[0][1], v_ref, rtol=0, atol=1e-9 * np.abs(v_ref).max())


def test_the_blocked_element_checks_match_naive_volume_ratios_and_stretches():
    """The guard's J = det F and RMS stretch |F| / sqrt(3), computed in the step's vectorised
    blocks, match NumPy's per tet to round-off (a mesh whose tet count is no multiple of the block
    size, some tets inverted), and the per-tet kernel's."""
    from softsim.kernels.element_checks import block_volume_ratios_and_stretches, element_volume_ratios_and_stretches

    points, tets, x = mesh((7, 5, 3))
    body = Body(points, tets, "colour")
    assert body.tet_count % BLOCK != 0
    x[tets[:40, 0]] = x[tets[:40, 1:]].mean(axis=1) * 2.0 - x[tets[:40, 0]]    # mirror corner 0: inverted
    m = body.tet_count
    J, stretch = np.full(m, np.nan), np.full(m, np.nan)
    ones = np.ones(m)
    assert block_volume_ratios_and_stretches(x, body.blocks.tets, body.blocks.rest,
                                             CompileTimeConstant(body.blocks.triangular), m, body.blocks.whole_rows,
                                             J, stretch, ones, ones, 0.05)     # the inverted ones moved
    Ds = np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    F = Ds @ body.Dm_inv
    np.testing.assert_allclose(J, np.linalg.det(F), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(stretch, np.sqrt((F * F).sum(axis=(1, 2)) / 3.0), rtol=1e-13)
    assert (J < 0).sum() >= 10
    J_tet, stretch_tet = np.empty(m), np.empty(m)
    assert element_volume_ratios_and_stretches(x, body.tets, body.Dm_inv, J_tet, stretch_tet, ones, ones, 0.05)
    np.testing.assert_allclose(J, J_tet, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(stretch, stretch_tet, rtol=1e-14)
