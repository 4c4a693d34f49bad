"""Compiling kernels in a helper process while this one works.

A first run compiles its kernels one after another: Numba compiles in one thread, under a lock
the whole process shares, so a second core sits idle.  The cantilever scene's first run took
about 40 s of compiling on a 2-core machine, its step (``advance_colour``) 9-13 s of it and the
guard's measure of the tets 4-5 s.  ``submit`` hands specialisations that Numba's disk cache
lacks to a helper process (``main``), which compiles them into that cache while this process
goes on compiling the others; ``wait(kernel)``, just before this process first calls ``kernel``,
blocks until the helper has compiled it, and the call then loads the machine code from the cache.
The machine code is the same either way: the helper imports the same modules from the same
``sys.path`` (and so sets the same LLVM options, ``kernels.jit``), loads Numba's extensions as a
first call does, and compiles each function for the same argument types.  Both processes write
the cache under a lock (``kernels.jit._save_data_first``).

Nothing depends on the helper: if it cannot start, fails or dies, this process compiles what it
lacks itself, as it would have without it.  The helper is never killed (a process stopped while
it writes a cache entry could leave the entry half written): when this process stops waiting for
it, or exits, the helper finishes the kernel it is compiling and then exits too.  It runs in a
session of its own, so that a Ctrl-C, which asks a run to stop after its frame, does not stop it
mid-write.  Set ``SOFTSIM_COMPILE_AHEAD=0`` to never start one; none starts where only one core
is available.
"""

import importlib
import os
import pickle
import subprocess
import sys
import time

# ``SOFTSIM_COMPILE_AHEAD=0`` in the environment: never start a helper.
ENVIRONMENT_SWITCH = "SOFTSIM_COMPILE_AHEAD"
# The line the helper writes as each item is done.
DONE = b"compiled\n"
# The helper's program: this process's import path first (``python -c`` would put the working
# folder first, which may hold another softsim than the one this process imported).
_HELPER_CODE = "import sys; sys.path[:] = {path!r}; from softsim.kernels.compile_ahead import main; main()"


