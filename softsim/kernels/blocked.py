"""Elastic forces of blocks of ``BLOCK`` tets at a time, written so that LLVM vectorises them.

The per-tet kernel of ``forces.py`` reads ``x[tets[e]]`` and ``Dm_inv[e]`` from 2D/3D arrays and
compiles to scalar code.  Here the tets are grouped into blocks of ``BLOCK`` and every quantity of a
block is one row of ``BLOCK`` lanes (structure of arrays), read from the block's rest data
``rest = block_rest[b]`` and a flat scratch buffer ``buf``:

    rest rows 0..8   Dm^-1 (row-major)          [1/m]     lanes in groups of L: rest[g, row, l]
    rest row  9      rest volume V0             [m^3]     is lane g L + l
      or, the triangular form (float64, the objective laws; ``rotated_rest``):
    rest rows 0..5   R^-1 of Dm = Q R           [1/m]     entries 00, 01, 02, 11, 12, 22
    rest row  6      rest volume V0             [m^3]
    buf rows  0..11  corner positions x_c,k     [m]       gathered from ``x``: row 3 c + k
                     (or corner displacements u_c,k = x - X, in the displacement form below)
    buf rows 12..23  corner forces f_c,k        [N]       row 12 + 3 c + k
                     (the guard's element checks: J and the stretch in rows 12 and 13)
    buf rows 24..36  corotated only: the lanes' next stage, Newton's state (see ``corotated_block``)
    buf rows 37..46  where the step computes the rest data (``rest_from_corners_block``): the
                     block's rest rows in the layout of ``block_rest[b]`` (groups, 10 or 7, lanes)

Row offsets are compile-time constants and every access of the lane loop is ``rest[g, row, l]`` or
``buf[row * BLOCK + j]``: LLVM emits packed SIMD code (AVX2 / AVX-512), its one runtime alias check
(``rest`` against ``buf``) outside the loop over a group's lanes.  Each lane loop's function calls
``simd.prefer_wide_vectors``: LLVM's tuning for Intel's AVX-512 cores prefers 256-bit vectors, and
left to it the loops compiled to ymm on an AVX-512 Xeon (KVM); in zmm the step ran 1.06, 1.08
and 1.03x as fast at 10k, 100k and 1M tets (StVK, 2 threads, one process), float32 StVK 1.09x,
corotated 1.13x and neohookean 1.05x at 100k.  The rest rows are read in place:
copying them into the buffer, as an earlier version did, cost as much as gathering the corners.
They are stored in groups of lanes, a group's ten rows one after the other, each row one cache
line (``REST_ROW_BYTES``: 8 lanes in float64, 16 in float32, ``lanes_per_group``), so that a
block's rest data is read in address order, a vector of lanes at a time.  Streaming such rows from
memory on one core (float64): ten rows of 64 lanes (ten interleaved streams 512 B apart) 11 GB/s,
groups of 16 lanes 22 GB/s, of 8 lanes 31 GB/s.  LLVM does not vectorise a loop of fewer than 16
iterations that needs a runtime alias check unless told (``jit.VECTORIZER_MIN_TRIP_COUNT``);
float64 groups held 16 lanes until it was.  With 8, one thread, the gather and the lane loop of
StVK on the beam took 5.36 against 7.31 ns a tet at 100k tets (4.89 against 5.65 with one block's
rest data in cache) and 9.65 against 12.13 at 2M (without the prefetches below).  On a mesh whose rest data exceed
``PREFETCH_FROM_BYTES``, before a group's lane loop, the same group of the block
``PREFETCH_BLOCKS_AHEAD`` further on is fetched into L2 (``prefetch_rows``): the hardware
prefetcher alone left the lane loop waiting on memory.  So are, before each block, the rows of
``x`` and of the vertex forces of the vertices that the block as far ahead is the first of its
part to use (``first_uses``, ``prefetch_vertex_rows``): the gather and the scatter waited on them
too.  Where a large last-level cache holds such a mesh the prefetches cost more than they save,
so the run times the step with them and without them and keeps the faster
(``BlockLayout.measure_prefetch``).  The material law in the lane loop is the 9-tuple function of ``materials.models``,
inlined; one lane loop per model keeps the law a compile-time choice.  (Corotated's takes
Newton's scaled iterate and ``-V0`` in its scalars, ``lane_store_corotated_forces``.)

Forces (Sifakis & Barbic 2012, section 4.3): ``H = -V0 P(F) Dm^-T``; its columns are the forces on
corners 1, 2, 3 and ``f0 = -(h1 + h2 + h3)``, exactly as ``forces.tet_corner_forces`` computes them.
StVK, neo-Hookean and corotated in float64 take their rest data in the triangular form
(``uses_triangular_rest``): ``F_r = Ds R^-1`` and ``H = -V0 P(F_r) R^-T``, the same forces for a
law with ``P(F Q^T) = P(F) Q^T`` (``rotated_rest``), with 18 multiply-adds instead of 27 for each
product and 56 bytes of rest data a tet instead of 80.  Beam, 2 threads, two alternating processes
each, against the full form: StVK 1.08-1.12x at 100k tets, 1.26-1.27x at 1M, 1.08-1.09x at 2M;
neo-Hookean 1.07-1.09x and corotated 1.03-1.06x at 100k.

Precision: the buffer has the dtype of ``x`` and ``block_rest``.  In float64 the corner rows hold
positions and the laws take ``F``; in float32 they hold displacements ``u = x - X`` and the laws take
``H = Du Dm^-1 = F - I`` (``materials.models``, displacement form), so that small strains survive
float32's 7 digits.

Blocks are padded to a whole block: a padding lane repeats the block's first tet with ``V0 = 0``,
so it computes finite zero forces and the scatter skips it.
"""

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import types
from numba.core.errors import TypingError
from numba.extending import overload
from numba.np.numpy_support import as_dtype

from ..materials.models import (
    COROTATED,
    LINEAR,
    MODEL_IDS,
    NEOHOOKEAN,
    REST_FRAME_INVARIANT,
    STVK,
    corotated_weighted_stress,
    linear_weighted_first_piola,
    linear_weighted_first_piola_displacement,
    neohookean_weighted_first_piola,
    neohookean_weighted_first_piola_displacement,
    stvk_weighted_first_piola,
    stvk_weighted_first_piola_displacement,
)
from ..mesh.reorder import SLABS
from .jit import njit, njit_inline
from .mat3 import (mat3_cofactor_inline, mat3_ddot_inline, mat3_det_inline, mat3_mul_inline,
                   mat3_mul_transpose_b_inline, mat3_scale_inline)
from .polar3 import (NEWTON_FIRST_STEPS, NEWTON_MIN_FIRST_STEPS, jacobi_rotation_and_stretch, newton_polar_finish,
                     newton_polar_start, newton_polar_start_three, newton_polar_start_two)
from .rotated_rest import TRIANGULAR_ENTRIES, triangular_rest_inverse, triangular_rest_inverses
from .simd import (CACHE_LINE_BYTES, FORCE_COLUMNS, SCATTER_LANES, add_corner_force, add_four_lanes_corner_forces,
                   gather_corner_rows, prefer_wide_vectors, prefetch_line)

BLOCK = 64                 # tets per block (a multiple of the SIMD width: 8 doubles in AVX-512)
REST_ROW_BYTES = 64        # bytes of a row of a group of rest data (one cache line): 8 float64 lanes, 16 float32
ROW_DM_INV = 0             # rows of ``block_rest[b, g]``, the full form
ROW_VOLUME = 9
REST_ROWS = 10
ROW_TRIANGULAR_VOLUME = 6  # the triangular form: rows 0..5 R^-1 (``rotated_rest``), 6 V0
TRIANGULAR_REST_ROWS = 7
ROW_X = 0                  # rows of the scratch buffer
ROW_F = 12
ROW_J = ROW_F              # the guard's element checks: J = det F
ROW_STRETCH = ROW_F + 1    # and the RMS stretch |F| / sqrt(3)
ROW_STAGE = 24             # corotated: what a lane still needs: STAGE_DONE, STAGE_NEWTON or STAGE_JACOBI
ROW_LIST = 25              # corotated: the lanes a scalar pass redoes, listed first
ROW_NEWTON = 26            # corotated: rows 26..34 ``Z`` of Newton's iteration (X_k = inv Z), 35 inv, 36 det F
ROWS = 37                  # rows of the scratch buffer; ``ROWS * BLOCK`` floats
ROW_REST = ROWS            # computed rest data (rest_from_points): REST_ROWS rows more
SCRATCH_ROWS = ROW_REST + REST_ROWS   # rows of the step's scratch buffer, computed rest data included
STAGE_DONE = 0.0           # corotated, row ROW_STAGE: forces stored
STAGE_NEWTON = 1.0         # Newton's last two steps to take (det F > 0, the first steps did not settle)
STAGE_JACOBI = 2.0         # the Jacobi SVD to take (det F <= 0, or Newton did not converge)


REST_FRAME_INVARIANT_IDS = tuple(MODEL_IDS[name] for name in REST_FRAME_INVARIANT)


