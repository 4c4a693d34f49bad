"""The hand-written gather and scatter of ``kernels.simd`` against NumPy's fancy indexing and
``np.add.at``, bit for bit, in both precisions; and through ``kernels.blocked`` on a whole block.
The prefetch hint: what it compiles to, and that it changes nothing.  The subnormal flush."""

import ctypes
import mmap
import platform
import subprocess
import sys

import numba
import numpy as np
import pytest

from softsim.kernels import simd
from softsim.kernels.blocked import BLOCK, ROW_F, ROW_X, ROWS, gather_corners, scatter_block
from softsim.kernels.jit import njit
from softsim.kernels.simd import (
    FORCE_COLUMNS,
    PREFERRED_VECTOR_BITS,
    add_corner_force,
    flush_subnormals,
    gather_corner_rows,
    prefer_wide_vectors,
    prefetch_line,
    restore_float_control,
)


@njit
def gather_rows(x, tets, tet_offset, buf, buf_offset):
    gather_corner_rows(x, tets, tet_offset, buf, buf_offset, 32, False)


@njit
def gather_whole_rows(x, tets, tet_offset, buf, buf_offset):
    gather_corner_rows(x, tets, tet_offset, buf, buf_offset, 32, True)


@njit
def add_forces(forces, vertices, buf, row_stride):
    for j in range(vertices.shape[0]):
        add_corner_force(forces, vertices[j], buf, j, row_stride)


def gather_rows_compiled(monkeypatch, by_transpose, whole_rows=False):
    """A fresh ``gather_rows`` (``gather_whole_rows``) whose gather compiles one way or the other
    (both are correct on every target; ``simd.gather_by_transpose`` picks the faster one)."""
    monkeypatch.setattr(simd, "GATHER_BY_TRANSPOSE", by_transpose)
    return numba.njit((gather_whole_rows if whole_rows else gather_rows).py_func)


