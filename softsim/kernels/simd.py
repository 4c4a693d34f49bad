"""The memory moves of the blocked step that Numba cannot express, written as LLVM IR.

``kernels.blocked`` gathers the corner positions of a block of tets into rows of lanes and adds
the corner forces back into the vertices.  Written as Numba loops, both compile to one scalar
load and one scalar store per value: the store port is then the limit (12 stores a tet each
way), and LLVM cannot vectorise the gather because it cannot prove that ``x[tets[j]]`` and the
scratch buffer do not overlap (no runtime check exists for an indexed access).  These intrinsics
emit the instructions directly:

- ``gather_corner_rows``: the scalar loads of a row of lanes are inserted into vector registers
  (``vmovsd`` / ``vmovhps`` / ``vinsertf128`` / ``vinsertf64x4`` on AVX-512) and stored once per
  vector: per tet 12 loads and 1.5 stores (float64) instead of 12 and 12.  Where the target has
  AVX-512, each vertex's row is loaded whole instead and the rows are transposed into rows of
  lanes by two-source shuffles (``gather_by_transpose``): a shuffle per value becomes about one
  per five.  The AVX-512 gather instruction, which LLVM emits when it does vectorise such a
  loop, was slower than the scalar loop on Zen 4.
- ``add_corner_force``: a corner's three force components are added to a vertex's row of four
  (``(n, 4)`` vertex forces, the fourth always zero) as one vector read-modify-write: 4 stores a
  tet instead of 12.  Each component gets the same IEEE addition as a scalar one: the same bits.
  ``add_four_lanes_corner_forces`` does so for four lanes at once, building their rows by
  shuffles from vector loads of the rows of lanes: in float32 always, in float64 where the host
  measured that faster (``float64_scatter_by_shuffles``).

Measured per tet, one thread, data in L1/L2 (10k-tet beam, AVX-512, Zen 4, medians of 9): the
gather by inserts 3.6-3.8 ns against 4.8 (float32 and float64 alike), the scatter 3.1-3.2 ns
against 4.6-4.8.  On a Xeon (100k-tet beam), the gather by transposing rows 1.63 / 1.26 ns in
float64 / float32 against 2.62 / 2.81 by inserts (``gather_by_transpose``).

And a hint Numba has no word for:

- ``prefetch_line``: fetch a cache line into L2 ahead of its use (``llvm.prefetch`` with locality
  2: ``prefetcht1`` on x86), so that the rest data of a block are on their way while an earlier
  block computes (``kernels.blocked``).

And the floating-point control Numba leaves alone:

- ``flush_subnormals`` / ``restore_float_control``: a thread's x86 FTZ and DAZ bits on for the
  step's parts and back off after them: in float32 the front of a wave is made of subnormal
  numbers, each a microcode assist (3-4x slower steps until the wave fills the mesh).

All take C-contiguous arrays (the typing rejects others) and check no bounds (the block layout
guarantees the indices); the gather and the scatter assume 3 columns in ``x`` and
``FORCE_COLUMNS`` in the vertex forces, which their callers in ``kernels.blocked`` check.  A
prefetch never faults, but its callers keep it inside the array too.
"""

from llvmlite import binding, ir
from llvmlite.ir.values import FunctionAttributes
from numba import types
from numba.extending import intrinsic

# Bytes of one vector of the gathered rows (a zmm register; LLVM splits it where vectors are
# narrower, e.g. into two ymm on AVX2).
VECTOR_BYTES = 64
# Columns of the vertex forces ``add_corner_force`` adds into: x, y, z and a zero.
FORCE_COLUMNS = 4
# Bytes of a cache line on x86-64 and most Arm cores (Apple's have 128: a prefetch every 64 B
# then asks for some lines twice, which costs an instruction and nothing else).
CACHE_LINE_BYTES = 64
# ``llvm.prefetch`` locality: 3 keeps the line in every level (``prefetcht0``), 2 in L2 and
# beyond (``prefetcht1``), 0 streams it past the caches (``prefetchnta``).
PREFETCH_LOCALITY_L2 = 2
# The name of ``llvm.prefetch`` for a byte pointer: ``p0i8`` with typed pointers, ``p0`` with
# opaque ones (LLVM 15 on; llvmlite 0.44 still builds typed ones on LLVM 15, whose IR parser
# renames the intrinsic to match).
_PREFETCH = "llvm.prefetch.p0" if binding.llvm_version_info[0] >= 15 else "llvm.prefetch.p0i8"


