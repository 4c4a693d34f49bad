"""The one place where softsim's Numba compilation flags live.

``njit`` compiles a serial function (inlined into its callers by LLVM where small);
``njit_inline`` one that LLVM always inlines (the bodies of loops that must vectorise, the step
driver's helpers);
``njit_parallel`` a driver whose ``prange`` loops run on Numba's thread pool.  ``njit`` and
``njit_parallel`` cache the machine code on disk (``cache=True``), so a second run does not
recompile (``njit_inline``'s code is cached inside its callers').  Every jitted function is a
module-level function: Numba cannot cache closures.

Numba checks a cached function only against its *own* source file, yet the machine code also
contains every jitted function it calls from other files (a driver in ``forces.py`` inlines the
material law of ``materials/models.py``).  Each cache entry is therefore also stamped with a hash
of the sources of the jitted packages: editing any of them recompiles instead of running stale code.
Entries are read and written under a lock on the cache folder, the data before the index that
names them (``_save_data_first``): several processes may fill one cache at once.
"""

import contextlib
import ctypes
import functools
import hashlib
import importlib.metadata
import itertools
import os

try:
    import fcntl
except ImportError:              # Windows: Numba's cache is used without locks
    fcntl = None

import llvmlite.binding
import numba
from numba import types
from numba.core import event
from numba.extending import typeof_impl

from . import compile_ahead