@pytest.mark.parametrize("whole_rows", [False, True])
@pytest.mark.parametrize("by_transpose", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_gather_corner_rows_is_fancy_indexing(dtype, by_transpose, whole_rows, monkeypatch):
    gather = gather_rows_compiled(monkeypatch, by_transpose, whole_rows)
    rng = np.random.default_rng(1)
    x = rng.standard_normal((50, 3)).astype(dtype)
    last = 48 if whole_rows else 49              # whole rows: the caller keeps off x's last row
    tets = rng.integers(0, last, size=(3, 40)).astype(np.uint32)
    tets.reshape(-1)[60] = last                  # masked: the last vertex, whose row ends the array
    buf = np.full(200, np.nan, dtype=dtype)
    gather(x, tets, 45, buf, 7)                  # lanes 45..76 of the flat tets, from buf[7]
    lanes = tets.reshape(-1)[45:77]
    expected = x[lanes].T                        # (3, 32): row k holds component k
    np.testing.assert_array_equal(buf[7:7 + 96].reshape(3, 32), expected)
    assert np.isnan(buf[:7]).all() and np.isnan(buf[7 + 96:]).all()     # nothing written outside


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_add_corner_force_is_add_at(dtype):
    rng = np.random.default_rng(2)
    n, count, stride = 20, 300, 301
    vertices = rng.integers(0, n, size=count)    # many repeats: each must accumulate in order
    buf = rng.standard_normal(3 * stride).astype(dtype)
    start = rng.standard_normal((n, 3)).astype(dtype)
    forces = np.zeros((n, FORCE_COLUMNS), dtype=dtype)
    forces[:, :3] = start
    add_forces(forces, vertices, buf, stride)
    expected = start.copy()
    for k in range(3):                           # np.add.at sums in index order, like the scatter
        np.add.at(expected[:, k], vertices, buf[k * stride:k * stride + count])
    np.testing.assert_array_equal(forces[:, :3], expected)
    assert not forces[:, 3].any()


@njit
def add_four_lanes(forces, tets, tet_offset, buf, buf_offset, row_stride):
    simd.add_four_lanes_corner_forces(forces, tets, tet_offset, buf, buf_offset, row_stride)


@pytest.mark.parametrize("by_shuffles", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_four_lanes_add_their_corner_forces_lane_by_lane(dtype, by_shuffles, monkeypatch):
    """Four lanes' corner rows built by shuffles or value by value (float64 picks by host,
    ``simd.float64_scatter_by_shuffles``; float32 always shuffles) add the same bits as a loop over
    the lanes and their corners, into rows that several corners share."""
    monkeypatch.setattr(simd, "SCATTER_FLOAT64_BY_SHUFFLES", by_shuffles)
    add = numba.njit(add_four_lanes.py_func)          # compiled afresh, the chosen way
    rng = np.random.default_rng(4)
    n, stride, tet_offset, buf_offset = 6, 9, 3, 5
    tets = rng.integers(0, n, size=4 * stride).astype(np.uint32)
    buf = rng.standard_normal(12 * stride + 8).astype(dtype)
    forces = np.zeros((n, FORCE_COLUMNS), dtype=dtype)
    forces[:, :3] = rng.standard_normal((n, 3))
    expected = forces[:, :3].copy()
    for lane in range(4):
        for c in range(4):
            expected[tets[tet_offset + c * stride + lane]] += buf[buf_offset + (3 * c + np.arange(3)) * stride + lane]
    add(forces, tets, tet_offset, buf, buf_offset, stride)
    np.testing.assert_array_equal(forces[:, :3], expected)
    assert not forces[:, 3].any()


@pytest.mark.parametrize("lane_count", [BLOCK, BLOCK - 5, 3])
@pytest.mark.parametrize("uses_last_row", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_block_gather_and_scatter(dtype, uses_last_row, lane_count):
    """A block off x's last row gathers whole rows, one on it masked ones: both as fancy indexing.
    The scatter adds ``SCATTER_LANES`` lanes at a time and the rest lane by lane (a block of a
    multiple of them, one with some left over, one with only those), in the order of a loop over
    lanes and corners: the same bits (100 vertices, many used by several corners)."""
    rng = np.random.default_rng(3)
    n = 100
    x = rng.standard_normal((n, 3)).astype(dtype)
    block_tets = rng.integers(0, n - 1, size=(2, 4, BLOCK)).astype(np.uint32)
    if uses_last_row:
        block_tets[1, 2, 17] = n - 1
    buf = rng.standard_normal(ROWS * BLOCK).astype(dtype)
    whole_rows = bool(block_tets[1].max() < n - 1)          # as ``BlockLayout.whole_rows`` has it
    assert whole_rows is not uses_last_row
    gather_corners(x, block_tets, 1, buf, whole_rows)
    for c in range(4):
        gathered = buf[(ROW_X + 3 * c) * BLOCK:(ROW_X + 3 * c + 3) * BLOCK].reshape(3, BLOCK)
        np.testing.assert_array_equal(gathered, x[block_tets[1, c]].T)
    forces = np.zeros((n, FORCE_COLUMNS), dtype=dtype)
    scatter_block(block_tets, 1, lane_count, buf, forces)
    expected = np.zeros((n, 3), dtype=dtype)
    for j in range(lane_count):                  # lane by lane, corner by corner: the scatter's order
        for c in range(4):
            expected[block_tets[1, c, j]] += buf[(ROW_F + 3 * c + np.arange(3)) * BLOCK + j]
    np.testing.assert_array_equal(forces[:, :3], expected)
    assert not forces[:, 3].any()


def array_ending_at_a_guard_page(values):
    """A copy of the 1D array ``values`` whose last byte is the last of a page followed by a page
    that may not be read (Linux ``mprotect``): a read past its end faults."""
    page = mmap.PAGESIZE
    pages = mmap.mmap(-1, 2 * page, prot=mmap.PROT_READ | mmap.PROT_WRITE)
    start = ctypes.addressof(ctypes.c_char.from_buffer(pages))
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    if libc.mprotect(start + page, page, 0) != 0:            # PROT_NONE
        pytest.skip(f"mprotect failed: errno {ctypes.get_errno()}")
    out = np.frombuffer(pages, dtype=values.dtype, count=values.size, offset=page - values.nbytes)
    out[...] = values
    return out


def gather_at_a_guard_page(dtype):
    """Gather a block that uses x's last row, that row ending where the readable memory ends."""
    rng = np.random.default_rng(4)
    n = 40
    x = array_ending_at_a_guard_page(rng.standard_normal(3 * n).astype(dtype)).reshape(n, 3)
    block_tets = rng.integers(0, n, size=(1, 4, BLOCK)).astype(np.uint32)
    block_tets[0, 3, BLOCK - 1] = n - 1
    buf = np.zeros(ROWS * BLOCK, dtype=dtype)
    gather_corners(x, block_tets, 0, buf)
    for c in range(4):
        gathered = buf[(ROW_X + 3 * c) * BLOCK:(ROW_X + 3 * c + 3) * BLOCK].reshape(3, BLOCK)
        np.testing.assert_array_equal(gathered, x[block_tets[0, c]].T)


@pytest.mark.skipif(platform.system() != "Linux", reason="the guard page uses Linux's mprotect")
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_block_gather_never_reads_past_x(dtype):
    """The block that uses x's last row must not load the row's fourth value: with x ending at a
    page that may not be read, that load would fault.  Run in a child process, so that a fault
    fails this test rather than ending the test run."""
    done = subprocess.run([sys.executable, __file__, "gather_at_a_guard_page", dtype], capture_output=True, text=True)
    assert done.returncode == 0, f"exit status {done.returncode}: {done.stderr[-2000:]}"


def test_wrong_widths_are_refused():
    """The intrinsics assume 3 columns of positions and ``FORCE_COLUMNS`` of forces: the block
    functions refuse other widths instead of reading or writing the wrong rows."""
    block_tets = np.zeros((1, 4, BLOCK), dtype=np.uint32)
    buf = np.zeros(ROWS * BLOCK)
    with pytest.raises(ValueError, match="3 columns"):
        gather_corners(np.zeros((5, 4)), block_tets, 0, buf)
    with pytest.raises(ValueError, match="FORCE_COLUMNS"):
        scatter_block(block_tets, 0, BLOCK, buf, np.zeros((5, 3)))


@numba.njit          # not cached: Numba inspects only freshly compiled code
def prefetch_every_line(a, line):
    for e in range(0, a.size, line):
        prefetch_line(a, e)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_prefetch_line_is_an_l2_prefetch_and_nothing_else(dtype):
    """``prefetch_line`` compiles to a prefetch into L2 (``prefetcht1`` on x86-64) and leaves the
    array as it was."""
    a = np.arange(4 * 10 * 16, dtype=dtype).reshape(4, 10, 16)
    before = a.copy()
    prefetch_every_line(a, 64 // a.itemsize)
    np.testing.assert_array_equal(a, before)
    if platform.machine() in ("x86_64", "AMD64"):
        asm = prefetch_every_line.inspect_asm(prefetch_every_line.signatures[-1])
        assert "prefetcht1" in asm
        assert not any(f"prefetch{kind}\t" in asm for kind in ("t0", "t2", "nta"))


def test_prefetch_line_takes_only_contiguous_arrays():
    with pytest.raises(numba.TypingError):
        prefetch_every_line(np.zeros((10, 16))[:, ::2], 8)


def test_the_step_prefetches_first_used_vertex_rows_only_when_asked():
    """``blocked.prefetch_vertex_rows`` compiles to L2 prefetches of the rows of ``x`` and of the
    vertex forces when the layout prefetches (an int: how far ahead), and to nothing at all when
    it does not (None: Numba prunes the loop), and leaves the arrays as they were."""
    from softsim.kernels.blocked import prefetch_vertex_rows

    rows = numba.njit(prefetch_vertex_rows.py_func)         # a fresh dispatcher: its machine code can be read
    x, forces = np.ones((6, 3)), np.ones((6, FORCE_COLUMNS))
    first_offsets, first_vertices = np.array([0, 2, 3, 5]), np.array([0, 4, 1, 2, 5], dtype=np.uint32)
    for ahead in (1, None):
        rows(x, forces, first_offsets, first_vertices, 0, ahead)
    assert (x == 1).all() and (forces == 1).all()
    if platform.machine() in ("x86_64", "AMD64"):
        with_ahead, without = (rows.inspect_asm(sig) for sig in rows.signatures)
        assert with_ahead.count("prefetcht1") >= 2
        assert "prefetcht" not in without


@pytest.mark.skipif(platform.system() != "Linux", reason="maps a guard page with Linux's mmap and mprotect")
@pytest.mark.parametrize("by_transpose", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_gather_reads_nothing_past_the_last_vertex(dtype, by_transpose, monkeypatch):
    """The last vertex's row ends where unreadable memory begins (a guard page): the transposing
    gather loads rows of four values with the fourth masked off, so it neither faults there nor
    reads past ``x`` (a fault would end the test process)."""
    import ctypes
    import mmap

    gather = gather_rows_compiled(monkeypatch, by_transpose)
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mmap.restype = ctypes.c_void_p
    libc.mmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long]
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    libc.munmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t]
    page = mmap.PAGESIZE
    base = libc.mmap(None, 2 * page, mmap.PROT_READ | mmap.PROT_WRITE, mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS, -1, 0)
    assert base not in (None, ctypes.c_void_p(-1).value)
    try:
        assert libc.mprotect(base + page, page, 0) == 0        # PROT_NONE
        n = 20
        nbytes = n * 3 * np.dtype(dtype).itemsize
        x = np.frombuffer((ctypes.c_char * nbytes).from_address(base + page - nbytes), dtype=dtype).reshape(n, 3)
        x[...] = np.arange(3 * n).reshape(n, 3)
        tets = np.full((1, 32), n - 1, dtype=np.uint32)
        tets[0, ::3] = 0
        buf = np.zeros(96, dtype=dtype)
        gather(x, tets, 0, buf, 0)
        np.testing.assert_array_equal(buf.reshape(3, 32), x[tets[0]].T)
    finally:
        libc.munmap(base, 2 * page)


def _axpy_loop(a, b, out):
    for i in range(out.size):
        out[i] = a[i] * b[i] + out[i]


def _wide_axpy_loop(a, b, out):
    prefer_wide_vectors()
    for i in range(out.size):
        out[i] = a[i] * b[i] + out[i]


def test_prefer_wide_vectors_lets_the_vectoriser_use_the_widest_registers():
    """A function calling ``prefer_wide_vectors`` carries LLVM's ``"prefer-vector-width"="512"``
    attribute (one that does not, none), and on a host with AVX-512 its loop compiles to zmm
    registers, where LLVM's tuning for Intel's AVX-512 cores would otherwise keep it to ymm."""
    from llvmlite import binding

    plain, wide = numba.njit(_axpy_loop), numba.njit(_wide_axpy_loop)     # fresh: their code can be read
    a, b = np.arange(100.0), np.full(100, 2.0)
    results = []
    for fn in (plain, wide):
        out = np.ones(100)
        fn(a, b, out)
        results.append(out)
    np.testing.assert_array_equal(results[0], results[1])
    np.testing.assert_array_equal(results[1], 2 * a + 1)
    attribute = f'"prefer-vector-width"="{PREFERRED_VECTOR_BITS}"'
    assert attribute in wide.inspect_llvm(wide.signatures[0])
    assert "prefer-vector-width" not in plain.inspect_llvm(plain.signatures[0])
    if "+avx512f" in binding.get_host_cpu_features().flatten():
        assert "zmm" in wide.inspect_asm(wide.signatures[0])


@njit
def _products(x, y, out, flushed):
    """``out = x * y``, with subnormals flushed to zero where ``flushed``; returns the float control
    word before and after."""
    before = flush_subnormals()
    if not flushed:
        restore_float_control(before)
    for i in range(x.size):
        out[i] = x[i] * y[i]
    if flushed:
        restore_float_control(before)
    after = flush_subnormals()
    restore_float_control(after)
    return before, after


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_flush_subnormals_zeroes_subnormal_results_until_restored(dtype):
    """Between ``flush_subnormals`` and ``restore_float_control`` a product below the smallest normal
    number is zero (on x86; elsewhere both are no-ops); normal products are untouched; and the
    thread's control word is what it was before."""
    tiny = np.sqrt(np.finfo(dtype).tiny).astype(dtype) / dtype(4)     # tiny^2 / 16: subnormal
    x = np.array([tiny, 1.5, -tiny], dtype=dtype)
    y = np.array([tiny, 2.0, tiny], dtype=dtype)
    plain, flushed = np.empty_like(x), np.empty_like(x)
    _products(x, y, plain, False)
    before, after = _products(x, y, flushed, True)
    assert before == after
    np.testing.assert_array_equal(plain, x * y)
    assert plain[0] != 0 and plain[0] < np.finfo(dtype).tiny
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert flushed.tolist() == [0.0, 3.0, 0.0]
    else:
        np.testing.assert_array_equal(flushed, plain)


if __name__ == "__main__":          # test_block_gather_never_reads_past_x's child process
    globals()[sys.argv[1]](np.dtype(sys.argv[2]))