def _is_c_array(t, ndim):
    return isinstance(t, types.Array) and t.ndim == ndim and t.layout == "C"


def _int64(context, builder, value, value_type):
    return context.cast(builder, value, value_type, types.int64)


def _data(context, builder, array_type, array):
    """The data pointer of a Numba array value (typed: a GEP on it counts elements)."""
    return context.make_array(array_type)(context, builder, array).data


def _float_type(context, dtype):
    """``(LLVM type, size in bytes)`` of the float ``dtype``."""
    float_type = context.get_value_type(dtype)
    return float_type, context.get_abi_sizeof(float_type)


@intrinsic(prefer_literal=True)
def gather_corner_rows(typingctx, x, tets, tet_offset, buf, buf_offset, lanes, whole_rows):
    """Gather the vertex rows ``x[tets.flat[tet_offset + j]]`` of ``lanes`` lanes (a literal multiple
    of the vector width) into three rows of ``buf``:
    ``buf[buf_offset + k * lanes + j] = x[tets.flat[tet_offset + j], k]``, k < 3, j < lanes.

    x: (n, 3) C-contiguous float; tets: C-contiguous uint32 (any shape, indexed flat); buf: 1D,
    the dtype of ``x``; offsets: integers (elements).  Compiled by transposing vertex rows where
    the target has AVX-512 (``gather_by_transpose``), else by inserting values.
    whole_rows: a literal bool; True only where no lane's vertex is x's last row (``n - 1``): the
    transpose then loads each row as four values with a plain load, where False masks the fourth
    off so as not to read past ``x``.  The fourth is the next row's first value, which another
    thread may be writing at the time (the vertex update of a part of the same colour): it is
    never used, only shuffled away, and the three values of the row itself are not written then.
    """
    if not (_is_c_array(x, 2) and isinstance(x.dtype, types.Float) and isinstance(tets, types.Array)
            and tets.layout == "C" and tets.dtype == types.uint32 and _is_c_array(buf, 1) and buf.dtype == x.dtype
            and isinstance(lanes, types.IntegerLiteral)
            and lanes.literal_value % (VECTOR_BYTES * 8 // x.dtype.bitwidth) == 0
            and isinstance(whole_rows, types.BooleanLiteral)):
        return None
    lane_count = lanes.literal_value
    plain_loads = whole_rows.literal_value
    sig = types.void(x, tets, tet_offset, buf, buf_offset, lanes, whole_rows)

    def codegen(context, builder, signature, args):
        x_arg, tets_arg, tet_offset_arg, buf_arg, buf_offset_arg, _, _ = args
        x_data = _data(context, builder, signature.args[0], x_arg)
        tet_data = _data(context, builder, signature.args[1], tets_arg)
        buf_data = _data(context, builder, signature.args[3], buf_arg)
        float_type, size = _float_type(context, signature.args[0].dtype)
        tet_offset = _int64(context, builder, tet_offset_arg, signature.args[2])
        buf_offset = _int64(context, builder, buf_offset_arg, signature.args[4])
        i64 = ir.IntType(64)
        width = VECTOR_BYTES // size
        vector_type = ir.VectorType(float_type, width)
        by_transpose = gather_by_transpose(context) if GATHER_BY_TRANSPOSE is None else GATHER_BY_TRANSPOSE
        lane_rows = _rows_by_transpose if by_transpose else _rows_by_inserts
        for first in range(0, lane_count, width):
            row_starts = []                    # x's element offset of each lane's vertex row
            for lane in range(width):
                index_ptr = builder.gep(tet_data, [builder.add(tet_offset, ir.Constant(i64, first + lane))],
                                        inbounds=True)
                row_starts.append(builder.mul(builder.zext(builder.load(index_ptr, align=4), i64), ir.Constant(i64, 3)))
            rows = lane_rows(builder, x_data, row_starts, float_type, size, plain_loads)
            for k in range(3):
                out = builder.gep(buf_data, [builder.add(buf_offset, ir.Constant(i64, k * lane_count + first))],
                                  inbounds=True)
                builder.store(rows[k], builder.bitcast(out, vector_type.as_pointer()), align=size)
        return context.get_dummy_value()

    return sig, codegen


# None: ``gather_corner_rows`` transposes where ``gather_by_transpose`` says so; True / False: always
# / never (the tests compile both ways on any host: either is correct on every target).
GATHER_BY_TRANSPOSE = None


def gather_by_transpose(context):
    """Whether the target of Numba's ``context`` has AVX-512 (F and VL), where gathering by
    transposing vertex rows (``_rows_by_transpose``) beat inserting values (``_rows_by_inserts``):
    per tet, one thread, 100k-tet beam, AVX-512 Xeon (KVM): 1.63 against 2.62 ns in float64,
    1.26 against 2.81 ns in float32.  Compiled for AVX2 on the same machine, inserting took 1.75
    and 2.2 ns, transposing 1.98 and 2.12."""
    features = getattr(context.codegen(), "_tm_features", None)
    if features is None:
        features = binding.get_host_cpu_features().flatten()
    return "+avx512f" in features and "+avx512vl" in features


def _rows_by_inserts(builder, x_data, row_starts, float_type, size, plain_loads):
    """Rows x, y, z (vectors of ``len(row_starts)`` lanes): each value loaded and inserted into its
    lane (``vmovsd`` / ``vmovhps`` / ``vinsertf128``...); ``plain_loads`` changes nothing here
    (no load reaches past its value)."""
    i64, i32 = ir.IntType(64), ir.IntType(32)
    vector_type = ir.VectorType(float_type, len(row_starts))
    rows = [ir.Constant(vector_type, ir.Undefined)] * 3
    for lane, start in enumerate(row_starts):
        for k in range(3):
            value_ptr = builder.gep(x_data, [builder.add(start, ir.Constant(i64, k))], inbounds=True)
            rows[k] = builder.insert_element(rows[k], builder.load(value_ptr, align=size), ir.Constant(i32, lane))
    return rows


def _rows_by_transpose(builder, x_data, row_starts, float_type, size, plain_loads):
    """Rows x, y, z (vectors of ``W = len(row_starts)`` lanes, W a multiple of 4): each vertex's
    row loaded as one vector of 4 (with ``plain_loads`` a plain load, else its fourth value masked
    off: no read past the array; masked everywhere, they made the step 1.01-1.05x slower), the rows
    of a quarter of the lanes side by side in a vector ``Q_k``, then x and y of half the lanes
    taken from two of them, z likewise, and halves joined: seven two-source shuffles (AVX-512
    ``vpermt2pd`` / ``vpermt2ps``) for 3 W values, where inserting takes one shuffle a value."""
    width = len(row_starts)
    quarter, half = width // 4, width // 2
    row_type = ir.VectorType(float_type, 4)
    pointers = [builder.bitcast(builder.gep(x_data, [start], inbounds=True), row_type.as_pointer())
                for start in row_starts]
    if plain_loads:
        rows = [builder.load(pointer, align=size) for pointer in pointers]
    else:
        rows = [_masked_row_load(builder, pointer, row_type, size) for pointer in pointers]
    quarters = []                              # Q_k: lanes k W/4 .. (k + 1) W/4 - 1, 4 values each
    for k in range(4):
        parts = rows[k * quarter:(k + 1) * quarter]
        while len(parts) > 1:
            n = 2 * len(parts[0].type)
            parts = [_shuffle(builder, parts[i], parts[i + 1], range(n)) for i in range(0, len(parts), 2)]
        quarters.append(parts[0])

    def at(lane, k):                           # value k of lane (< W/2) in Q_a ++ Q_b
        return (lane // quarter) * width + 4 * (lane % quarter) + k

    xy = [_shuffle(builder, quarters[2 * h], quarters[2 * h + 1],
                   [at(p, 0) if p < half else at(p - half, 1) for p in range(width)]) for h in range(2)]
    z = [_shuffle(builder, quarters[2 * h], quarters[2 * h + 1], [at(p % half, 2) for p in range(width)])
         for h in range(2)]
    low = [p if p < half else width + p - half for p in range(width)]      # first halves joined
    high = [half + p if p < half else width + p for p in range(width)]    # second halves joined
    return [_shuffle(builder, xy[0], xy[1], low), _shuffle(builder, xy[0], xy[1], high),
            _shuffle(builder, z[0], z[1], low)]


def _shuffle(builder, a, b, indices):
    """``shufflevector a, b`` with constant ``indices`` into ``a ++ b``."""
    i32 = ir.IntType(32)
    indices = list(indices)
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(i32, len(indices)),
                                                    [ir.Constant(i32, i) for i in indices]))