def uses_triangular_rest(model, dtype):
    """Whether the step of ``model`` (``materials.models`` id) in ``dtype`` takes its rest data in
    the triangular form: float64 (float32 takes displacements, whose law needs ``Dm^-1`` itself)
    and a law whose stress turns with the rest frame (``materials.models.REST_FRAME_INVARIANT``:
    not ``linear``; ``rotated_rest``)."""
    return np.dtype(dtype) == np.float64 and model in REST_FRAME_INVARIANT_IDS


def rest_rows(triangular):
    """Rows of a group of rest data: ``TRIANGULAR_REST_ROWS`` in the triangular form, else ``REST_ROWS``."""
    return TRIANGULAR_REST_ROWS if triangular else REST_ROWS


def lanes_per_group(dtype):
    """Lanes of a group of rest data in ``dtype``: a group's rows are ``REST_ROW_BYTES`` each (8
    float64 lanes, 16 float32), the trip count of the lane loops."""
    return REST_ROW_BYTES // np.dtype(dtype).itemsize


def group_lanes(rest):
    """``lanes_per_group`` of the rest data ``rest`` (an array); in compiled code a constant."""
    return lanes_per_group(rest.dtype)


@overload(group_lanes, inline="always")
def _group_lanes_constant(rest):
    lanes = lanes_per_group(as_dtype(rest.dtype))
    return lambda rest: lanes


# Meshes whose rest data exceed ``PREFETCH_FROM_BYTES`` fetch the rest data of the block
# ``PREFETCH_BLOCKS_AHEAD`` blocks ahead into L2, a group's rows (20 cache lines in float64) before
# each group's lane loop (``prefetch_rows``).  Without it the rows come from memory when the lane
# loop reads them: the hardware prefetcher does not run far enough ahead.  Beam, 2 threads, this
# host (AVX-512, Zen 4), against no prefetch, 3 alternating processes per variant, one run:
#     tets                      10k     100k    310k    1M
#     1 block ahead, L2         0.90    0.98    1.07    1.25
#     2 blocks ahead, L2        0.91    0.98    1.11    1.17
#     1 / 2 / 4 ahead, NTA      0.85-0.87  0.96-1.02  0.96-1.02  1.12-1.13
# (another run, 2 ahead, L2: 0.94, 0.92, 1.41, 1.13 and 1.09 at 2M).  Timed in one process, the
# same compiled step on the same mesh (``python -m benchmarks``, section ``prefetch``), 2 ahead
# against none: 1.43 at 310k, 1.16 at 1M, 1.24 at 2M; 1, 3 or 4 ahead against 2: 0.98, 1.00, 0.91
# at 1M, 1.04, 1.02, 1.07 at 2M, 0.99, 0.93, 0.95 at 310k.  From process to process the same code
# varied by up to 1.5x at 1M, so one-process numbers are the ones to trust.  On a small mesh, whose data
# stay in cache, the prefetches cost more than they save: they are compiled out below the threshold
# (``BlockLayout.prefetch``).  Above it, the run times the step with them and without them and
# keeps the faster (``BlockLayout.measure_prefetch``): where the data fit in a large last-level
# cache (310k tets on a Xeon) they cost 7-12 %.  The same prefetches issued all at once at the start of a block gained
# 1.14x at 1M; into L1 (``prefetcht0``) they lost 6-12 %.
# The rows of the vertices a block uses first in its part (``first_uses``: about 14 a block on the
# beam, 0.2 a tet) are fetched as far ahead, before the block (``prefetch_vertex_rows``): a scatter
# of the 1M beam's forces alone, one thread, took 6.7 ns a tet without, 5.0 with (3.5 with its
# data in cache); the whole step, 2 threads, against the rest data prefetched alone, in one
# process: 1.09 at 310k, 1.19 at 1M, 1.16 at 2M (other runs: 1.03, 1.08-1.12, 1.18-1.25).  All corner
# rows of the block ahead (256 prefetches a block, not 28) lost 8-11 %; the corner indices of the
# block ahead, or the vertices a part reuses after more than 64 blocks, gained nothing.
PREFETCH_BLOCKS_AHEAD = 2
PREFETCH_FROM_BYTES = 8 * 2**20

# float64 meshes whose rest data exceed ``REST_FROM_POINTS_BYTES`` do not stream them in the step:
# each block computes its ``Dm^-1`` and ``V0`` from the rest positions of its corners, gathered
# like the current ones (``rest_from_corners_block``; ``BlockLayout.rest_from_points``).  80 bytes
# a tet then become the corners' rest rows, which neighbouring blocks share and cache holds, for
# a second gather and 4.5 ns a tet more work (one thread, a block in cache: 11.5 against 7.0 ns).
# Beam, 2 threads, one process, medians of 9 interleaved rounds, against the stored rest data
# (both prefetching): 0.83x at 310k, 0.97x at 1M (77 MiB of rest data), 1.13x
# at 2M (150 MiB).  (Every block reading the same rest data, always in cache, bounds what can be
# gained: 1.50x at 1M, 1.45x at 2M.)  In the triangular form (``uses_triangular_rest``) the rest data
# are 56 bytes a tet, and computing them takes Gram-Schmidt's two square roots and two divisions a
# tet: 0.73x at 310k, 0.77x at 1M and 0.79x at 2M against the stored ones (``python -m benchmarks``,
# section ``prefetch``), so that form is always stored unless asked for (``rest_from_points=True``).
REST_FROM_POINTS_BYTES = 128 * 2**20

# corotated: the Jacobi SVD of the lanes where Newton's polar iteration did not converge runs as
# a packed SIMD loop over the whole block (costing all 64 lanes) above this many such lanes, and
# lane by lane in scalar code up to it.  Measured on one block in L1 cache (AVX-512, Zen 4): the
# scalar code ~370 ns per lane, the packed loop ~55 ns per lane of the block: even at about 9 lanes.
FALLBACK_VECTOR_MIN_LANES = 9
# corotated: the last two Newton steps of the lanes the first four did not settle (strains above
# about 0.05) run packed over the whole block above this many lanes, lane by lane up to it.
# Measured on one block in L1 cache (AVX-512, Zen 4): the first stage 1140 ns a block; the packed
# second stage 650 ns more, a scalar lane 58 ns: even at about 11 lanes.  (The single pass of six
# steps before: 1300 ns a block.)
NEWTON_VECTOR_MIN_LANES = 11


# Scatter of the corner forces: ``colour`` adds each block's forces straight into the vertex forces,
# one colour of parts at a time (no per-tet buffer, a barrier per colour); ``csr`` writes them
# into a per-(tet, corner) buffer that each vertex then gathers (96 B/tet more traffic).  Colour is
# the default at every size: beam, M tet-steps/s, medians of 7 interleaved rounds (passive waits),
#     tets      colour 1 thread   colour 2 threads   csr 1 thread   csr 2 threads
#     2k        51.3              11.9               28.1           14.2
#     10k       44.4              34.8               32.2           33.0
#     40k       52.3              58.2               30.7           44.7
# (small meshes step on one thread: ``integrators.symplectic_euler.step_threads``); csr stays for
# comparison (``benchmarks``).
# The blocks are grouped into as many parts of consecutive blocks as ``mesh.reorder`` cuts slabs,
# of equal block counts (``slab_parts``; the tets are ordered slab by slab, so each part is a
# slab); parts sharing no vertex get one colour and are scattered in parallel.  Alternate parts
# make two colours of equal parts: two barriers per step.


