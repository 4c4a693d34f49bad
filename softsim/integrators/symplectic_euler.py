"""Symplectic (semi-implicit) Euler, the whole step loop between two frames in compiled code.

One step, for every vertex ``i`` (Sifakis & Barbic 2012, section 6):

    v_i += dt * (f_i / m_i + a_ext_i)        elastic force, gravity and tractions
    ground contact (only with a ground): penalty pressure on the vertex's downward area, friction
    v_i *= damping_factor                    (only with damping)
    x_i += dt * v_i
    held components: v = prescribed velocity, x = start + velocity * t

Precision: in float64, ``x`` holds positions; in float32 it holds displacements ``u = x - X`` from
the rest positions ``rest`` (float32 keeps 7 digits: a steel step moves a vertex ~1e-8 m, below
float32's spacing at 1 m, and would be lost in ``x += dt v``, not in ``u += dt v``), and the
force kernel takes the laws in displacement form.  ``rest`` is None in float64.

Features a scene does not use cost nothing: ``ground`` and ``damping_factor`` are ``None`` then,
and Numba compiles (and caches) a separate specialisation of the step (``advance_colour``) in
which those branches are pruned away; the model id comes as a compile-time constant, so that the
step compiles the lane loop of the scene's material law alone.  Each step evaluates the corner
forces of blocks of tets in vectorised code (``kernels.blocked``), then sums them per vertex in a
fixed order (deterministic results): scattered one colour of slab-shaped parts at a time (or,
kept for comparison, stored per (tet, corner) and gathered per vertex: ``kernels.blocked``
``scatter='csr'``).
"""

import numpy as np
from numba import prange

from ..kernels.blocked import (BLOCK, SCRATCH_ROWS, block_forces, cache_aligned_empty, cache_aligned_scratch,
                               prefetch_vertex_rows, scatter_block, store_block_corners)
from ..kernels.forces import gather_vertex_force
from ..kernels.jit import njit, njit_inline, njit_parallel
from ..kernels.polar3 import NEWTON_FIRST_STEPS
from ..kernels.simd import CACHE_LINE_BYTES, FORCE_COLUMNS, flush_subnormals, restore_float_control
from ..kernels.sync import compare_exchange, fetch_add, load_acquire, spin_pause, yield_thread


# Tets per thread of the step: fewer threads for a smaller mesh, one below 2 x this.  Measured when
# each step passed two parallel regions (one per colour; now the parts of a call share one region
# unless another process takes a core, ``PartSchedule``), about 1 us each on TBB, tens of
# microseconds on a passive OpenMP (``kernels.jit``); on the beam, 1 / 2 threads (M tet-steps/s,
# medians of 5 timings, two alternating processes each): TBB 26 / 16 at 300 tets, 37 / 18-28 at 600, 46-49 / 29-55 at
# 1k, 56 / 64-80 at 2.5k, 58 / 90 at 5k, 60 / 86-108 at 10k; passive OpenMP 59.6 / 48.8 at 10k,
# 46.5 / 53.9 at 20k, 51.3 / 62.9 at 28k.  Remeasured with the parts of a call in one region (TBB,
# quiet host, 2 threads / 1, medians of 11 interleaved rounds, one process per list): 0.54-0.65 at
# 200-630 tets, 0.88-1.08 at 1.2k-1.36k, 1.13 at 1.4k, 1.18-1.24 at 2.4k-2.5k, 1.37 at 4.5k,
# 1.59 at 10k: two threads still pay from about 2k, so the threshold stays.
# Values of a block's scratch buffer (``kernels.blocked.SCRATCH_ROWS``: the rows of a block, then
# its rest data where the step computes them): a whole number of cache lines in either precision
# (47 * 64 values), so that consecutive buffers in one array each start at a line.
SCRATCH = SCRATCH_ROWS * BLOCK

TETS_PER_THREAD = 1_000              # on TBB
TETS_PER_THREAD_OTHER_LAYERS = 10_000