def _masked_row_load(builder, pointer, row_type, size):
    """The first three values at ``pointer`` as a vector of 4 (``llvm.masked.load``, the fourth
    lane off: it neither reads nor faults past the end of ``x``)."""
    i1, i32 = ir.IntType(1), ir.IntType(32)
    mask_type = ir.VectorType(i1, 4)
    suffix = f"v4f{8 * size}"
    name = f"llvm.masked.load.{suffix}.p0" + ("" if binding.llvm_version_info[0] >= 15 else suffix)
    load = builder.module.globals.get(name) or ir.Function(
        builder.module, ir.FunctionType(row_type, [row_type.as_pointer(), i32, mask_type, row_type]), name)
    mask = ir.Constant(mask_type, [ir.Constant(i1, 1)] * 3 + [ir.Constant(i1, 0)])
    return builder.call(load, [pointer, ir.Constant(i32, size), mask, ir.Constant(row_type, ir.Undefined)])


def _add_to_row(builder, forces_data, vertex, add, size):
    """``forces[vertex, :FORCE_COLUMNS] += add`` (a vector of ``FORCE_COLUMNS``): one load, add and store."""
    row = builder.gep(forces_data, [builder.mul(vertex, ir.Constant(ir.IntType(64), FORCE_COLUMNS))], inbounds=True)
    row = builder.bitcast(row, add.type.as_pointer())
    builder.store(builder.fadd(builder.load(row, align=size), add), row, align=size)