@dataclass(frozen=True, eq=False)
class BlockLayout:
    """The tets of a model in blocks of ``BLOCK`` for the vectorised step (see the module docstring).

    tets (block_count, 4, BLOCK) uint32; rest (block_count, BLOCK // lanes, rows, lanes) [1/m, m^3], lanes
    ``lanes_per_group`` of its dtype, rows 10 (``Dm^-1``, V0) or in the triangular form 7 (``R^-1``,
    V0; ``uses_triangular_rest``); tet_count: real
    tets (the last block is padded); part_offsets (part_count + 1,): part p is blocks
    ``part_offsets[p]`` to ``part_offsets[p + 1] - 1``; colour_offsets (colours + 1,), colour_parts
    (part_count,): parts grouped by colour; run_offsets (part_count + 1,) int64, owned_runs (runs, 2)
    uint64: the vertices part p moves (``vertex_owners``), in runs of consecutive vertices, run r
    being vertices ``owned_runs[r, 0]`` to ``owned_runs[r, 1] - 1``, part p's runs
    ``run_offsets[p]`` to ``run_offsets[p + 1] - 1`` (``owned_vertex_runs``); scatter:
    ``"colour"`` or ``"csr"``; prefetch: how many blocks ahead the step fetches rest data into
    L2 (``PREFETCH_BLOCKS_AHEAD``), or None: not at all (a small mesh);
    first_offsets (block_count + 1,) int64, first_vertices uint32: the vertices block b is the
    first of its part to use, ``first_vertices[first_offsets[b]:first_offsets[b + 1]]``, whose
    rows the step fetches as far ahead (``first_uses``; empty when ``prefetch`` is None);
    whole_rows (block_count,) bool: block b does not use the last vertex, so its gather may load
    every corner's row as four values (``gather_corners``);
    rest_from_points: the step computes each block's rest data from the rest positions instead of
    reading ``rest`` (float64 rest data in the full form only, above ``REST_FROM_POINTS_BYTES``;
    ``rest_from_corners_block``);
    ``build_block_layout`` then stores none (``rest`` has no blocks), and so do the guard's element
    checks (``kernels.element_checks``);
    measure_prefetch: the run times calls of the step with the prefetches and without them
    (``unprefetched``) and keeps the faster (``integrators.symplectic_euler.PrefetchChoice``);
    False: the step always fetches as ``prefetch`` says.
    """

    tets: np.ndarray
    rest: np.ndarray
    tet_count: int
    part_offsets: np.ndarray
    colour_offsets: np.ndarray
    colour_parts: np.ndarray
    run_offsets: np.ndarray
    owned_runs: np.ndarray
    scatter: str
    prefetch: int | None
    first_offsets: np.ndarray
    first_vertices: np.ndarray
    whole_rows: np.ndarray
    rest_from_points: bool = False
    measure_prefetch: bool = False

    @property
    def colour_count(self):
        return self.colour_offsets.shape[0] - 1

    @property
    def triangular(self):
        """Whether the rest data are in the triangular form (``rotated_rest``)."""
        return self.rest.shape[2] == TRIANGULAR_REST_ROWS

    def check_model(self, model, dtype):
        """Raise ValueError unless the step of ``model`` (``materials.models`` id) in ``dtype`` reads
        this layout's rest data: its dtype, and its form (``uses_triangular_rest``)."""
        triangular = uses_triangular_rest(model, dtype)
        if self.rest.dtype != np.dtype(dtype) or self.triangular != triangular:
            form = {True: "triangular", False: "full"}
            raise ValueError(f"the layout's rest data are {self.rest.dtype} in the {form[self.triangular]} form; "
                             f"this step needs {np.dtype(dtype)} in the {form[triangular]} form "
                             f"(build_block_layout(model=...))")

    @functools.cached_property
    def unprefetched(self):
        """This layout without any prefetch (``prefetching(self, ..., None)``), made once."""
        return prefetching(self, 0, None)

    def points_for_rest(self, rest_points):
        """What the step and the guard's element checks take as ``rest_points``: the rest positions
        (n, 3) [m], C-contiguous, where they compute the rest data (``rest_from_points``), else None."""
        return np.ascontiguousarray(rest_points) if self.rest_from_points else None