class _Helper:
    """A helper process compiling ``items``, ``[(module, qualname, signature), ...]``, in their
    order, writing ``DONE`` on its standard output as each is done.  Raises ``OSError`` where it
    cannot be started or given its work."""

    def __init__(self, items):
        work = pickle.dumps(items)
        self.functions = [(module, qualname) for module, qualname, _ in items]
        self.reported = 0
        program = _HELPER_CODE.format(path=[str(p) for p in sys.path])
        self.process = subprocess.Popen([sys.executable, "-c", program], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            self.process.stdin.write(work)
            self.process.stdin.close()
        except OSError:
            self.release()
            raise

    def items_through(self, dispatcher):
        """How many items must be done before ``dispatcher``'s are all done (0: none is its)."""
        function = (dispatcher.py_func.__module__, dispatcher.py_func.__qualname__)
        return max((k + 1 for k, item in enumerate(self.functions) if item == function), default=0)

    def wait(self, count):
        """Block until ``count`` items are done, or the helper has exited; returns whether it has
        nothing more to do for this process (then released)."""
        try:
            while self.reported < count:
                line = self.process.stdout.readline()
                if not line:
                    break
                self.reported += line == DONE
        except BaseException:
            self.release()
            raise
        if self.reported < count or self.reported == len(self.functions):
            self.release()
            return True
        return False

    def release(self):
        """Stop listening: a helper with nothing left exits; one still compiling finishes its
        current item and exits when it finds nobody reading its reports."""
        self.process.stdout.close()
        if self.reported == len(self.functions):
            self.process.wait()


_helper = None
_waited_s = 0.0


def available_cores():
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:       # not on Linux
        return os.cpu_count() or 1


def enabled():
    """Whether a helper may start: more than one core, and not switched off (``ENVIRONMENT_SWITCH``)."""
    return os.environ.get(ENVIRONMENT_SWITCH, "1") != "0" and available_cores() > 1


def argument_types(dispatcher, arguments):
    """The signature ``dispatcher`` compiles for a call with ``arguments`` (a tuple): the types
    its own ``typeof_pyval`` gives them, as a call does."""
    return tuple(dispatcher.typeof_pyval(a) for a in arguments)


def is_compiled_or_cached(dispatcher, signature):
    """Whether a call of ``dispatcher`` with ``signature`` would compile nothing: compiled in this
    process already, or in Numba's disk cache.  Reads Numba's cache index through its private
    names; where those are not there, says True (then nothing is compiled ahead)."""
    if signature in dispatcher.overloads:
        return True
    try:
        cache = dispatcher._cache
        key = cache._index_key(signature, dispatcher.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:            # another Numba's private names: do not guess
        return True


def submit(calls):
    """Compile ``calls``, ``[(dispatcher, arguments), ...]`` (each a cached jitted function and a
    tuple of arguments of the types it will be called with), those the disk cache lacks, in a
    helper process, in their order; a helper given work before is released first (``release``).
    Returns how many were handed over (0: none lacking, or no helper allowed or started).  Call
    ``wait(dispatcher)`` before calling any of them."""
    global _helper
    release()
    if not enabled():
        return 0
    items = []
    for dispatcher, arguments in calls:
        signature = argument_types(dispatcher, arguments)
        if not is_compiled_or_cached(dispatcher, signature):
            items.append((dispatcher.py_func.__module__, dispatcher.py_func.__qualname__, signature))
    if not items:
        return 0
    try:
        _helper = _Helper(items)
    except OSError:
        return 0
    return len(items)


def compile_shared(calls):
    """Compile ``calls`` (as ``submit``'s) that the disk cache lacks, each specialisation once: half
    in a helper process (``submit``), the other half, and the odd one, in this process, now (the
    helper starts later and was slower per item: 13.8 against 11.9 s for ``softsim verify``'s
    steps).  Returns once this process has compiled its share, the helper maybe still compiling
    (``wait`` for it before calling the kernels), how many specialisations were compiled or handed
    over; 0 where no helper starts (``enabled``): then each compiles when first called, as it
    would have without this."""
    if not enabled():
        return 0
    lacking = {}
    for dispatcher, arguments in calls:
        signature = argument_types(dispatcher, arguments)
        if not is_compiled_or_cached(dispatcher, signature):
            lacking.setdefault((dispatcher, signature), arguments)
    handed_over = [(dispatcher, arguments) for (dispatcher, _), arguments in lacking.items()]
    if not submit(handed_over[1::2]):
        return 0
    for dispatcher, signature in list(lacking)[::2]:
        dispatcher.compile(signature)
    return len(lacking)


def wait(dispatcher=None):
    """Block until the helper (if one runs) has compiled what it was given for ``dispatcher`` (a
    jitted function; None: everything it was given); the seconds waited count in
    ``waited_seconds``.  Returns at once when no helper runs or it was given nothing of ``dispatcher``."""
    global _helper, _waited_s
    if _helper is None:
        return
    count = len(_helper.functions) if dispatcher is None else _helper.items_through(dispatcher)
    if count == 0:
        return
    started = time.perf_counter()
    finished = True
    try:
        finished = _helper.wait(count)
    finally:
        if finished:
            _helper = None
        _waited_s += time.perf_counter() - started


def release():
    """Stop waiting for the helper, if one runs (``_Helper.release``)."""
    global _helper
    if _helper is not None:
        _helper.release()
        _helper = None


def waited_seconds():
    """Seconds this process has spent in ``wait`` (``jit.compile_timer`` counts them as compiling)."""
    return _waited_s


def _compile_items(items, report):
    """The helper's work: compile each ``(module, qualname, signature)`` of ``items``, calling
    ``report()`` after each (compiled or not)."""
    for module, qualname, signature in items:
        function = importlib.import_module(module)
        for name in qualname.split("."):
            function = getattr(function, name)
        try:
            function.compile(signature)
        except Exception:        # the caller compiles it itself, and says what is wrong
            pass
        report()


def main():
    """The helper: reads the items pickled on its standard input, compiles them
    (``_compile_items``) and writes ``DONE`` to its standard output after each; anything else
    written to the standard output (Numba's debug output) goes to the standard error instead.
    Exits when nobody reads its reports any more."""
    items = pickle.loads(sys.stdin.buffer.read())
    reports = os.fdopen(os.dup(sys.stdout.fileno()), "wb", buffering=0)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    from numba.core import entrypoints

    entrypoints.init_all()        # as a dispatcher's first call does, before it compiles

    def report():
        reports.write(DONE)

    try:
        _compile_items(items, report)
    except BrokenPipeError:
        pass