def _zero_row(float_type):
    """The constant vector of ``FORCE_COLUMNS`` zeros of ``float_type``."""
    return ir.Constant(ir.VectorType(float_type, FORCE_COLUMNS), [ir.Constant(float_type, 0.0)] * FORCE_COLUMNS)


def _row_from_values(builder, data, offset, stride, float_type, size):
    """The vector ``(data[offset], data[offset + stride], data[offset + 2 stride], 0)``: three scalar
    loads (offset, stride: i64 values)."""
    i32 = ir.IntType(32)
    row = _zero_row(float_type)
    for k in range(3):
        row = builder.insert_element(row, builder.load(builder.gep(data, [offset], inbounds=True), align=size),
                                     ir.Constant(i32, k))
        offset = builder.add(offset, stride)
    return row


@intrinsic
def add_corner_force(typingctx, forces, vertex, buf, buf_offset, row_stride):
    """``forces[vertex, k] += buf[buf_offset + k * row_stride]`` for k < 3, as one vector
    read-modify-write of the row ``forces[vertex, :4]`` (its fourth value gets ``+ 0``).

    forces: (n, 4) C-contiguous float; buf: 1D, the dtype of ``forces``; vertex, offsets: integers.
    """
    if not (_is_c_array(forces, 2) and isinstance(forces.dtype, types.Float) and _is_c_array(buf, 1)
            and buf.dtype == forces.dtype):
        return None
    sig = types.void(forces, vertex, buf, buf_offset, row_stride)

    def codegen(context, builder, signature, args):
        forces_arg, vertex_arg, buf_arg, buf_offset_arg, row_stride_arg = args
        forces_data = _data(context, builder, signature.args[0], forces_arg)
        buf_data = _data(context, builder, signature.args[2], buf_arg)
        float_type, size = _float_type(context, signature.args[0].dtype)
        vertex = _int64(context, builder, vertex_arg, signature.args[1])
        offset = _int64(context, builder, buf_offset_arg, signature.args[3])
        stride = _int64(context, builder, row_stride_arg, signature.args[4])
        _add_to_row(builder, forces_data, vertex, _row_from_values(builder, buf_data, offset, stride, float_type, size),
                    size)
        return context.get_dummy_value()

    return sig, codegen