# ``fastmath={"contract"}`` lets LLVM fuse a multiply and an add into one FMA (one rounding instead of
# two) and nothing else: no reassociation, NaN and infinities kept.  Without it the lane loops of
# ``kernels.blocked`` compiled to separate packed multiplies and adds (StVK: 122 and 83 a vector of
# lanes; with it 66 FMAs, 47 multiplies): a block in L1 cache, one thread, StVK 4.19 -> 3.16 ns a
# tet, corotated 10.6 -> 9.15; the whole step (100k beam, 2 threads) StVK 1.08x.  LLVM fuses where
# it chooses, which need not be the same places in a packed loop as in a scalar function: the two
# agree to round-off, not bit for bit.  The same code gives the same bits on every run.
#
# ``no_cfunc_wrapper``: Numba otherwise compiles, beside each function, a C-ABI wrapper that only
# ``cfunc``-style callers (ctypes, a jitted function passed as a first-class value) use; softsim has
# none.  A cold run of the cantilever scene, fresh cache each, six pairs in turn: 0.89x the process
# time (medians; 0.91x the fastest of each), 38 MiB less peak memory.  The wrapper Python calls
# (``no_cpython_wrapper``) stays: without it a call from Python crashes the process.
JIT_OPTIONS = dict(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy", no_cfunc_wrapper=True)
# The same, not cached on disk: for helpers whose code lives on inside their cached callers.
UNCACHED_JIT_OPTIONS = {**JIT_OPTIONS, "cache": False}

# LLVM's loop vectoriser leaves a loop of fewer than 16 known iterations scalar when it would need
# a run-time check that two arrays do not overlap (its ``-vectorizer-min-trip-count``).  The float64
# lane loops of ``kernels.blocked`` run 8 iterations (a group of lanes whose rest rows are one cache
# line each) and read two arrays: softsim lowers the threshold to 8 for the process's LLVM.  It
# only lets such short loops be vectorised where the cost model finds it pays.
VECTORIZER_MIN_TRIP_COUNT = 8
llvmlite.binding.set_option("softsim", f"-vectorizer-min-trip-count={VECTORIZER_MIN_TRIP_COUNT}")

# Threading layer, chosen by measurement (beam, 2 threads, M tet-steps/s, medians of 5 timings per
# process, processes alternating; quiet machine / one core held by another process, two sessions
# of runs at 100k):
#                                         10k tets        100k tets
#   TBB                                   106 / 54        100-114 / 46-56
#   GNU OpenMP, OMP_WAIT_POLICY=passive    52 / 51         96-100 / 46-59
#   GNU OpenMP, spinning (its default)     an earlier run at 100k: 83 / 25
#   workqueue                              an earlier run at 100k: 37 / 32
# (``python -m benchmarks``, layers section, 100k quiet: TBB 117.8, passive OpenMP 101.4,
# workqueue 78.2.)
# When these were measured a step passed two parallel regions (one per colour; the steps of a
# call now share one region, ``integrators.symplectic_euler.PartSchedule``); an empty
# region costs 1.2 us with TBB or a spinning OpenMP, 47 us with a passive OpenMP, whose threads
# sleep in the kernel between regions.  A spinning OpenMP collapses when another process holds a
# core; TBB, which yields while it waits, does not.  TBB comes from pip's ``tbb`` wheel (a
# dependency); the GNU OpenMP of Numba's wheel is the fallback where it does not load, with
# passive waits (libgomp reads the policy when it loads, at the first parallel call; a value
# already in the environment wins, as does NUMBA_THREADING_LAYER).
os.environ.setdefault("OMP_WAIT_POLICY", "passive")
numba.config.THREADING_LAYER_PRIORITY = ["tbb", "omp", "workqueue"]

# The names of the TBB runtime Numba's TBB layer loads (``numba.np.ufunc.parallel``).
_TBB_LIBRARIES = ("libtbb.so.12", "libtbb.12.dylib", "tbb12.dll")


def _preload_tbb():
    """Load the TBB runtime of pip's ``tbb`` wheel by its path, if it is installed.

    The wheel puts ``libtbb.so.12`` in ``<prefix>/lib``, which the dynamic loader does not search
    in a virtual environment, so Numba does not find it (numba/numba#9740).  Loaded once by path,
    it is then found by name.  Without the wheel (or where it fails to load) Numba falls back to
    the next layer of ``THREADING_LAYER_PRIORITY``.  Returns whether it loaded.
    """
    try:
        files = importlib.metadata.files("tbb") or ()
    except importlib.metadata.PackageNotFoundError:
        return False
    for file in files:
        if file.name in _TBB_LIBRARIES:
            try:
                ctypes.CDLL(str(file.locate()))
            except OSError:
                return False
            return True
    return False


_TBB_LOADED = _preload_tbb()


def threading_layer():
    """The Numba threading layer parallel regions run on: ``numba.threading_layer()`` once one has
    run; before that ``"tbb"`` where its runtime loaded and no other layer was asked for (Numba's
    first choice then), else ``"other"``."""
    try:
        return numba.threading_layer()
    except ValueError:                    # no parallel region has run yet
        asked = numba.config.THREADING_LAYER in ("default", "tbb", "safe", "threadsafe")
        return "tbb" if _TBB_LOADED and asked else "other"


_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# The packages whose functions are jitted or inlined into jitted code; editing the orchestration,
# config, mesh or report modules must not recompile the kernels.
_JITTED_PACKAGES = ("kernels", "materials", "integrators")


def _walk_jitted_sources():
    for package in _JITTED_PACKAGES:
        yield from os.walk(os.path.join(_PACKAGE_DIR, package))


def _package_source_hash():
    """SHA-256 over the relative paths and contents of the ``.py`` files of ``_JITTED_PACKAGES``."""
    digest = hashlib.sha256()
    for root, dirs, files in _walk_jitted_sources():
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(f for f in files if f.endswith(".py")):
            path = os.path.join(root, name)
            digest.update(os.path.relpath(path, _PACKAGE_DIR).encode())
            with open(path, "rb") as f:
                digest.update(f.read())
    return digest.hexdigest()


_SOURCE_HASH = _package_source_hash()
# The file in each cache folder (a ``__pycache__`` of softsim's, or under NUMBA_CACHE_DIR) whose
# lock orders the reading and writing of cache entries between processes.
CACHE_LOCK_NAME = "softsim-numba-cache.lock"


@contextlib.contextmanager
def _cache_folder_lock(cache_file, exclusive):
    """Hold an advisory lock (``flock``) on the folder of a Numba cache file while inside: shared to
    read an entry, exclusive to write one.  Where locks are not to be had (no ``fcntl``, a folder
    not there yet or not writable), no lock."""
    try:
        fd = os.open(os.path.join(cache_file._cache_path, CACHE_LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o666)
    except (OSError, AttributeError):
        fd = None
    try:
        if fd is not None and fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        yield
    finally:
        if fd is not None:
            os.close(fd)


def _load_locked(cache_file, key):
    """``IndexDataCacheFile.load``, under the cache folder's shared lock."""
    with _cache_folder_lock(cache_file, exclusive=False):
        return type(cache_file).load(cache_file, key)


def _save_data_first(cache_file, key, data):
    """``IndexDataCacheFile.save``, under the cache folder's exclusive lock, writing the data file
    before the index that names it.

    Numba writes the index first and picks the data file's number from the index it has read: two
    processes saving entries of one function at once (the helper of ``compile_ahead`` and this
    process compiling a kernel both call, or two test workers) could both pick a number and leave
    the index naming a file holding the other's code, and a process stopped between the two writes
    an index naming a file of an older source (Numba overwrites stale data files only as it reuses
    their numbers).  Locked and in this order, an index only ever names complete data of its key."""
    with _cache_folder_lock(cache_file, exclusive=True):
        overloads = cache_file._load_index()
        data_name = overloads.get(key)
        if data_name is None:
            taken = set(overloads.values())
            data_name = next(name for name in map(cache_file._data_name, itertools.count(1)) if name not in taken)
        cache_file._save_data(data_name, data)
        if overloads.get(key) != data_name:
            overloads[key] = data_name
            cache_file._save_index(overloads)


# Numba's private names the two functions above use; where a Numba lacks them, its own are kept.
_CACHE_FILE_NAMES = ("_cache_path", "_load_index", "_data_name", "_save_data", "_save_index", "_source_stamp")


def _prepare_disk_cache(dispatcher):
    """Make ``dispatcher``'s on-disk cache stale whenever any softsim source file changes, and
    read and write its entries under a lock (``_load_locked``, ``_save_data_first``)."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    if cache_file is not None and all(hasattr(cache_file, name) for name in _CACHE_FILE_NAMES):
        cache_file._source_stamp = (cache_file._source_stamp, _SOURCE_HASH)
        cache_file.load = functools.partial(_load_locked, cache_file)
        cache_file.save = functools.partial(_save_data_first, cache_file)
    return dispatcher


def njit(func):
    """Compile ``func`` as a serial, cached Numba function."""
    return _prepare_disk_cache(numba.njit(**JIT_OPTIONS)(func))


def njit_inline(func):
    """Compile ``func`` as ``njit`` does, marked for LLVM to inline into every caller
    (``forceinline``: LLVM's ``alwaysinline`` attribute), whatever its size.

    For the bodies of loops that must vectorise: LLVM does not inline a callee it finds large, and
    a loop with a call in it stays scalar.  Inlined by LLVM rather than at Numba IR level
    (``inline="always"``), which re-ran Numba's front end and deep-copied the callee's IR at every
    call site, nested helpers at every level: corotated's lane loop compiled in 75-81 s that way
    and in 11.6 s this way, to the same instructions (1568 packed and 2369 scalar arithmetic ones,
    AVX2; ``benchmarks/NOTES.md``).

    Numba takes a reference to each array a function receives and releases it on return, atomic
    operations it prunes only where the function's branches let it; inlining by LLVM comes after
    that pruning.  A helper called per vertex or per tet must therefore keep its branches simple
    (scalars in and out: ``integrators.symplectic_euler.update_vertex``; a test checks its IR).

    Not cached on disk: its callers are, with its code inlined, so a run that loads them never
    compiles it.  Cached, it would share its cache entries with a cached ``njit`` twin of the same
    Python function (``mat3.mat3_mul`` and ``mat3.mat3_mul_inline``), Numba keying them by function
    and signature, not by options: whichever compiled first would be loaded for both, possibly
    without the attribute.
    """
    return numba.njit(forceinline=True, **UNCACHED_JIT_OPTIONS)(func)


def njit_parallel(func):
    """Compile ``func`` as a cached Numba function whose ``prange`` loops run in parallel.

    Compiling a parallel function costs more than a serial one, twice over: Numba types its body
    twice, the ``prange`` index as an int64 and then, in the parallel loop, as a uint64, so a
    jitted function called with the index is compiled for both.  The kernels pass it on as
    ``np.int64(index)`` (the step's vertex loop as a uint64, the type of its other vertex loop):
    one specialisation (tet_shapes, cold cache, 1.25-1.29 s against 1.71-1.95 s).  A pass that
    runs once per mesh, not per frame (its checks, its rest data), is compiled serially (``njit``)
    instead: the checks of a mesh compile in about half the time, and take at 2M tets 0.1 s more
    (sorted_face_triples 0.20 s against 0.12 s).  With both, a first run of the cantilever scene
    (a fresh cache each, seven pairs in turn) took 21.7 s against 24.8 s (medians, 0.82x pair by
    pair; 2-core AMD EPYC with AVX2, 2026-12-07)."""
    return _prepare_disk_cache(numba.njit(parallel=True, **JIT_OPTIONS)(func))


class CompileTimeConstant(int):
    """An int that a jitted function taking it compiles as a constant (Numba's ``IntegerLiteral``
    type): a specialisation per value, in which code branching on it at typing time (an
    ``overload`` with ``prefer_literal=True``) keeps only its own branch.  A plain int compiles
    one specialisation for every value."""

    def __repr__(self):
        return f"CompileTimeConstant({int(self)})"


@typeof_impl.register(CompileTimeConstant)
def _typeof_compile_time_constant(value, context):
    return _integer_literal(int(value))


@functools.cache
def _integer_literal(value):
    """Numba's ``IntegerLiteral`` type of ``value``, made once: making one types the value before
    Numba interns it, about 25 us, which every call of a kernel taking a ``CompileTimeConstant``
    paid in its dispatch (the guard's stable-step estimate makes two such calls an iteration)."""
    return types.IntegerLiteral(value)


class _FirstCompileListener(event.Listener):
    """Calls ``callback()`` when the first compile of a function starts, once."""

    def __init__(self, callback):
        self.callback = callback
        self.called = False

    def on_start(self, event):
        if not self.called:
            self.called = True
            self.callback()

    def on_end(self, event):
        pass


@contextlib.contextmanager
def on_first_compile(callback):
    """While inside, call ``callback()`` (no arguments) once, as Numba starts compiling the first
    function its disk cache does not hold; loading machine code from the cache calls nothing.
    (The CLI's notice that a first run compiles for a while.)"""
    with event.install_listener("numba:compile", _FirstCompileListener(callback)):
        yield


@contextlib.contextmanager
def compile_timer():
    """Time Numba spends compiling while inside (not loading machine code from its disk cache),
    and time waiting for a helper process compiling kernels (``compile_ahead.wait``): yields a
    function returning the seconds so far.  Nested compiles (a kernel and what it calls) count once."""
    listener = event.TimingListener()
    waited_before = compile_ahead.waited_seconds()
    with event.install_listener("numba:compile", listener):
        yield lambda: ((listener.duration if listener.done else 0.0)
                       + compile_ahead.waited_seconds() - waited_before)