def step_threads(tet_count, available, layer="tbb"):
    """Threads the step of a mesh of ``tet_count`` tets runs on, of ``available``, on the Numba
    threading ``layer`` (``kernels.jit.threading_layer``)."""
    per_thread = TETS_PER_THREAD if layer == "tbb" else TETS_PER_THREAD_OTHER_LAYERS
    return max(1, min(available, tet_count // per_thread))


@njit_inline
def position(x, rest, i, k):
    """Component ``k`` of vertex ``i``'s position [m]: ``x[i, k]``, or ``rest[i, k] + x[i, k]`` when
    ``x`` holds displacements from ``rest``."""
    if rest is None:
        return x[i, k]
    return rest[i, k] + x[i, k]


@njit
def face_area_z(x, rest, faces, f):
    """A third of the z component [m^2] of boundary face ``f``'s current area vector
    ``1/2 (x1 - x0) x (x2 - x0)`` (outward): each corner's share."""
    a = faces[f, 0]
    b = faces[f, 1]
    c = faces[f, 2]
    ux = position(x, rest, b, 0) - position(x, rest, a, 0)
    uy = position(x, rest, b, 1) - position(x, rest, a, 1)
    wx = position(x, rest, c, 0) - position(x, rest, a, 0)
    wy = position(x, rest, c, 1) - position(x, rest, a, 1)
    return (ux * wy - uy * wx) / 6.0


@njit
def part_face_areas(x, rest, ground_faces, area_z, part):
    """Add the ``face_area_z`` of part ``part``'s boundary faces to their corners in ``area_z``.
    Summed over every face at a vertex, minus it (where positive) is the vertex's area facing the
    ground: side faces add nothing and a flat bottom face gives exactly its area."""
    part_face_offsets, part_faces = ground_faces
    for f in range(part_face_offsets[part], part_face_offsets[part + 1]):
        share = face_area_z(x, rest, part_faces, f)
        area_z[part_faces[f, 0]] += share
        area_z[part_faces[f, 1]] += share
        area_z[part_faces[f, 2]] += share


@njit_inline
def ground_velocity(vx, vy, vz, depth, area, dt, stiffness, friction, inv_mass):
    """The velocity (vx, vy, vz) [m/s] of a vertex ``depth`` [m] below the ground after a step of
    the ground's penalty pressure ``stiffness * depth`` [Pa] on its downward ``area`` [m^2] and of
    friction, which removes at most ``friction`` times the normal velocity change of tangential
    speed (it can stop a sliding vertex, never reverse it); inv_mass [1/kg], dt [s].

    Scalars in, scalars out: with arrays the vertex update would take and release references
    that Numba does not prune where it branches to the ground (``update_vertex``)."""
    dv_normal = dt * stiffness * depth * area * inv_mass
    vz += dv_normal
    if friction > 0.0:
        vt = (vx ** 2 + vy ** 2) ** 0.5
        dv_friction = friction * dv_normal
        if vt <= dv_friction:
            vx = 0.0
            vy = 0.0
        else:
            scale = 1.0 - dv_friction / vt
            vx *= scale
            vy *= scale
    return vx, vy, vz


@njit_inline
def vertex_accel(gravity, external_accel, i, k):
    """Component ``k`` of vertex ``i``'s external acceleration [m/s^2]: ``external_accel[i, k]``, or
    ``gravity[k]`` where ``external_accel`` is None (no tractions: every vertex has gravity alone,
    and the step reads no per-vertex array for it)."""
    if external_accel is None:
        return gravity[k]
    return external_accel[i, k]


@njit_inline
def move_vertex(x, v, i, dt, t_next, held, held_start, held_velocity):
    """``x[i] += dt v[i]``; held components follow ``start + velocity * t_next`` exactly."""
    for k in range(3):
        if held[i, k]:
            v[i, k] = held_velocity[i, k]
            x[i, k] = held_start[i, k] + held_velocity[i, k] * t_next
        else:
            x[i, k] += dt * v[i, k]


@njit_inline
def update_vertex(x, rest, v, i, fx, fy, fz, dt, t_next, inv_mass, gravity, external_accel, held, held_start,
                  held_velocity, ground, damping_factor):
    """One step of vertex ``i`` from its elastic force ``(fx, fy, fz)`` [N] (see the module docstring).

    ground: None, or ``(height [m], stiffness [Pa/m], friction, area_z (n,))``
    (``Model.ground_arguments``), ``area_z[i]`` being vertex i's ``part_face_areas`` at the
    positions the step's forces saw: a vertex below ``height`` gets ``ground_velocity``, and its
    ``area_z`` is zeroed for the next step.  The velocity is updated in scalars and stored once,
    the arrays touched only here: an array passed on to a helper that branches took and released
    a reference per array and vertex (atomic, not pruned by Numba), and the beam with a ground
    stepped at half the rate (``benchmarks/NOTES.md``)."""
    w = inv_mass[i]
    vx = v[i, 0] + dt * (fx * w + vertex_accel(gravity, external_accel, i, 0))
    vy = v[i, 1] + dt * (fy * w + vertex_accel(gravity, external_accel, i, 1))
    vz = v[i, 2] + dt * (fz * w + vertex_accel(gravity, external_accel, i, 2))
    if ground is not None:
        height, stiffness, friction, area_z = ground
        depth = height - position(x, rest, i, 2)
        if depth > 0.0:                        # below the ground
            gx, gy, gz = ground_velocity(vx, vy, vz, depth, max(0.0, -area_z[i]), dt, stiffness, friction, w)
            # rounded to v's precision, as if stored, before the damping (the ground is float64)
            vx, vy, vz = v.dtype.type(gx), v.dtype.type(gy), v.dtype.type(gz)
        area_z[i] = 0.0
    if damping_factor is not None:
        vx *= damping_factor
        vy *= damping_factor
        vz *= damping_factor
    v[i, 0] = vx
    v[i, 1] = vy
    v[i, 2] = vz
    move_vertex(x, v, i, dt, t_next, held, held_start, held_velocity)


@njit_inline
def update_from_forces(x, rest, v, vertex_forces, i, dt, t_next, inv_mass, gravity, external_accel, held,
                       held_start, held_velocity, ground, damping_factor):
    """``update_vertex`` with vertex ``i``'s summed force from ``vertex_forces``, which it zeroes."""
    fx = vertex_forces[i, 0]
    fy = vertex_forces[i, 1]
    fz = vertex_forces[i, 2]
    vertex_forces[i, 0] = 0.0
    vertex_forces[i, 1] = 0.0
    vertex_forces[i, 2] = 0.0
    update_vertex(x, rest, v, i, fx, fy, fz, dt, t_next, inv_mass, gravity, external_accel, held, held_start,
                  held_velocity, ground, damping_factor)


# ``advance``'s counters of the parts of a call run in one region (``one_region``), a cache line
# apart: parts done, waits that outlasted the spinning, then a claim per part (``claim``).
COUNTER_STRIDE = CACHE_LINE_BYTES // 8
DONE = 0
LONG_WAITS = COUNTER_STRIDE
CLAIMS = 2                 # the first claim's line
# Pauses (``kernels.sync.spin_pause``, 9.5 ns each on this host: 19 us in all) a thread spins while
# it waits for another's part, before it yields its core between further looks.  A wait that long
# means that the other thread lost its core (another process holds one).
SPINS_BEFORE_YIELD = 2_000


@njit_inline
def wait_until_done(counters, target):
    """Spin until ``counters[DONE]`` reaches ``target`` parts: ``spin_pause`` for
    ``SPINS_BEFORE_YIELD`` looks, then ``yield_thread`` between looks (counted in
    ``counters[LONG_WAITS]``)."""
    spins = 0
    while load_acquire(counters, DONE) < target:
        if spins < SPINS_BEFORE_YIELD:
            spin_pause()
            spins += 1
        else:
            if spins == SPINS_BEFORE_YIELD:
                fetch_add(counters, LONG_WAITS, 1)
                spins += 1
            yield_thread()


class PartSchedule:
    """Which way ``advance`` runs the parts of the colour scatter, call by call (``one_region``).

    In one region per call the threads claim the parts themselves and wait for each other by
    spinning: no parallel region to start per colour and step.  Beam, 2 threads, M tet-steps/s,
    a process each, alternating, quiet host: 10k tets 185-195 against 155-167 with a region per
    colour and step, 100k 204-227 against 198-218.  But where another process holds a core, a
    thread loses its core while it holds a part, and the other waits for it: 10k 89-95 against
    113-114, 100k 108-112 against 113-115.  Waits past the spinning (``SPINS_BEFORE_YIELD``) tell
    the two apart: on the quiet host 0-2 in a call of 800 parts at 10k, 0-6 of 160 at 100k; with
    a core taken 57-190 and 2-37.  So a call in one region whose long waits exceed
    ``LONG_WAIT_SHARE`` of its parts sends the next ``SEPARATE_CALLS`` calls to a region per colour
    and step (TBB's waiting threads sleep, freeing the core); then one region is tried again.
    With the switch, against a region per colour and step always (three alternating processes
    each): quiet, 10k 1.14-1.19x, 100k 1.01-1.08x, 310k 1.01-1.04x; with another process spinning
    on a core, 0.92-1.09x at 10k to 310k, medians 0.95-0.98x.  (All measured when the threads
    took every part from one shared counter.  Since a thread takes its own parts and then any
    part not yet taken, the one that keeps its core takes the other's parts instead of waiting:
    with another process spinning on a core, 0-2 long waits a call of 800 parts at 10k and 1-5 of
    160 at 100k, as on the quiet host (0-2 and 0-6), so the switch no longer fires there, and the
    one region ran 1.15x and 1.06x the shared counter with its switch.)
    """

    def __init__(self):
        self.separate_calls_left = 0

    def one_region(self):
        """Whether the next call runs in one region."""
        return self.separate_calls_left == 0

    def record(self, one_region, long_waits, parts):
        """Note a call's way (``one_region``), its ``long_waits`` (``advance``'s result) and the
        ``parts`` it ran (steps x parts a step)."""
        if not one_region:
            self.separate_calls_left = max(0, self.separate_calls_left - 1)
        elif long_waits > LONG_WAIT_SHARE * parts:
            self.separate_calls_left = SEPARATE_CALLS


LONG_WAIT_SHARE = 0.1
SEPARATE_CALLS = 16


class PrefetchChoice:
    """Whether the next call of the step of a large mesh (``BlockLayout.measure_prefetch``) runs
    with its prefetches or without them (``BlockLayout.unprefetched``), chosen by timing both.

    What the prefetches buy depends on the host as much as on the mesh: on the 310k beam they cost
    a Xeon 7-12 % (179-212 against 193-237 M tet-steps/s without, in three suite runs) and gained
    1.43x on an AMD EPYC; from 1M up they gained on both (1.14-1.23x at 1M and 1.19-1.21x at 2M
    on the Xeon).  So a trial runs the two in the order with, without, without, with, with, ...
    for ``2 * (1 + TRIAL_CALLS)`` calls (so that calls of alternating lengths, a run's 32 steps and
    a frame's remainder, fall to both), the first call of each untimed (it may find the caches
    cold; ``simulation.step`` compiles both ways before the first call), compares their seconds
    per step over all the other calls, and runs the faster for
    ``KEEP_CALLS`` calls; then the next trial begins.  Calls of no step do not count.  Both give
    the same bits.
    """

    def __init__(self):
        self.trial_call = 0
        self.seconds = {True: 0.0, False: 0.0}
        self.steps = {True: 0, False: 0}
        self.kept_calls_left = 0
        self.prefetch = True

    @property
    def trying(self):
        """Whether the calls now are a trial's, not the kept way's."""
        return self.kept_calls_left == 0

    def prefetch_next(self):
        """Whether the next call fetches ahead."""
        if not self.trying:
            return self.prefetch
        return (self.trial_call + 1) // 2 % 2 == 0

    def record(self, prefetched, seconds, steps):
        """Note a call (``prefetched`` as ``prefetch_next`` said) that took ``seconds`` for ``steps`` steps."""
        if steps <= 0:
            return
        if not self.trying:
            self.kept_calls_left -= 1
            return
        if self.trial_call >= 2:
            self.seconds[prefetched] += seconds
            self.steps[prefetched] += steps
        self.trial_call += 1
        if self.trial_call == 2 * (1 + TRIAL_CALLS):
            self.prefetch = self.seconds[True] * self.steps[False] <= self.seconds[False] * self.steps[True]
            self.kept_calls_left = KEEP_CALLS
            self.trial_call = 0
            self.seconds = {True: 0.0, False: 0.0}
            self.steps = {True: 0, False: 0}


TRIAL_CALLS = 3
KEEP_CALLS = 256


@njit
def block_range_forces(x, rest, blocks, first, stop, model, lam, mu, scatter, vertex_forces, corner_forces, buf):
    """Forces of blocks ``first`` to ``stop - 1``, in order (in the precision of ``blocks``' rest data),
    through the scratch ``buf`` (``SCRATCH``, starting at a cache line; this thread's alone).

    scatter: add them to ``vertex_forces`` (node_count, 4) (no other thread may be writing the
    vertices of these blocks); else store them per (tet, corner) into ``corner_forces`` (tet_count, 4, 3).
    """
    block_tets = blocks[0]
    block_rest = blocks[1]
    tet_count = blocks[2]
    prefetch = blocks[7]
    rest_points = blocks[11]
    for b in range(first, stop):
        prefetch_vertex_rows(x, vertex_forces, blocks[8], blocks[9], b, prefetch, rest_points)
        block_forces(x, block_tets, block_rest, b, model, lam, mu, buf, rest, prefetch, blocks[10][b], blocks[12],
                     rest_points)
        lane_count = min(BLOCK, tet_count - b * BLOCK)
        if scatter:
            scatter_block(block_tets, b, lane_count, buf, vertex_forces)
        else:
            store_block_corners(b, lane_count, buf, corner_forces)


@njit
def elastic_vertex_forces(x, blocks, model, lam, mu, vertex_forces, buf):
    """Elastic forces [N] on every vertex at positions ``x`` (n, 3) [m] into ``vertex_forces``
    (n, ``FORCE_COLUMNS``), zeroed first: the step's blocked kernels (``block_range_forces``), every
    block in order on this thread.  blocks: ``step_arguments``' of a float64 model with the colour
    scatter; buf: ``SCRATCH`` floats starting at a cache line.  (The stable-step estimate's force
    evaluations, ``stability._SymmetricOperator``.)

    The blocks run from the first part's first to the last part's last, typed as ``part_step``
    passes them (int64, not the literal 0): the step and this function then call one compiled
    ``block_range_forces``, whose lane loop LLVM optimises once, not once for each."""
    vertex_forces[...] = 0.0
    part_offsets = blocks[3]
    block_range_forces(x, None, blocks, part_offsets[0], part_offsets[-1], model, lam, mu, True, vertex_forces,
                       np.empty((0, 4, 3), dtype=vertex_forces.dtype), buf)


@njit_inline
def part_step(x, rest, v, step_start, step, dt, blocks, part, model, lam, mu, vertex_forces, corner_forces,
              inv_mass, gravity, external_accel, held, held_start, held_velocity, ground, ground_faces,
              damping_factor, scratch):
    """Part ``part``'s share of step ``step`` of the colour scatter (``advance``, same arguments):
    after the first step of the call the previous step's update of the vertices the part owns,
    then its faces' areas (with a ground) and its blocks' forces, added into ``vertex_forces``.
    Inlined by LLVM into both of ``advance``'s schedules, as is the vertex update it calls."""
    run_offsets = blocks[5]
    owned_runs = blocks[6]
    part_offsets = blocks[3]
    if step > step_start:
        for r in range(run_offsets[part], run_offsets[part + 1]):
            for i in range(owned_runs[r, 0], owned_runs[r, 1]):
                update_from_forces(x, rest, v, vertex_forces, i, dt, step * dt, inv_mass, gravity, external_accel,
                                   held, held_start, held_velocity, ground, damping_factor)
    if ground is not None:
        part_face_areas(x, rest, ground_faces, ground[3], part)
    block_range_forces(x, rest, blocks, part_offsets[part], part_offsets[part + 1], model, lam, mu, True,
                       vertex_forces, corner_forces, scratch[part * SCRATCH:(part + 1) * SCRATCH])


def advance(x, rest, v, step_start, step_count, dt,
            blocks, colour_offsets, scatter, model, lam, mu, offsets, slots, vertex_forces, corner_forces,
            inv_mass, gravity, external_accel, held, held_start, held_velocity,
            ground, ground_faces, damping_factor, threads, one_region):
    """Advance positions ``x`` and velocities ``v`` (node_count, 3) [m, m/s] in place by ``step_count`` steps.

    rest: None; or, in float32, the rest positions (n, 3) [m], ``x`` then holding displacements
    from them (and ``held_start`` too).  Every array and scalar is in the precision of ``x``,
    but for ``rest``, the ground's tuple and ``damping_factor``: float64.
    step_start: index of the first step (time ``step_start * dt`` [s]); dt [s].
    blocks: ``(block_tets, block_rest, tet_count, part_offsets, colour_parts, run_offsets, owned_runs,
    prefetch, first_offsets, first_vertices, whole_rows, rest_points, first_steps)`` of a
    ``kernels.blocked.BlockLayout`` (rest_points: None, or the rest positions where
    ``rest_from_points``; first_steps: (block_count,) uint8, corotated's first steps of Newton's
    iteration per block, ``kernels.blocked.corotated_block``, which adapts them step by step from
    the 4 ``step_arguments`` starts each call with); colour_offsets:
    (colours + 1,) into colour_parts; model: the model id as a ``kernels.jit.CompileTimeConstant``
    (the step compiles its lane loop alone; a plain int is refused at compile time); Lame lam, mu [Pa].
    scatter True: the forces are added into ``vertex_forces`` (node_count, 4: x, y, z and a zero,
    ``kernels.simd.FORCE_COLUMNS``), one colour of parts
    at a time, its parts in parallel (``advance_colour``); False: stored into ``corner_forces``
    (tet_count, 4, 3) and gathered per vertex through the vertex -> (tet, corner) map ``offsets``
    (n+1,), ``slots`` (4m,) (``advance_csr``: kept for comparison, and compiled only where asked
    for; with it in the same compiled function, each specialisation of the step took a third
    longer to compile: a second one of StVK, damping added, 20-21 s against 13-16 s).
    The colour scatter moves each part's vertices (``BlockLayout.owned_runs``) at the start of the
    part's next step (``part_step``), and all of them after the last step: one wait per colour and
    step, none for the vertex update.  one_region: the parts of every step in one parallel region,
    colour after colour, each thread waiting, spinning, until the colours before are done
    (``kernels.sync``), then taking its own parts of the colour (``part_owner``: the same slabs
    every step, whose vertex rows stay in its core's cache) and then any part of it no thread has
    taken yet (a thread that fell behind, or lost its core); else a region per colour and step
    (``PartSchedule`` chooses).  Returns the waits that outlasted the spinning (0 for csr).
    Each vertex gets the same arithmetic in the same order as in a separate vertex loop, so the
    same bits, in either schedule.  With a ground, each part also
    adds its boundary faces' areas to their corners (``part_face_areas``) from the positions its
    forces see; the contact of the vertex update reads them, not the neighbours' positions.  The
    csr scatter updates every vertex in a loop of its own after each step, with a ground after
    summing every part's face areas in one thread.
    inv_mass (n,) [1/kg]; gravity: 3-tuple [m/s^2]; external_accel: None (no tractions: gravity
    alone), or (n, 3) [m/s^2] gravity plus tractions / mass.
    held (n, 3) bool; held_start, held_velocity (n, 3) [m, m/s]: prescribed motion of held components.
    ground: None, or the tuple ``update_vertex`` takes (small: it reaches every vertex update);
    ground_faces: None, or ``(part_face_offsets, part_faces)`` (``Model.ground_arguments``);
    damping_factor: None, or exp(-damping dt).
    threads: ``numba.get_num_threads()``.

    Every vertex sums its forces in a fixed order, whatever the thread count: a run gives the same
    bits every time.  The forces and every vertex update are computed with subnormal numbers flushed
    to zero (``kernels.simd.flush_subnormals``: in float32 the front of a wave is made of them, and
    each cost a microcode assist), each thread's control word restored after its part or chunk.
    """
    driver, arguments = advance_driver(x, rest, v, step_start, step_count, dt, blocks, colour_offsets, scatter, model,
                                       lam, mu, offsets, slots, vertex_forces, corner_forces, inv_mass, gravity,
                                       external_accel, held, held_start, held_velocity, ground, ground_faces,
                                       damping_factor, threads, one_region)
    return driver(*arguments)


def advance_driver(x, rest, v, step_start, step_count, dt,
                   blocks, colour_offsets, scatter, model, lam, mu, offsets, slots, vertex_forces, corner_forces,
                   inv_mass, gravity, external_accel, held, held_start, held_velocity,
                   ground, ground_faces, damping_factor, threads, one_region):
    """The compiled driver ``advance`` runs for its arguments (the same), and the driver's own
    arguments: ``(advance_colour, (...))`` or ``(advance_csr, (...))``."""
    if scatter:
        return advance_colour, (x, rest, v, step_start, step_count, dt, blocks, colour_offsets, model, lam, mu,
                                vertex_forces, corner_forces, inv_mass, gravity, external_accel, held, held_start,
                                held_velocity, ground, ground_faces, damping_factor, threads, one_region)
    return advance_csr, (x, rest, v, step_start, step_count, dt, blocks, model, lam, mu, offsets, slots,
                         vertex_forces, corner_forces, inv_mass, gravity, external_accel, held, held_start,
                         held_velocity, ground, ground_faces, damping_factor, threads)


@njit
def zeroed_counters(part_count=0):
    """``advance``'s counters, zeroed, and after them a claim per part of the one region (the
    steps of the call claimed so far), each on a cache line of its own (a serial function: in
    ``advance_colour`` Numba would make ``np.zeros`` a parallel loop of its own, to compile)."""
    return np.zeros((CLAIMS + part_count) * COUNTER_STRIDE, dtype=np.int64)


@njit_inline
def part_owner(part, part_count, threads):
    """The thread (chunk of the one region) that runs ``part`` (0 <= part < part_count) unless
    another takes it first: ``threads`` runs of consecutive parts."""
    return part * threads // part_count


@njit_inline
def claim(counters, k, step):
    """Whether this thread is the first to take the ``k``-th part (of ``colour_parts``) in the
    call's ``step``-th step: its claim then goes from ``step`` steps claimed to ``step + 1``.  A
    thread reaches step ``step`` only when step ``step - 1`` is done, so the claim holds ``step``
    or ``step + 1``.  Read first: a part already taken costs no exclusive hold of its line."""
    line = (CLAIMS + k) * COUNTER_STRIDE
    return load_acquire(counters, line) == step and compare_exchange(counters, line, step, step + 1)


@njit_parallel
def advance_colour(x, rest, v, step_start, step_count, dt, blocks, colour_offsets, model, lam, mu, vertex_forces,
                   corner_forces, inv_mass, gravity, external_accel, held, held_start, held_velocity, ground,
                   ground_faces, damping_factor, threads, one_region):
    """``advance`` with the colour scatter (``scatter`` True)."""
    node_count = x.shape[0]
    part_offsets = blocks[3]
    colour_parts = blocks[4]
    # a scratch buffer per part, made once per call, not per part and step
    scratch = cache_aligned_scratch(max(part_offsets.shape[0] - 1, threads) * SCRATCH, blocks[1])
    for i in prange(node_count):
        for k in range(FORCE_COLUMNS):
            vertex_forces[i, k] = 0.0
        if ground is not None:
            ground[3][i] = 0.0
    part_count = colour_parts.shape[0]
    colour_count = colour_offsets.shape[0] - 1
    counters = zeroed_counters(part_count if one_region else 0)
    if one_region:
        # every part of every step in one region, colour after colour: each thread waits until
        # every part of the colours before is done, then takes its own parts of the colour
        # (``part_owner``), then any other part of it that no thread has taken yet
        for chunk in prange(threads):
            control = flush_subnormals()
            for group in range(step_count * colour_count):
                step = group // colour_count
                colour = group % colour_count
                wait_until_done(counters, step * part_count + colour_offsets[colour])
                for own in (True, False):
                    for k in range(colour_offsets[colour], colour_offsets[colour + 1]):
                        if ((part_owner(colour_parts[k], part_count, threads) == chunk) == own
                                and claim(counters, k, step)):
                            part_step(x, rest, v, step_start, step_start + step, dt, blocks, colour_parts[k],
                                      model, lam, mu, vertex_forces, corner_forces, inv_mass, gravity,
                                      external_accel, held, held_start, held_velocity, ground, ground_faces,
                                      damping_factor, scratch)
                            fetch_add(counters, DONE, 1)
            restore_float_control(control)
    else:
        for step in range(step_start, step_start + step_count):
            for colour in range(colour_offsets.shape[0] - 1):
                for k in prange(colour_offsets[colour], colour_offsets[colour + 1]):
                    control = flush_subnormals()
                    part_step(x, rest, v, step_start, step, dt, blocks, colour_parts[k],
                              model, lam, mu, vertex_forces, corner_forces, inv_mass, gravity, external_accel,
                              held, held_start, held_velocity, ground, ground_faces, damping_factor, scratch)
                    restore_float_control(control)
    if step_count > 0:
        chunks = min(threads, node_count)
        for chunk in prange(chunks):
            control = flush_subnormals()
            # uint64 vertex numbers, as part_step's (``BlockLayout.owned_runs``): one specialisation
            # of update_from_forces (``kernels.jit.njit_parallel``)
            first = np.uint64(np.int64(chunk) * node_count // chunks)
            for i in range(first, np.uint64((np.int64(chunk) + 1) * node_count // chunks)):
                update_from_forces(x, rest, v, vertex_forces, i, dt, (step_start + step_count) * dt, inv_mass,
                                   gravity, external_accel, held, held_start, held_velocity, ground,
                                   damping_factor)
            restore_float_control(control)
    return counters[LONG_WAITS]


@njit_parallel
def advance_csr(x, rest, v, step_start, step_count, dt, blocks, model, lam, mu, offsets, slots, vertex_forces,
                corner_forces, inv_mass, gravity, external_accel, held, held_start, held_velocity, ground, ground_faces,
                damping_factor, threads):
    """``advance`` with the forces stored per (tet, corner) and gathered per vertex (``scatter`` False)."""
    node_count = x.shape[0]
    block_count = blocks[0].shape[0]
    part_offsets = blocks[3]
    # a scratch buffer per chunk (at most ``threads``), made once per call
    scratch = cache_aligned_scratch(threads * SCRATCH, blocks[1])
    for step in range(step_start, step_start + step_count):
        t_next = (step + 1) * dt
        chunks = min(threads, block_count)
        for chunk in prange(chunks):
            control = flush_subnormals()
            block_range_forces(x, rest, blocks, chunk * block_count // chunks, (chunk + 1) * block_count // chunks,
                               model, lam, mu, False, vertex_forces, corner_forces,
                               scratch[chunk * SCRATCH:(chunk + 1) * SCRATCH])
            restore_float_control(control)
        if ground is not None:
            for part in range(part_offsets.shape[0] - 1):     # boundary faces only: one thread
                part_face_areas(x, rest, ground_faces, ground[3], part)
        vertex_chunks = min(threads, node_count)
        for chunk in prange(vertex_chunks):
            control = flush_subnormals()
            for i in range(chunk * node_count // vertex_chunks, (chunk + 1) * node_count // vertex_chunks):
                fx, fy, fz = gather_vertex_force(corner_forces, offsets, slots, i)
                update_vertex(x, rest, v, i, fx, fy, fz, dt, t_next, inv_mass, gravity, external_accel, held,
                              held_start, held_velocity, ground, damping_factor)
            restore_float_control(control)
    return 0


def step_arguments(model, work, prefetch=True):
    """The ``blocks, colour_offsets, scatter, offsets, slots, vertex_forces, corner_forces``
    arguments of ``advance`` for ``model``; work: a buffer from ``work_buffer`` (or larger), in the
    precision of the step (``SinglePrecisionWork.forces`` in float32); prefetch False: the blocks
    of the layout without prefetches (``BlockLayout.unprefetched``; ``PrefetchChoice``).  Each call starts every block
    at four first steps of corotated's Newton iteration (``blocks[12]``), so that a call's forces do
    not depend on earlier calls: a resumed run steps as the run that never stopped.
    """
    layout = model.blocks if prefetch else model.blocks.unprefetched
    n, m = model.node_count, model.tet_count
    flat = work.reshape(-1)
    needed = FORCE_COLUMNS * n if layout.scatter == "colour" else 12 * m
    if flat.size < needed:
        raise ValueError(f"work buffer of {flat.size} floats, the {layout.scatter} scatter needs {needed}")
    layout.check_model(model.material_id, flat.dtype)
    if not layout.rest_from_points and layout.rest.shape[0] != layout.tets.shape[0]:
        raise ValueError("the layout holds no rest data (built with rest_from_points); the step must compute them")
    blocks = (layout.tets, layout.rest, layout.tet_count, layout.part_offsets, layout.colour_parts,
              layout.run_offsets, layout.owned_runs, layout.prefetch, layout.first_offsets, layout.first_vertices,
              layout.whole_rows, layout.points_for_rest(model.rest_points),
              np.full(layout.tets.shape[0], NEWTON_FIRST_STEPS, dtype=np.uint8))
    if layout.scatter == "colour":
        vertex_forces = flat[:FORCE_COLUMNS * n].reshape(n, FORCE_COLUMNS)
        corner_forces = np.empty((0, 4, 3), dtype=flat.dtype)
        scatter = True
    else:
        vertex_forces = np.empty((0, FORCE_COLUMNS), dtype=flat.dtype)
        corner_forces = flat[:12 * m].reshape(m, 4, 3)
        scatter = False
    return (blocks, layout.colour_offsets, scatter, model.csr_offsets, model.csr_slots,
            vertex_forces, corner_forces)


def force_buffer(model, dtype=np.float64):
    """Vertex forces (n, ``FORCE_COLUMNS``) for the colour scatter (x, y, z and a zero: a vector
    per vertex, ``kernels.simd.add_corner_force``, starting at a cache line), or per-(tet, corner)
    forces (m, 4, 3) for csr."""
    if model.blocks.scatter == "colour":
        forces = cache_aligned_empty((model.node_count, FORCE_COLUMNS), dtype)
        forces[...] = 0.0
        return forces
    return np.empty((model.tet_count, 4, 3), dtype=dtype)


class SinglePrecisionWork:
    """The buffers of the float32 step (``work_buffer`` of a model with ``precision: float32``).

    ``load`` turns the float64 state into displacements ``u = x - X`` and velocities in float32
    before a call of ``advance``; ``store`` turns them back (``x = X + u`` in float64) after it.
    float64 holds 29 more bits, so the round trip returns the same float32 values (only
    displacements below about 1e-9 of the coordinates may move by one float32 unit): splitting a
    run into more calls changes next to nothing, and the same calls give the same bits.
    inv_mass, held_velocity: the model's arrays in float32; gravity: a 3-tuple of float32;
    external_accel: the model's in float32 where it has tractions, else None; rest: the rest
    positions, kept in float64 (only the ground reads them, ``position``: the depth is then exact
    to float32's spacing of the displacement, not of the coordinate); forces: the scatter's buffer
    (``force_buffer``).  Velocities are float32 as they are: a step's change of a velocity below
    6e-8 of it (a weak damping, gravity on a fast body) is lost to its rounding.
    """

    def __init__(self, model):
        n = model.node_count
        self.u = np.zeros((n, 3), dtype=np.float32)
        self.v = np.zeros((n, 3), dtype=np.float32)
        self.held_start = np.zeros((n, 3), dtype=np.float32)
        self.forces = force_buffer(model, np.float32)
        self.rest = model.rest_points
        self.inv_mass = model.inv_mass.astype(np.float32)
        self.gravity = tuple(np.float32(g) for g in model.gravity)
        self.external_accel = model.external_accel.astype(np.float32) if model.has_tractions else None
        self.held_velocity = model.held_velocity.astype(np.float32)

    def load(self, state, rest_points):
        np.subtract(state.x, rest_points, out=self.u, casting="same_kind")
        np.subtract(state.held_start, rest_points, out=self.held_start, casting="same_kind")
        self.v[...] = state.v

    def store(self, state, rest_points):
        np.add(rest_points, self.u, out=state.x)
        state.v[...] = self.v


def work_buffer(model):
    """The work buffer ``advance`` needs for ``model``: float64 vertex forces or per-(tet, corner)
    forces, or for a float32 model a ``SinglePrecisionWork``."""
    if model.precision == "float32":
        return SinglePrecisionWork(model)
    return force_buffer(model)