# Lanes ``add_four_lanes_corner_forces`` adds at once.
SCATTER_LANES = 4
# None: ``add_four_lanes_corner_forces`` builds float64 rows by shuffles where
# ``float64_scatter_by_shuffles`` says so; True / False: always / never (the tests compile both ways
# on any host: both add the same bits on every target).
SCATTER_FLOAT64_BY_SHUFFLES = None


def float64_scatter_by_shuffles(context):
    """Whether the CPU that Numba's ``context`` compiles for is an AMD Zen 4 or 5 (``znver4``,
    ``znver5``), where the scatter built its float64 corner rows faster by shuffles than value by
    value: the 100k beam's blocks, one thread, 3.3-4.1 against 4.1-5.3 ns a tet, the step 1.09-1.10x
    (``benchmarks.phases``, three alternating pairs of processes, 2-core AMD EPYC with AVX-512).  On
    an AVX-512 Xeon the shuffles took 3.81 against 3.02 ns; Zen 3 was not measured."""
    cpu_name = getattr(context.codegen(), "_get_host_cpu_name", binding.get_host_cpu_name)()
    return cpu_name in ("znver4", "znver5")


@intrinsic
def add_four_lanes_corner_forces(typingctx, forces, tets, tet_offset, buf, buf_offset, row_stride):
    """``add_corner_force`` for ``SCATTER_LANES`` consecutive lanes and the 4 corners of each, in
    that order (lane after lane, corner after corner: the same sums, bit for bit):
    ``forces[tets.flat[tet_offset + c * row_stride + l], k] += buf[buf_offset + (3 c + k) * row_stride + l]``
    for lanes l < 4, corners c < 4, k < 3.

    In float32 each corner's x, y and z rows of the 4 lanes are read as three vectors and turned
    into the 4 lanes' rows ``(x, y, z, 0)`` by 8 shuffles instead of being built value by value
    from 12 scalar loads: the scatter of a 100k beam's blocks, one thread, 2.13 against 2.63 ns a
    tet; the step, against one lane at a time, one process, 2 threads, 1.05x at 100k tets and
    1.04x at 1M, one thread 1.09x at 100k.  In float64 the last of those shuffles, of 4 doubles,
    cross the 128-bit halves of a register, which costs a Xeon more than building the rows value
    by value as ``add_corner_force`` does, and an AMD Zen 4 less (``float64_scatter_by_shuffles``).
    forces: (n, 4) C-contiguous float; tets: C-contiguous uint32 (``BlockLayout.tets``); buf: 1D,
    the dtype of ``forces``; offsets, stride: integers, ``row_stride`` both the distance between a
    lane's corners in ``tets`` and between rows of lanes in ``buf`` (``BLOCK`` in both).
    """
    if not (_is_c_array(forces, 2) and isinstance(forces.dtype, types.Float) and _is_c_array(buf, 1)
            and buf.dtype == forces.dtype and isinstance(tets, types.Array) and tets.layout == "C"
            and tets.dtype == types.uint32):
        return None
    sig = types.void(forces, tets, tet_offset, buf, buf_offset, row_stride)

    def codegen(context, builder, signature, args):
        forces_arg, tets_arg, tet_offset_arg, buf_arg, buf_offset_arg, row_stride_arg = args
        forces_data = _data(context, builder, signature.args[0], forces_arg)
        tets_data = _data(context, builder, signature.args[1], tets_arg)
        buf_data = _data(context, builder, signature.args[3], buf_arg)
        i64 = ir.IntType(64)
        float_type, size = _float_type(context, signature.args[0].dtype)
        vector_type = ir.VectorType(float_type, FORCE_COLUMNS)
        tet_offset = _int64(context, builder, tet_offset_arg, signature.args[2])
        buf_offset = _int64(context, builder, buf_offset_arg, signature.args[4])
        stride = _int64(context, builder, row_stride_arg, signature.args[5])
        zero = _zero_row(float_type)
        by_shuffles = size == 4 or (float64_scatter_by_shuffles(context) if SCATTER_FLOAT64_BY_SHUFFLES is None
                                    else SCATTER_FLOAT64_BY_SHUFFLES)

        def row_offset(row, lane=0):
            return builder.add(buf_offset, builder.add(builder.mul(stride, ir.Constant(i64, row)),
                                                       ir.Constant(i64, lane)))

        lane_rows = []                  # lane_rows[c][l]: lane l's (x, y, z, 0) of corner c
        for c in range(4):
            if not by_shuffles:         # float64 off Zen 4: value by value (shuffles across halves)
                lane_rows.append([_row_from_values(builder, buf_data, row_offset(3 * c, lane), stride, float_type, size)
                                  for lane in range(SCATTER_LANES)])
                continue
            x, y, z = (builder.load(builder.bitcast(builder.gep(buf_data, [row_offset(3 * c + k)], inbounds=True),
                                                    vector_type.as_pointer()), align=size) for k in range(3))
            xy_even = _shuffle(builder, x, y, [0, 4, 2, 6])     # x0 y0 x2 y2
            xy_odd = _shuffle(builder, x, y, [1, 5, 3, 7])      # x1 y1 x3 y3
            z_even = _shuffle(builder, z, zero, [0, 4, 2, 6])   # z0 0 z2 0
            z_odd = _shuffle(builder, z, zero, [1, 5, 3, 7])    # z1 0 z3 0
            lane_rows.append([_shuffle(builder, xy_even, z_even, [0, 1, 4, 5]),
                              _shuffle(builder, xy_odd, z_odd, [0, 1, 4, 5]),
                              _shuffle(builder, xy_even, z_even, [2, 3, 6, 7]),
                              _shuffle(builder, xy_odd, z_odd, [2, 3, 6, 7])])
        for lane in range(SCATTER_LANES):
            for c in range(4):
                index = builder.add(tet_offset, builder.add(builder.mul(stride, ir.Constant(i64, c)),
                                                            ir.Constant(i64, lane)))
                vertex = builder.zext(builder.load(builder.gep(tets_data, [index], inbounds=True)), i64)
                _add_to_row(builder, forces_data, vertex, lane_rows[c][lane], size)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def prefetch_line(typingctx, a, index):
    """Hint the cache line holding element ``index`` (flat) of the C-contiguous array ``a`` into
    L2 (``llvm.prefetch``, read, locality ``PREFETCH_LOCALITY_L2``).  A hint: no load, no fault."""
    if not (isinstance(a, types.Array) and a.layout == "C" and isinstance(index, types.Integer)):
        return None
    sig = types.void(a, index)

    def codegen(context, builder, signature, args):
        a_arg, index_arg = args
        i8_ptr, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        address = builder.gep(_data(context, builder, signature.args[0], a_arg),
                              [_int64(context, builder, index_arg, signature.args[1])])
        prefetch = builder.module.globals.get(_PREFETCH) or ir.Function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8_ptr, i32, i32, i32]), _PREFETCH)
        builder.call(prefetch, [builder.bitcast(address, i8_ptr), ir.Constant(i32, 0),
                                ir.Constant(i32, PREFETCH_LOCALITY_L2), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


# The vector width LLVM's loop vectoriser may choose in a function that calls
# ``prefer_wide_vectors``: its "prefer-vector-width" attribute.
PREFERRED_VECTOR_BITS = 512


class _PreferredVectorWidth(FunctionAttributes):
    """A function's attributes plus ``"prefer-vector-width"``, which llvmlite has no word for."""

    def __bool__(self):
        return True

    def _to_list(self, ret_type):
        return super()._to_list(ret_type) + [f'"prefer-vector-width"="{PREFERRED_VECTOR_BITS}"']


@intrinsic
def prefer_wide_vectors(typingctx):
    """Let LLVM vectorise the loops of the calling function with ``PREFERRED_VECTOR_BITS``-bit
    vectors.  LLVM's tuning for Intel's AVX-512 cores (Skylake-X to Sapphire Rapids) prefers
    256-bit vectors to avoid lowering the clock, so the lane loops compiled to ymm on them (zmm on
    AMD Zen 4); a function attribute overrides the preference for that function only."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        function = builder.function
        if not isinstance(function.attributes, _PreferredVectorWidth):
            attributes = _PreferredVectorWidth()
            for name in function.attributes:
                attributes.add(name)
            attributes.alignstack = function.attributes.alignstack
            attributes.personality = function.attributes.personality
            function.attributes = attributes
        return context.get_dummy_value()

    return sig, codegen


# MXCSR bits (x86): FTZ, results below the smallest normal number are flushed to zero; DAZ, such
# inputs are read as zero.
MXCSR_FLUSH_SUBNORMALS = 0x8040


def _is_x86(context):
    triple = getattr(context.codegen(), "_tm", None)
    triple = triple.triple if triple is not None else binding.get_process_triple()
    return triple.startswith(("x86_64", "i686", "i386"))


def _mxcsr_function(builder, name):
    i8_ptr = ir.IntType(8).as_pointer()
    return builder.module.globals.get(name) or ir.Function(
        builder.module, ir.FunctionType(ir.VoidType(), [i8_ptr]), name)


@intrinsic
def flush_subnormals(typingctx):
    """Have this thread's floating-point unit treat subnormal numbers as zero (x86: set FTZ and DAZ
    in MXCSR); returns the previous control word for ``restore_float_control``.  Elsewhere a no-op
    returning 0.

    A subnormal (below 1.2e-38 in float32, 2.2e-308 in float64) costs an x86 core a microcode
    assist of about a hundred cycles per operation.  In an explicit step they appear at the
    front of a wave that has not yet crossed the mesh, where displacements decay element by
    element: on the 310k-tet beam in float32, steps 33-113 ran at 61-96 M tet-steps/s against 244
    once the wave had filled the beam.  Flushed, such a value changes nothing a float of that
    precision can hold next to the others."""
    sig = types.uint32()

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        if not _is_x86(context):
            return ir.Constant(i32, 0)
        slot = builder.alloca(i32)
        pointer = builder.bitcast(slot, ir.IntType(8).as_pointer())
        builder.call(_mxcsr_function(builder, "llvm.x86.sse.stmxcsr"), [pointer])
        old = builder.load(slot)
        builder.store(builder.or_(old, ir.Constant(i32, MXCSR_FLUSH_SUBNORMALS)), slot)
        builder.call(_mxcsr_function(builder, "llvm.x86.sse.ldmxcsr"), [pointer])
        return old

    return sig, codegen


@intrinsic
def restore_float_control(typingctx, control):
    """Restore the floating-point control word ``control`` that ``flush_subnormals`` returned
    (x86: MXCSR); elsewhere a no-op."""
    if not isinstance(control, types.Integer):
        return None
    sig = types.void(control)

    def codegen(context, builder, signature, args):
        if not _is_x86(context):
            return context.get_dummy_value()
        i32 = ir.IntType(32)
        slot = builder.alloca(i32)
        builder.store(builder.trunc(args[0], i32) if args[0].type.width > 32 else args[0], slot)
        builder.call(_mxcsr_function(builder, "llvm.x86.sse.ldmxcsr"),
                     [builder.bitcast(slot, ir.IntType(8).as_pointer())])
        return context.get_dummy_value()

    return sig, codegen