def build_block_layout(tets, Dm_inv, rest_volume, node_count, scatter=None, slabs=SLABS, dtype=np.float64,
                       rest_from_points=None, *, model):
    """The ``BlockLayout`` of a mesh numbered by ``mesh.reorder.renumber_for_locality`` with as many
    ``slabs`` for the step of ``model`` (``materials.models`` id: it decides the form of the rest
    data, ``uses_triangular_rest``); ``scatter``: ``"colour"`` (None: the default) or ``"csr"``;
    ``dtype`` of the rest data: the precision of the step (float64 or float32).  rest_from_points:
    whether the step computes the rest data from the rest positions, the layout then holding none
    (None: above ``REST_FROM_POINTS_BYTES`` of float64 rest data in the full form; True / False for tests and
    benchmarks)."""
    triangular = uses_triangular_rest(model, dtype)
    rest_bytes = -(-tets.shape[0] // BLOCK) * BLOCK * rest_rows(triangular) * np.dtype(dtype).itemsize
    if rest_from_points is None:
        rest_from_points = np.dtype(dtype) == np.float64 and not triangular and rest_bytes > REST_FROM_POINTS_BYTES
    block_tets, block_rest = block_layout(tets, Dm_inv, rest_volume, dtype, with_rest=not rest_from_points,
                                          triangular=triangular)
    part_offsets = slab_parts(block_tets.shape[0], slabs)
    colour_offsets, colour_parts = part_colouring(block_tets, tets.shape[0], node_count, part_offsets)
    run_offsets, owned_runs = owned_vertex_runs(*vertex_owners(block_tets, tets.shape[0], node_count, part_offsets,
                                                               colour_parts))
    if scatter is None:
        scatter = "colour"
    first_offsets, first_vertices = no_first_uses(block_tets.shape[0])
    layout = BlockLayout(tets=block_tets, rest=block_rest, tet_count=int(tets.shape[0]), part_offsets=part_offsets,
                         colour_offsets=colour_offsets, colour_parts=colour_parts, run_offsets=run_offsets,
                         owned_runs=owned_runs, scatter=scatter, prefetch=None, first_offsets=first_offsets,
                         first_vertices=first_vertices,
                         whole_rows=block_tets.max(axis=(1, 2), initial=0) < node_count - 1,
                         rest_from_points=bool(rest_from_points))
    if rest_bytes > PREFETCH_FROM_BYTES:
        layout = dataclasses.replace(prefetching(layout, node_count, PREFETCH_BLOCKS_AHEAD), measure_prefetch=True)
    return layout


def prefetching(layout, node_count, ahead, vertex_rows=True):
    """``layout`` fetching the rest data ``ahead`` blocks ahead (None: not at all) and, with
    ``vertex_rows``, the rows of the vertices each block as far ahead uses first (``first_uses``;
    without: empty lists), always (``measure_prefetch`` False).  ``build_block_layout`` asks for it
    above ``PREFETCH_FROM_BYTES``, measured; tests and benchmarks force it on or off."""
    if ahead is not None and vertex_rows:
        first_offsets, first_vertices = first_uses(layout.tets, layout.part_offsets, node_count)
    else:
        first_offsets, first_vertices = no_first_uses(layout.tets.shape[0])
    return dataclasses.replace(layout, prefetch=ahead, first_offsets=first_offsets, first_vertices=first_vertices,
                               measure_prefetch=False)


def no_first_uses(block_count):
    """Empty first-use lists of ``block_count`` blocks (``BlockLayout.first_offsets``,
    ``first_vertices``): a layout that fetches no vertex rows."""
    return np.zeros(block_count + 1, dtype=np.int64), np.empty(0, np.uint32)


def slab_parts(block_count, slabs=SLABS):
    """``part_offsets`` (parts + 1,): ``slabs`` parts of consecutive blocks, as equal in block count
    as can be (empty ones dropped).  With the tets in the order of ``mesh.reorder.slab_order``
    (sorted by their first vertex) each part is a slab of the mesh, thick enough that parts two
    apart share no vertex (the colouring checks).  Cut instead at the slabs of equal vertex count,
    the last part, whose vertices start few tets, held 15 blocks against 20-21 (10k-tet beam): the
    other thread waited for the longer ones.  Equal parts against those, beam, 2 threads, one
    process, 9 rounds each: 0.99-1.04x at 10k tets (4 runs), 0.99 and 1.08 at 28k, 1.01 and 1.07
    at 100k, 1.06 at 1M: within the noise, a little ahead; still two colours on the beam and the
    example scenes of more than 2k tets."""
    return np.unique((np.arange(slabs + 1) * block_count) // slabs).astype(np.int64)


def first_uses(block_tets, part_offsets, node_count):
    """``(first_offsets, first_vertices)``: the vertices each block is the first of its part to use
    (the part's blocks taken in order), block b's ``first_vertices[first_offsets[b]:first_offsets[b + 1]]``,
    increasing.  Later blocks of the part find these vertices' rows in cache; the first one does not,
    and nor does the hardware prefetcher find them (Morton order within thin slabs, ``mesh.reorder``):
    the step fetches them ahead (``prefetch_vertex_rows``).  About 14 a block on the beam."""
    block_count = block_tets.shape[0]
    block_part = np.repeat(np.arange(part_offsets.shape[0] - 1), np.diff(part_offsets))
    corners = block_tets.reshape(block_count, 4 * BLOCK).astype(np.int64)
    _, first = np.unique((block_part[:, None] * node_count + corners).ravel(), return_index=True)
    block = first // (4 * BLOCK)
    vertex = corners.ravel()[first]
    order = np.lexsort((vertex, block))
    first_offsets = np.zeros(block_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(block, minlength=block_count), out=first_offsets[1:])
    return first_offsets, vertex[order].astype(np.uint32)


def block_layout(tets, Dm_inv, rest_volume, dtype=np.float64, with_rest=True, triangular=False):
    """``(block_tets, block_rest)``: the tets in blocks of ``BLOCK``, structure of arrays.

    block_tets: (block_count, 4, BLOCK) uint32 corner vertex indices; block_rest: (block_count,
    BLOCK // lanes, rows, lanes) ``dtype`` (rounded from float64; ``lanes = lanes_per_group(dtype)``),
    rows ``Dm^-1`` (9, row-major) [1/m] and ``V0`` [m^3], or with ``triangular`` the upper triangle
    of ``R^-1`` (6; ``rotated_rest``) and ``V0``.  Tet ``e`` is lane ``j = e % BLOCK`` of block ``e // BLOCK``, in block_rest
    ``[e // BLOCK, j // lanes, :, j % lanes]``; padding lanes repeat the block's first tet with V0 = 0.
    Without ``with_rest``, block_rest has no blocks (shape (0, BLOCK // lanes, rows, lanes)).
    """
    m = tets.shape[0]
    block_count = -(-m // BLOCK)
    padded = block_count * BLOCK
    lane_tet = np.arange(padded)
    lane_tet = np.where(lane_tet < m, lane_tet, (lane_tet // BLOCK) * BLOCK)
    block_tets = np.ascontiguousarray(tets[lane_tet].reshape(block_count, BLOCK, 4).transpose(0, 2, 1))
    lanes = lanes_per_group(dtype)
    rows = rest_rows(triangular)
    if not with_rest:
        return block_tets.astype(np.uint32), cache_aligned_empty((0, BLOCK // lanes, rows, lanes), dtype)
    rest = np.empty((padded, rows))
    if triangular:
        rest[:, :TRIANGULAR_ENTRIES] = triangular_rest_inverses(np.ascontiguousarray(Dm_inv, dtype=np.float64))[lane_tet]
    else:
        rest[:, :9] = Dm_inv.reshape(m, 9)[lane_tet]
    rest[:, rows - 1] = np.where(np.arange(padded) < m, rest_volume[lane_tet], 0.0)
    block_rest = cache_aligned_empty((block_count, BLOCK // lanes, rows, lanes), dtype)
    block_rest[...] = rest.reshape(block_count, BLOCK // lanes, lanes, rows).transpose(0, 1, 3, 2)
    return block_tets.astype(np.uint32), block_rest


def cache_aligned_empty(shape, dtype):
    """An uninitialised C-contiguous array whose data start at a cache line (``CACHE_LINE_BYTES``).

    NumPy aligns large arrays to 16 bytes only (the malloc header of an mmap'ed block), so a row
    of rest data meant to be one cache line (``REST_ROW_BYTES``) straddled two, and so did every
    second float64 row of the vertex forces (32 bytes).  Beam, float64, 2 threads, one process:
    the rest data aligned ran 1.06x as fast at 100k tets and 1.05x at 1M, the vertex forces 1.06x
    at 100k (the scatter alone, one thread, 100k: 3.15 against 3.82 ns a tet); float32 1.00x.  (A
    copy of the array, in a pickle or a Dask worker, is aligned as NumPy allocates it: the same
    results, a little slower.)
    """
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    raw = np.empty(count * dtype.itemsize + CACHE_LINE_BYTES, dtype=np.uint8)
    first = -raw.ctypes.data % CACHE_LINE_BYTES
    return raw[first:first + count * dtype.itemsize].view(dtype).reshape(shape)


@njit_inline
def cache_aligned_scratch(size, like):
    """An uninitialised 1D array of ``size`` values of ``like``'s dtype starting at a cache line
    (the compiled counterpart of ``cache_aligned_empty``: Numba aligns its arrays to 32 bytes)."""
    raw = np.empty(size + CACHE_LINE_BYTES // like.itemsize, dtype=like.dtype)
    first = (-raw.ctypes.data % CACHE_LINE_BYTES) // like.itemsize
    return raw[first:first + size]


def part_colouring(block_tets, tet_count, node_count, part_offsets):
    """``(colour_offsets, colour_parts)``: the parts of consecutive blocks given by ``part_offsets``,
    grouped so that no two parts of a colour share a vertex.

    Greedy colouring in part order.  The parts of colour ``c`` are
    ``colour_parts[colour_offsets[c]:colour_offsets[c + 1]]``, in increasing order: scattering one
    colour at a time, in parallel over its parts and in block order within a part, no two threads
    write the same vertex and every vertex receives its contributions in the same order on every
    run, whatever the thread count.
    """
    block_count = block_tets.shape[0]
    part_count = part_offsets.shape[0] - 1
    lanes = np.arange(block_count * BLOCK).reshape(block_count, 1, BLOCK)
    real = np.broadcast_to(lanes < tet_count, block_tets.shape)
    vertex = block_tets[real].astype(np.int64)
    block_part = np.repeat(np.arange(part_count), np.diff(part_offsets))
    part = np.broadcast_to(block_part[:, None, None], block_tets.shape)[real]
    pairs = np.unique(vertex * part_count + part)
    vertex, part = pairs // part_count, pairs % part_count
    # vertex -> parts (CSR, from the sorted pairs) and part -> vertices
    v_offsets = np.zeros(node_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(vertex, minlength=node_count), out=v_offsets[1:])
    order = np.argsort(part, kind="stable")
    p_offsets = np.zeros(part_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(part, minlength=part_count), out=p_offsets[1:])
    colour = _greedy_colours(v_offsets, part, p_offsets, vertex[order], part_count)
    colour_parts = np.argsort(colour, kind="stable").astype(np.int64)
    colour_offsets = np.zeros(int(colour.max(initial=-1)) + 2, dtype=np.int64)
    np.cumsum(np.bincount(colour), out=colour_offsets[1:])
    return colour_offsets, colour_parts


def vertex_owners(block_tets, tet_count, node_count, part_offsets, colour_parts):
    """``(owned_offsets, owned)``: each vertex goes to the first part, in colour order
    (``colour_parts``), whose tets use it; a vertex no tet uses to the first part.  Part p owns
    ``owned[owned_offsets[p]:owned_offsets[p + 1]]``, in increasing order.

    The step moves a part's vertices just before it computes the part's forces of the next step
    (``integrators.symplectic_euler.advance``): by then every force on them has been added, and no
    part of an earlier colour, nor another part of the same colour, reads them in that step.
    """
    block_count = block_tets.shape[0]
    part_count = part_offsets.shape[0] - 1
    order = np.empty(part_count, dtype=np.int64)
    order[colour_parts] = np.arange(part_count)          # position of each part in colour order
    lanes = np.arange(block_count * BLOCK).reshape(block_count, 1, BLOCK)
    real = np.broadcast_to(lanes < tet_count, block_tets.shape)
    block_part = np.repeat(np.arange(part_count), np.diff(part_offsets))
    rank = np.broadcast_to(order[block_part][:, None, None], block_tets.shape)[real]
    first = np.full(node_count, part_count, dtype=np.int64)
    np.minimum.at(first, block_tets[real].astype(np.int64), rank)
    first[first == part_count] = 0                       # used by no tet: the first part in colour order
    owner = colour_parts[first] if part_count else first
    owned = np.argsort(owner, kind="stable").astype(np.int64)
    owned_offsets = np.zeros(part_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=part_count), out=owned_offsets[1:])
    return owned_offsets, owned


def owned_vertex_runs(owned_offsets, owned):
    """``(run_offsets, owned_runs)`` (``BlockLayout``): each part's vertices ``owned[owned_offsets[p]:
    owned_offsets[p + 1]]`` (increasing, ``vertex_owners``) cut into runs of consecutive indices.

    The step moves a part's vertices run by run, in a loop over an unsigned range: Numba then
    indexes without its check for negative indices, and the vertex rows are read in order (vertex
    update alone, 100k-tet beam, one thread: 0.75 ns/tet in runs, 1.1 over signed ranges, 1.4
    through the list ``owned``).  In ``mesh.reorder``'s numbering a part's vertices are nearly
    consecutive: 124 runs in 8 parts of 22k vertices on the beam, 596 of 32k on a gmsh box.
    """
    part_count = owned_offsets.shape[0] - 1
    part = np.repeat(np.arange(part_count), np.diff(owned_offsets))
    starts = np.ones(owned.shape[0], dtype=bool)
    starts[1:] = (np.diff(owned) != 1) | (np.diff(part) != 0)
    first = np.flatnonzero(starts)
    stop = np.append(first[1:], owned.shape[0])[:first.size]
    owned_runs = np.stack([owned[first], owned[stop - 1] + 1], axis=1).astype(np.uint64)
    run_offsets = np.zeros(part_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(part[first], minlength=part_count), out=run_offsets[1:])
    return run_offsets, owned_runs


def faces_by_part(faces, face_tets, part_offsets):
    """``(part_face_offsets, part_faces)``: boundary ``faces`` (b, 3) grouped by the part of their
    tet (``face_tets`` (b,)), part p's ``part_faces[part_face_offsets[p]:part_face_offsets[p + 1]]``.
    A part uses every vertex of its faces, so it may read and add to them during its colour."""
    part_count = part_offsets.shape[0] - 1
    part = np.searchsorted(part_offsets, np.asarray(face_tets) // BLOCK, side="right") - 1
    order = np.argsort(part, kind="stable")
    offsets = np.zeros(part_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(part, minlength=part_count), out=offsets[1:])
    return offsets, np.ascontiguousarray(faces[order])


@njit
def _greedy_colours(v_offsets, v_units, u_offsets, u_vertices, unit_count):
    """Smallest colour per unit not used by an earlier unit sharing a vertex with it."""
    colour = np.full(unit_count, -1, dtype=np.int64)
    taken = np.full(unit_count + 1, -1, dtype=np.int64)      # taken[c] == b: colour c used next to b
    for b in range(unit_count):
        for k in range(u_offsets[b], u_offsets[b + 1]):
            i = u_vertices[k]
            for s in range(v_offsets[i], v_offsets[i + 1]):
                c = colour[v_units[s]]
                if c >= 0:
                    taken[c] = b
        c = 0
        while taken[c] == b:
            c += 1
        colour[b] = c
    return colour


# The material laws of ``materials.models``, always inlined into the lane loops (``jit.njit_inline``):
# as ordinary calls LLVM finds them too large to inline, and a loop with a call does not vectorise.
# Each takes a weight, ``-V0``, folded into its scalars: the lane loops scale neither the stress nor
# the rest matrix by it.
_stvk_weighted_first_piola = njit_inline(stvk_weighted_first_piola.py_func)
_neohookean_weighted_first_piola = njit_inline(neohookean_weighted_first_piola.py_func)
_linear_weighted_first_piola = njit_inline(linear_weighted_first_piola.py_func)
_corotated_weighted_stress = njit_inline(corotated_weighted_stress.py_func)
_linear_weighted_first_piola_displacement = njit_inline(linear_weighted_first_piola_displacement.py_func)
_stvk_weighted_first_piola_displacement = njit_inline(stvk_weighted_first_piola_displacement.py_func)
_neohookean_weighted_first_piola_displacement = njit_inline(neohookean_weighted_first_piola_displacement.py_func)


# ---------------------------------------------------------------------------------------------
# one block: gather, forces, scatter


@njit
def gather_corners(x, block_tets, b, buf, whole_rows=False, first_row=ROW_X):
    """Gather block ``b``'s corner positions (or displacements) ``x`` (n, 3) into rows ``first_row``
    to ``first_row + 11`` of the scratch ``buf`` (``simd.gather_corner_rows``: a vector store per
    row of lanes, not a scalar store per value); the rest positions go to rows ``ROW_F..``
    (``rest_from_corners_block``).

    whole_rows: True only if the block does not use x's last row (``BlockLayout.whole_rows``):
    each row is then loaded as four values with a plain load, where the last row's fourth would
    lie past ``x``; else with the fourth masked off.  Beam, 2 threads, one process, against masked
    loads everywhere: float64 1.03x at 10k tets, 1.02x at 100k, 1.05x at 1M, 1.01x at 2M;
    float32 1.05x at 100k.  (Finding the block's largest index in the step instead, a scalar
    pass over its 256 indices, made the step 0.78-0.91x as fast.)
    """
    if x.shape[1] != 3:
        raise ValueError("gather_corners: x must have 3 columns")
    if whole_rows:
        for c in range(4):
            gather_corner_rows(x, block_tets, (b * 4 + c) * BLOCK, buf, (first_row + 3 * c) * BLOCK, BLOCK, True)
    else:
        for c in range(4):
            gather_corner_rows(x, block_tets, (b * 4 + c) * BLOCK, buf, (first_row + 3 * c) * BLOCK, BLOCK, False)


@njit_inline
def group_rows(rest, g, upcoming):
    """Group ``g``'s rest rows (10 or 7, ``group_lanes(rest)``) of a block's ``rest``; with ``upcoming`` (a later
    block's rest, or None), first fetches group ``g`` of that block into L2.  Where ``upcoming``
    is None, Numba prunes the prefetch after inlining."""
    if upcoming is not None:
        prefetch_rows(upcoming[g])
    return rest[g]


@njit_inline
def block_ahead(b, prefetch, block_count):
    """The block whose data the step fetches while it computes block ``b``: ``prefetch`` blocks on,
    the last block at most (both prefetches, ``block_forces`` and ``prefetch_vertex_rows``)."""
    return min(b + prefetch, block_count - 1)


@njit
def prefetch_vertex_rows(x, vertex_forces, first_offsets, first_vertices, b, prefetch, rest_points=None):
    """Fetch the rows of ``x`` (n, 3), of ``vertex_forces`` (n, ``FORCE_COLUMNS``, or empty: not
    those) and of ``rest_points`` (n, 3, or None: not those) of the vertices that block
    ``b + prefetch`` (the last block at most) uses first in its part (``first_uses``) into L2;
    nothing where ``prefetch`` is None (pruned by Numba)."""
    if prefetch is None:
        return
    ahead = block_ahead(b, prefetch, first_offsets.shape[0] - 1)
    for q in range(first_offsets[ahead], first_offsets[ahead + 1]):
        i = np.int64(first_vertices[q])
        prefetch_line(x, i * 3)
        if vertex_forces.shape[0] > 0:
            prefetch_line(vertex_forces, i * FORCE_COLUMNS)
        if rest_points is not None:
            prefetch_line(rest_points, i * 3)


@njit_inline
def prefetch_rows(rows):
    """Fetch every cache line of ``rows`` (a C-contiguous view: a group's rest rows) into L2
    (``simd.prefetch_line``), ahead of the lane loop that will read them."""
    line = CACHE_LINE_BYTES // rows.itemsize
    for e in range(0, rows.size, line):
        prefetch_line(rows, e)


@njit_inline
def lane_edges(buf, j, first_row):
    """The edge matrix of lane ``j`` (9-tuple, row-major), columns ``x_c - x_0`` (c = 1, 2, 3) of the
    corner rows ``first_row..first_row + 11`` of ``buf`` (``gather_corners``)."""
    return (buf[(first_row + 3) * BLOCK + j] - buf[first_row * BLOCK + j],
            buf[(first_row + 6) * BLOCK + j] - buf[first_row * BLOCK + j],
            buf[(first_row + 9) * BLOCK + j] - buf[first_row * BLOCK + j],
            buf[(first_row + 4) * BLOCK + j] - buf[(first_row + 1) * BLOCK + j],
            buf[(first_row + 7) * BLOCK + j] - buf[(first_row + 1) * BLOCK + j],
            buf[(first_row + 10) * BLOCK + j] - buf[(first_row + 1) * BLOCK + j],
            buf[(first_row + 5) * BLOCK + j] - buf[(first_row + 2) * BLOCK + j],
            buf[(first_row + 8) * BLOCK + j] - buf[(first_row + 2) * BLOCK + j],
            buf[(first_row + 11) * BLOCK + j] - buf[(first_row + 2) * BLOCK + j])


@njit_inline
def lane_deformation_gradient(rest, l, buf, j):
    """``F = Ds Dm^-1`` of lane ``j`` (9-tuple), ``Ds`` the edges ``x_c - x_0`` as columns; when the
    corner rows hold displacements, the same product is ``H = Du Dm^-1 = F - I``.  rest: the rest
    rows of the lane's group (10, lanes), ``l``: the lane in it."""
    return mat3_mul_inline(lane_edges(buf, j, ROW_X), lane_rest_matrix(rest, l))


@njit_inline
def lane_rest_matrix(rest, l):
    """``Dm^-1`` of lane ``l`` of a group's rest rows (9-tuple, row-major) [1/m]."""
    return (rest[0, l], rest[1, l], rest[2, l], rest[3, l], rest[4, l], rest[5, l], rest[6, l], rest[7, l], rest[8, l])


@njit_inline
def lane_weight(rest, l):
    """``-V0`` [m^3] of lane ``l`` of a group's rest rows in the full form: the weight that the
    laws fold into their scalars (``lane_store_forces``)."""
    return -rest[ROW_VOLUME, l]


@njit_inline
def lane_store_forces(rest, l, buf, j, Q):
    """Corner forces of lane ``j`` (lane ``l`` of its group's rest rows) from its weighted stress
    ``Q = -V0 P`` (a law given ``lane_weight``): ``H = Q Dm^-T``, corner c (1..3) gets column c - 1
    of H, ``f0 = -(f1 + f2 + f3)``."""
    H = mat3_mul_transpose_b_inline(Q, lane_rest_matrix(rest, l))
    lane_store_component(buf, j, 0, H[0], H[1], H[2])
    lane_store_component(buf, j, 1, H[3], H[4], H[5])
    lane_store_component(buf, j, 2, H[6], H[7], H[8])


@njit_inline
def lane_store_component(buf, j, k, h1, h2, h3):
    """Component ``k`` of the corner forces of lane ``j``: corners 1..3 get ``h1..h3``, corner 0
    ``-(h1 + h2 + h3)`` [N]."""
    buf[(ROW_F + 3 + k) * BLOCK + j] = h1
    buf[(ROW_F + 6 + k) * BLOCK + j] = h2
    buf[(ROW_F + 9 + k) * BLOCK + j] = h3
    buf[(ROW_F + k) * BLOCK + j] = -(h1 + h2 + h3)


@njit_inline
def lane_rotated_deformation_gradient(rest, l, buf, j):
    """``F_r = Ds R^-1`` of lane ``j`` (9-tuple, row-major): ``F`` in the rest frame turned by ``Q``
    (``rotated_rest``), with the same ``det`` and stretches.  rest: the triangular rest rows of the
    lane's group (7, lanes), ``l``: the lane in it."""
    D = lane_edges(buf, j, ROW_X)
    a00, a01, a02 = rest[0, l], rest[1, l], rest[2, l]
    a11, a12, a22 = rest[3, l], rest[4, l], rest[5, l]
    return (D[0] * a00, D[0] * a01 + D[1] * a11, D[0] * a02 + D[1] * a12 + D[2] * a22,
            D[3] * a00, D[3] * a01 + D[4] * a11, D[3] * a02 + D[4] * a12 + D[5] * a22,
            D[6] * a00, D[6] * a01 + D[7] * a11, D[6] * a02 + D[7] * a12 + D[8] * a22)


@njit_inline
def lane_rotated_weight(rest, l):
    """``-V0`` [m^3] of lane ``l`` of a group's triangular rest rows (``lane_weight``)."""
    return -rest[ROW_TRIANGULAR_VOLUME, l]


@njit_inline
def lane_store_rotated_forces(rest, l, buf, j, Q):
    """Corner forces of lane ``j`` from the weighted stress ``Q = -V0 P(F_r)`` (a law given
    ``lane_rotated_weight``, ``F_r`` from ``lane_rotated_deformation_gradient``): ``H = Q R^-T``,
    stored as ``lane_store_forces`` does.  Folding ``-V0`` into a law's scalars costs two or three
    multiplies instead of the six that scaled ``R^-1`` (or the nine that scaled ``P``)."""
    lane_store_times_triangular(buf, j, Q, rest[0, l], rest[1, l], rest[2, l], rest[3, l], rest[4, l], rest[5, l])


@njit_inline
def lane_store_times_triangular(buf, j, Q, a00, a01, a02, a11, a12, a22):
    """The corner forces of lane ``j``, ``H = Q A^T`` with ``A`` upper triangular (``a00..a22``)."""
    lane_store_component(buf, j, 0, Q[0] * a00 + Q[1] * a01 + Q[2] * a02, Q[1] * a11 + Q[2] * a12, Q[2] * a22)
    lane_store_component(buf, j, 1, Q[3] * a00 + Q[4] * a01 + Q[5] * a02, Q[4] * a11 + Q[5] * a12, Q[5] * a22)
    lane_store_component(buf, j, 2, Q[6] * a00 + Q[7] * a01 + Q[8] * a02, Q[7] * a11 + Q[8] * a12, Q[8] * a22)


@njit
def stvk_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            F = lane_rotated_deformation_gradient(group, l, buf, j)
            lane_store_rotated_forces(group, l, buf, j,
                                      _stvk_weighted_first_piola(F, lane_rotated_weight(group, l), lam, mu))


@njit
def neohookean_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            F = lane_rotated_deformation_gradient(group, l, buf, j)
            lane_store_rotated_forces(group, l, buf, j,
                                      _neohookean_weighted_first_piola(F, lane_rotated_weight(group, l), lam, mu))


@njit_inline
def lane_store_corotated_forces(rest, l, buf, j, F, Z, inv, lam, mu):
    """``lane_store_rotated_forces`` of the corotated stress with ``R = inv Z`` (Newton's scaled
    iterate, ``polar3.newton_polar_start``; or a rotation and ``inv = 1``): ``-V0`` is folded into
    the law's scalars (``materials.models.corotated_weighted_stress``)."""
    lane_store_rotated_forces(rest, l, buf, j, _corotated_weighted_stress(F, Z, inv, lane_rotated_weight(rest, l), lam, mu))


@njit_inline
def lane_store_newton(buf, j, Z, inv, det):
    """Keep lane ``j``'s ``X_k = inv Z`` of the first stage (as Z and inv) and det F in rows
    ``ROW_NEWTON..`` for the second stage."""
    for k in range(9):
        buf[(ROW_NEWTON + k) * BLOCK + j] = Z[k]
    buf[(ROW_NEWTON + 9) * BLOCK + j] = inv
    buf[(ROW_NEWTON + 10) * BLOCK + j] = det


@njit_inline
def lane_load_newton(buf, j):
    """Lane ``j``'s ``X_k`` of the first stage from rows ``ROW_NEWTON..`` (9-tuple)."""
    return mat3_scale_inline(
        (buf[ROW_NEWTON * BLOCK + j], buf[(ROW_NEWTON + 1) * BLOCK + j], buf[(ROW_NEWTON + 2) * BLOCK + j],
         buf[(ROW_NEWTON + 3) * BLOCK + j], buf[(ROW_NEWTON + 4) * BLOCK + j], buf[(ROW_NEWTON + 5) * BLOCK + j],
         buf[(ROW_NEWTON + 6) * BLOCK + j], buf[(ROW_NEWTON + 7) * BLOCK + j], buf[(ROW_NEWTON + 8) * BLOCK + j]),
        buf[(ROW_NEWTON + 9) * BLOCK + j])


@njit_inline
def lane_finish_newton(rest, l, buf, j, lam, mu):
    """Newton's last two steps for lane ``j`` (lane ``l`` of ``rest``): its forces where they
    converge (``STAGE_DONE``), else ``STAGE_JACOBI``."""
    F = lane_rotated_deformation_gradient(rest, l, buf, j)
    Z, inv, converged = newton_polar_finish(lane_load_newton(buf, j), buf[(ROW_NEWTON + 10) * BLOCK + j])
    lane_store_corotated_forces(rest, l, buf, j, F, Z, inv, lam, mu)
    buf[ROW_STAGE * BLOCK + j] = STAGE_DONE if converged else STAGE_JACOBI


@njit
def list_lanes(buf, stage):
    """List the lanes at ``stage`` (row ``ROW_STAGE``) in row ``ROW_LIST`` (as floats); return their count."""
    k = 0
    for j in range(BLOCK):
        if buf[ROW_STAGE * BLOCK + j] == stage:
            buf[ROW_LIST * BLOCK + k] = j
            k += 1
    return k


@njit
def corotated_block(rest, buf, lam, mu, upcoming, first_steps=NEWTON_FIRST_STEPS):
    """The rotation of each lane by Newton's polar iteration in two stages, as
    ``polar3.newton_polar_rotation`` takes them: ``first_steps`` steps (4, 3 or 2) for every lane
    (packed), two more for the lanes these did not settle (not for inverted ones: Newton cannot
    accept them); the lanes where it did not converge (inverted, nearly flat or strongly stretched
    tets) are redone with the Jacobi SVD, as ``polar3.polar_rotation`` does per tet.  Every lane
    gets the per-tet law's forces to round-off.  rest: a block's rest rows in the triangular form
    (``F_r``, ``lane_rotated_deformation_gradient``).

    The first stage keeps each lane's iterate for the second, except with two steps: there the lanes
    sent on redo their first steps.

    Returns the first steps for the block's next step (``next_first_steps``): one more (4 at most)
    where a lane that is not inverted needed the second stage, one fewer (2 at least) where every
    such lane would have settled with one step fewer (``overdone``: ``polar3.newton_polar_certifies``
    passes on the iterate two before the last).  A step changes the strains little, so a block of
    small strains soon takes two or three steps instead of four; a wrong guess costs only the
    second stage, or the Jacobi SVD, for its lanes, once."""
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    pending = 0
    unsettled = 0
    # Three copies of the first stage's loop, one per step count.  One loop taking the count as a
    # variable (``if steps >= 3: Z, c = newton_polar_step(Z, c)``) still vectorised, but if-converted:
    # every count cost four steps (about 21 ns a tet at 2, 3 and 4 against 15-19 / 17 / 19-21 ns here,
    # one block in cache, one thread, Zen 4; an inner loop over the steps would keep the loop scalar).
    if first_steps == 2:
        for g in range(BLOCK // lanes):
            group = group_rows(rest, g, upcoming)
            for l in range(lanes):
                j = g * lanes + l
                F = lane_rotated_deformation_gradient(group, l, buf, j)
                Z, inv, det, converged, overdone = newton_polar_start_two(F)
                lane_store_corotated_forces(group, l, buf, j, F, Z, inv, lam, mu)
                stage = STAGE_DONE if converged else (STAGE_NEWTON if det > 0.0 else STAGE_JACOBI)
                buf[ROW_STAGE * BLOCK + j] = stage
                pending += 1 if stage != STAGE_DONE else 0
                unsettled += 1 if det > 0.0 and not overdone else 0
    elif first_steps == 3:
        for g in range(BLOCK // lanes):
            group = group_rows(rest, g, upcoming)
            for l in range(lanes):
                j = g * lanes + l
                F = lane_rotated_deformation_gradient(group, l, buf, j)
                Z, inv, det, converged, overdone = newton_polar_start_three(F)
                lane_store_corotated_forces(group, l, buf, j, F, Z, inv, lam, mu)
                lane_store_newton(buf, j, Z, inv, det)
                stage = STAGE_DONE if converged else (STAGE_NEWTON if det > 0.0 else STAGE_JACOBI)
                buf[ROW_STAGE * BLOCK + j] = stage
                pending += 1 if stage != STAGE_DONE else 0
                unsettled += 1 if det > 0.0 and not overdone else 0
    else:
        for g in range(BLOCK // lanes):
            group = group_rows(rest, g, upcoming)
            for l in range(lanes):
                j = g * lanes + l
                F = lane_rotated_deformation_gradient(group, l, buf, j)
                Z, inv, det, converged, overdone = newton_polar_start(F)
                lane_store_corotated_forces(group, l, buf, j, F, Z, inv, lam, mu)
                lane_store_newton(buf, j, Z, inv, det)
                stage = STAGE_DONE if converged else (STAGE_NEWTON if det > 0.0 else STAGE_JACOBI)
                buf[ROW_STAGE * BLOCK + j] = stage
                pending += 1 if stage != STAGE_DONE else 0
                unsettled += 1 if det > 0.0 and not overdone else 0
    if pending == 0:
        return next_first_steps(first_steps, 0, unsettled)
    newton = 0
    for j in range(BLOCK):
        newton += 1 if buf[ROW_STAGE * BLOCK + j] == STAGE_NEWTON else 0
    if first_steps == 2 and newton > 0:
        # The two-step loop keeps no iterate: a block takes two steps only after a step that sent
        # no lane to the second stage, so its lanes rarely need one, and the 11 stores a lane took
        # a tenth of its time (benchmarks/NOTES.md).  The few lanes that do need it redo their
        # first steps, to the same bits.  A loop of its own: folded into the second stage's loops
        # (``if first_steps == 2`` there, the iterate loaded otherwise) the second stage of four-step
        # blocks ran 1.05-1.08x as long, the two-step blocks no faster (one process, one thread).
        for g in range(BLOCK // lanes):
            group = rest[g]
            for l in range(lanes):                # packed SIMD over all lanes, stores masked
                j = g * lanes + l
                if buf[ROW_STAGE * BLOCK + j] == STAGE_NEWTON:
                    F = lane_rotated_deformation_gradient(group, l, buf, j)
                    Z, inv, det, _, _ = newton_polar_start_two(F)
                    lane_store_newton(buf, j, Z, inv, det)
    if newton > NEWTON_VECTOR_MIN_LANES:
        # Written out, not a call of lane_finish_newton: through that njit_inline helper this loop
        # compiled to scalar code (50 ns a lane of the block against 60 ns a listed scalar lane).
        for g in range(BLOCK // lanes):
            group = rest[g]
            for l in range(lanes):                # packed SIMD over all lanes, stores masked
                j = g * lanes + l
                if buf[ROW_STAGE * BLOCK + j] == STAGE_NEWTON:
                    F = lane_rotated_deformation_gradient(group, l, buf, j)
                    Z, inv, converged = newton_polar_finish(lane_load_newton(buf, j),
                                                            buf[(ROW_NEWTON + 10) * BLOCK + j])
                    lane_store_corotated_forces(group, l, buf, j, F, Z, inv, lam, mu)
                    buf[ROW_STAGE * BLOCK + j] = STAGE_DONE if converged else STAGE_JACOBI
    elif newton > 0:
        for k in range(list_lanes(buf, STAGE_NEWTON)):   # scalar, one listed lane at a time
            j = int(buf[ROW_LIST * BLOCK + k])
            lane_finish_newton(rest[j // lanes], j % lanes, buf, j, lam, mu)
    fallbacks = 0
    for j in range(BLOCK):
        fallbacks += 1 if buf[ROW_STAGE * BLOCK + j] == STAGE_JACOBI else 0
    if fallbacks > FALLBACK_VECTOR_MIN_LANES:
        # The two fallback loops repeat their three-line body: moved into an njit_inline helper,
        # this loop compiled to scalar code (903 -> 1805 scalar instructions, inspect_asm).
        for g in range(BLOCK // lanes):
            group = rest[g]
            for l in range(lanes):                # packed SIMD over all lanes, stores masked
                j = g * lanes + l
                if buf[ROW_STAGE * BLOCK + j] == STAGE_JACOBI:
                    F = lane_rotated_deformation_gradient(group, l, buf, j)
                    R, _, _, _ = jacobi_rotation_and_stretch(F)
                    lane_store_corotated_forces(group, l, buf, j, F, R, 1.0, lam, mu)
    elif fallbacks > 0:
        for k in range(list_lanes(buf, STAGE_JACOBI)):   # scalar, one listed lane at a time
            j = int(buf[ROW_LIST * BLOCK + k])
            group = rest[j // lanes]
            F = lane_rotated_deformation_gradient(group, j % lanes, buf, j)
            R, _, _, _ = jacobi_rotation_and_stretch(F)
            lane_store_corotated_forces(group, j % lanes, buf, j, F, R, 1.0, lam, mu)
    return next_first_steps(first_steps, newton, unsettled)


@njit_inline
def next_first_steps(first_steps, newton, unsettled):
    """The first steps of Newton's iteration for a block's next step (``corotated_block``), from this
    step's ``first_steps``, its lanes sent to the second stage (``newton``, inverted ones not
    counted) and its lanes not ``overdone`` (``unsettled``, inverted ones not counted): between
    ``polar3.NEWTON_MIN_FIRST_STEPS`` and ``polar3.NEWTON_FIRST_STEPS``."""
    if newton > 0:
        return min(first_steps + 1, NEWTON_FIRST_STEPS)
    if unsettled == 0:
        return max(first_steps - 1, NEWTON_MIN_FIRST_STEPS)
    return first_steps


@njit
def linear_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            F = lane_deformation_gradient(group, l, buf, j)
            lane_store_forces(group, l, buf, j, _linear_weighted_first_piola(F, lane_weight(group, l), lam, mu))


@njit
def stvk_displacement_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            H = lane_deformation_gradient(group, l, buf, j)
            lane_store_forces(group, l, buf, j, _stvk_weighted_first_piola_displacement(H, lane_weight(group, l), lam, mu))


@njit
def neohookean_displacement_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            H = lane_deformation_gradient(group, l, buf, j)
            lane_store_forces(group, l, buf, j,
                              _neohookean_weighted_first_piola_displacement(H, lane_weight(group, l), lam, mu))


@njit
def linear_displacement_block(rest, buf, lam, mu, upcoming):
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = group_rows(rest, g, upcoming)
        for l in range(lanes):
            j = g * lanes + l
            H = lane_deformation_gradient(group, l, buf, j)
            lane_store_forces(group, l, buf, j, _linear_weighted_first_piola_displacement(H, lane_weight(group, l), lam, mu))


@njit
def rest_from_corners_block(buf):
    """Each lane's rest data from the rest positions of its corners in rows ``ROW_F..ROW_F + 11`` of
    ``buf`` (``gather_corners(..., first_row=ROW_F)``) into rows ``ROW_REST..`` of ``buf``
    (``computed_rest``): ``Dm^-1 = cof(Dm)^T / det Dm`` [1/m] and ``V0 = det Dm / 6`` [m^3]
    (``kernels.rest_state`` computes them by LU: the two agree to round-off).  A padding lane gets
    its tet's volume, not zero: the scatter leaves padding lanes out anyway.

    The stores go to ``buf`` at compile-time-constant offsets, as a block of ``BlockLayout.rest``
    (groups of ``lanes``, each group's ten rows in turn).  Stored through a view of those rows
    (``rest[g][row, l]``, its row stride known only at run time) the loop needed more run-time
    alias checks than LLVM makes, and compiled to scalar code: 6 ns a tet, one thread."""
    prefer_wide_vectors()
    lanes = group_lanes(buf)
    for g in range(BLOCK // lanes):
        for l in range(lanes):
            j = g * lanes + l
            Dm = lane_edges(buf, j, ROW_F)
            cof = mat3_cofactor_inline(Dm)
            det = Dm[0] * cof[0] + Dm[1] * cof[1] + Dm[2] * cof[2]
            inv_det = 1.0 / det
            row = ROW_REST * BLOCK + g * REST_ROWS * lanes + l      # row 0 of lane l of group g
            buf[row + ROW_DM_INV * lanes] = cof[0] * inv_det           # Dm^-1 = cof^T / det, row-major
            buf[row + (ROW_DM_INV + 1) * lanes] = cof[3] * inv_det
            buf[row + (ROW_DM_INV + 2) * lanes] = cof[6] * inv_det
            buf[row + (ROW_DM_INV + 3) * lanes] = cof[1] * inv_det
            buf[row + (ROW_DM_INV + 4) * lanes] = cof[4] * inv_det
            buf[row + (ROW_DM_INV + 5) * lanes] = cof[7] * inv_det
            buf[row + (ROW_DM_INV + 6) * lanes] = cof[2] * inv_det
            buf[row + (ROW_DM_INV + 7) * lanes] = cof[5] * inv_det
            buf[row + (ROW_DM_INV + 8) * lanes] = cof[8] * inv_det
            buf[row + ROW_VOLUME * lanes] = det / 6.0


@njit
def triangular_rest_from_corners_block(buf):
    """``rest_from_corners_block`` in the triangular form (``rotated_rest.triangular_rest_inverse``):
    each group's rows ``R^-1`` (6) and ``V0 = det Dm / 6``."""
    prefer_wide_vectors()
    lanes = group_lanes(buf)
    for g in range(BLOCK // lanes):
        for l in range(lanes):
            j = g * lanes + l
            a00, a01, a02, a11, a12, a22, det = triangular_rest_inverse(lane_edges(buf, j, ROW_F))
            row = ROW_REST * BLOCK + g * TRIANGULAR_REST_ROWS * lanes + l      # row 0 of lane l of group g
            buf[row] = a00
            buf[row + lanes] = a01
            buf[row + 2 * lanes] = a02
            buf[row + 3 * lanes] = a11
            buf[row + 4 * lanes] = a12
            buf[row + 5 * lanes] = a22
            buf[row + ROW_TRIANGULAR_VOLUME * lanes] = det / 6.0


@njit_inline
def computed_rest(buf, rows):
    """Rows ``ROW_REST..`` of ``buf`` as a block of rest data (groups, ``rows``, lanes), the shape of
    ``block_rest[b]`` (``rest_from_corners_block``, ``triangular_rest_from_corners_block``)."""
    lanes = group_lanes(buf)
    return buf[ROW_REST * BLOCK:(ROW_REST + rows) * BLOCK].reshape((BLOCK // lanes, rows, lanes))


@njit
def volume_ratio_and_stretch_block(triangular, rest, buf):
    """``J = det F`` and the RMS stretch ``|F| / sqrt(3)`` of each lane, from the corner positions
    in ``buf``, into rows ``ROW_J`` and ``ROW_STRETCH`` of ``buf`` (the guard's element checks).
    rest: a block's rest rows, in the triangular form where ``triangular`` (a compile-time constant,
    ``kernels.jit.CompileTimeConstant``: 1 or 0) says so, else in the full form (``F_r`` has F's
    det and norm, ``rotated_rest``)."""
    prefer_wide_vectors()
    lanes = group_lanes(rest)
    for g in range(BLOCK // lanes):
        group = rest[g]
        for l in range(lanes):
            j = g * lanes + l
            lane_store_volume_ratio_and_stretch(buf, j, lane_rest_deformation_gradient(triangular, group, l, buf, j))


def lane_rest_deformation_gradient(triangular, group, l, buf, j):
    """Lane ``l``'s deformation gradient from its corners in ``buf`` (lane ``j``) and its rest rows
    ``group``, in the form ``triangular`` names; compiled code only (``_lane_rest_deformation_gradient``)."""
    raise NotImplementedError("lane_rest_deformation_gradient runs in compiled code only")


@overload(lane_rest_deformation_gradient, prefer_literal=True, inline="always")
def _lane_rest_deformation_gradient(triangular, group, l, buf, j):
    """Only the form's own gradient, ``triangular`` a constant: the guard's measure then compiles
    one form, not both (about 0.5 s less compiling in a first run).  An overload, as Numba does not
    prune a branch on an ``IntegerLiteral`` argument (it does on ``None``)."""
    if not isinstance(triangular, types.IntegerLiteral):
        raise TypingError(f"the rest data's form must be a compile-time constant (kernels.jit.CompileTimeConstant), "
                          f"not {triangular}")
    gradient = lane_rotated_deformation_gradient if triangular.literal_value else lane_deformation_gradient

    def one_form(triangular, group, l, buf, j):
        return gradient(group, l, buf, j)
    return one_form


@njit_inline
def lane_store_volume_ratio_and_stretch(buf, j, F):
    """Lane ``j``'s ``J = det F`` and RMS stretch ``|F| / sqrt(3)`` into rows ``ROW_J`` and ``ROW_STRETCH``."""
    buf[ROW_J * BLOCK + j] = mat3_det_inline(F)
    buf[ROW_STRETCH * BLOCK + j] = math.sqrt(mat3_ddot_inline(F, F) / 3.0)


@njit
def block_forces(x, block_tets, block_rest, b, model, lam, mu, buf, rest, prefetch, whole_rows, first_steps,
                 rest_points=None):
    """Corner forces [N] of block ``b`` into rows ``ROW_F..`` of ``buf`` (``ROWS * BLOCK`` values;
    ``SCRATCH_ROWS * BLOCK`` with ``rest_points``).

    rest: None when ``x`` holds positions; the rest positions when ``x`` holds displacements from
    them (the laws then take ``H = F - I``; ``materials.models.DISPLACEMENT_FORM_MODELS`` only).
    prefetch: None, or how many blocks ahead to fetch rest data into L2 (``BlockLayout.prefetch``).
    whole_rows: whether the block's corners leave out x's last row (``gather_corners``).
    first_steps: (block_count,) uint8, each block's first steps of Newton's iteration (corotated,
    ``corotated_block``): block ``b``'s is read and replaced by those for its next step; the other
    models leave it alone.
    rest_points: None, or (with ``x`` holding positions) the rest positions (n, 3) [m], from which
    the block's rest data are computed into ``buf`` (``rest_from_corners_block``) instead of read
    from ``block_rest`` (``BlockLayout.rest_from_points``).
    """
    block = gathered_block(x, block_tets, block_rest, b, buf, whole_rows, rest_points)
    if rest_points is not None or prefetch is None:
        first_steps[b] = model_forces(block, buf, model, lam, mu, rest, None, first_steps[b])
    else:
        first_steps[b] = model_forces(block, buf, model, lam, mu, rest,
                                      block_rest[block_ahead(b, prefetch, block_rest.shape[0])], first_steps[b])


@njit_inline
def gathered_block(x, block_tets, block_rest, b, buf, whole_rows, rest_points):
    """Gather block ``b``'s corners of ``x`` into ``buf`` (``gather_corners``) and return its rest
    rows: ``block_rest[b]``, or with ``rest_points`` (n, 3) [m] those computed from its corners'
    rest positions into ``buf``, in the form of ``block_rest`` (which then holds no blocks, only its
    form: ``rest_from_corners_block`` or ``triangular_rest_from_corners_block``, ``computed_rest``;
    ``buf`` then ``SCRATCH_ROWS * BLOCK`` values).  The step's forces and the guard's element
    checks both."""
    if rest_points is not None:
        gather_corners(rest_points, block_tets, b, buf, whole_rows, ROW_F)
        rows = block_rest.shape[2]
        if rows == TRIANGULAR_REST_ROWS:
            triangular_rest_from_corners_block(buf)
        else:
            rest_from_corners_block(buf)
        gather_corners(x, block_tets, b, buf, whole_rows)
        return computed_rest(buf, rows)
    gather_corners(x, block_tets, b, buf, whole_rows)
    return block_rest[b]


@njit
def model_forces(block, buf, model, lam, mu, rest, upcoming, first_steps=NEWTON_FIRST_STEPS):
    """The lane loop of ``model`` over one block's rest rows ``block`` (see ``block_forces``);
    upcoming: None, or a later block's rest rows, fetched into L2 meanwhile.  first_steps: the
    block's first steps of Newton's iteration (corotated, ``corotated_block``).  Returns those for
    the block's next step (``first_steps`` itself for the other models).  model: a model id that is
    a compile-time constant (``kernels.jit.CompileTimeConstant``): only its lane loop is compiled in."""
    return material_lane_loop(model, block, buf, lam, mu, rest, upcoming, first_steps)


def material_lane_loop(model, block, buf, lam, mu, rest, upcoming, first_steps):
    """``model_forces``'s choice of lane loop; compiled code only (``_material_lane_loop``)."""
    raise NotImplementedError("material_lane_loop runs in compiled code only")


def _lane_loop_of(model_id, displacements):
    """The jitted lane loop of model id ``model_id``, on positions or, with ``displacements``, on
    displacements from the rest positions."""
    if displacements:
        loops = {STVK: stvk_displacement_block, NEOHOOKEAN: neohookean_displacement_block,
                 LINEAR: linear_displacement_block}
    else:
        loops = {STVK: stvk_block, NEOHOOKEAN: neohookean_block, LINEAR: linear_block, COROTATED: corotated_block}
    if model_id not in loops:
        raise TypingError(f"material model {model_id} has no lane loop on "
                          f"{'displacements' if displacements else 'positions'}")
    return loops[model_id]


@overload(material_lane_loop, prefer_literal=True, inline="always")
def _material_lane_loop(model, block, buf, lam, mu, rest, upcoming, first_steps):
    """Only ``model``'s lane loop, ``model`` a constant: with every model's in one function, the
    step of a StVK scene took 122 s to compile instead of 17 (the beam, one core of a Zen 4).

    The lane loop is compiled here, before the implementation that calls it is typed: compiled
    while that is typed, corotated's took 1.5x as long (136 against 85-89 s, two processes side by
    side), the difference spent by Numba copying IR to inline."""
    if not isinstance(model, types.IntegerLiteral):
        raise TypingError(f"the model id must be a compile-time constant (kernels.jit.CompileTimeConstant), "
                          f"not {model}")
    law = _lane_loop_of(model.literal_value, not isinstance(rest, types.NoneType))
    if law is corotated_block:
        law.compile((block, buf, lam, mu, upcoming, first_steps))

        def corotated(model, block, buf, lam, mu, rest, upcoming, first_steps):
            return corotated_block(block, buf, lam, mu, upcoming, first_steps)
        return corotated

    law.compile((block, buf, lam, mu, upcoming))

    def one_model(model, block, buf, lam, mu, rest, upcoming, first_steps):
        law(block, buf, lam, mu, upcoming)
        return first_steps
    return one_model


@njit
def scatter_block(block_tets, b, lane_count, buf, vertex_forces):
    """Add the corner forces of the first ``lane_count`` lanes of ``buf`` to ``vertex_forces``
    (node_count, ``simd.FORCE_COLUMNS``): a vector read-modify-write per corner, the fourth column
    staying zero; ``simd.SCATTER_LANES`` lanes at a time (``simd.add_four_lanes_corner_forces``),
    the lanes past a multiple of them one by one (``simd.add_corner_force``)."""
    if vertex_forces.shape[1] != FORCE_COLUMNS:
        raise ValueError("scatter_block: the vertex forces must have FORCE_COLUMNS columns")
    whole = lane_count - lane_count % SCATTER_LANES
    for j in range(0, whole, SCATTER_LANES):
        add_four_lanes_corner_forces(vertex_forces, block_tets, b * 4 * BLOCK + j, buf, ROW_F * BLOCK + j, BLOCK)
    for j in range(whole, lane_count):
        for c in range(4):
            add_corner_force(vertex_forces, block_tets[b, c, j], buf, (ROW_F + 3 * c) * BLOCK + j, BLOCK)


@njit
def store_block_corners(b, lane_count, buf, corner_forces):
    """Write the corner forces of the first ``lane_count`` lanes into ``corner_forces`` (m, 4, 3)."""
    e0 = b * BLOCK
    for j in range(lane_count):
        for c in range(4):
            for k in range(3):
                corner_forces[e0 + j, c, k] = buf[(ROW_F + 3 * c + k) * BLOCK + j]


