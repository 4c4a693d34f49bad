"""Compiling kernels in a helper process while this one works.

A first run compiles its kernels one after another: Numba compiles in one thread, under a lock
the whole process shares, so a second core sits idle.  The cantilever scene's first run took
about 40 s of compiling on a 2-core machine, its step (``advance_colour``) 9-13 s of it and the
guard's measure of the tets 4-5 s.  ``submit`` hands specialisations that Numba's disk cache
lacks to a helper process (``main``), which compiles them into that cache while this process
goes on compiling the others; ``wait(kernel)``, just before this process first calls ``kernel``,
blocks until the helper has compiled it, and the call then loads the machine code from the cache.
``compile_shared`` compiles a list of specialisations on both cores at once, the helper taking
them from the first and this process from the last, before any of them is called (``softsim
verify`` and ``softsim stability``, whose runs must not be timed beside a compiling helper).
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

import contextlib
import importlib
import os
import pickle
import subprocess
import sys
import threading
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
    order, writing ``DONE`` on its standard output as each is done; a thread here counts the reports
    (``reported``; the helper is then at item ``reported``, counting from 0).  Its standard input
    stays open while this process may want more: ``do_only`` shortens its work, ``release`` closes
    it (the helper then exits after its current item).  Raises ``OSError`` where it cannot be
    started or given its work."""

    def __init__(self, items):
        work = pickle.dumps(items)
        self.functions = [(module, qualname) for module, qualname, _ in items]
        self.reported = 0
        self.exited = False
        self._reports = threading.Condition()
        program = _HELPER_CODE.format(path=[str(p) for p in sys.path])
        self.process = subprocess.Popen([sys.executable, "-c", program], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            self.process.stdin.write(work)
            self.process.stdin.flush()
        except OSError:
            self.release()
            self.process.stdout.close()
            raise
        threading.Thread(target=self._count_reports, name="softsim-compile-ahead", daemon=True).start()

    def _count_reports(self):
        """Count the helper's reports until it exits (its output ends), then reap it."""
        try:
            for line in iter(self.process.stdout.readline, b""):
                with self._reports:
                    self.reported += line == DONE
                    self._reports.notify_all()
        except (OSError, ValueError):
            pass
        finally:
            self.process.stdout.close()
            self.process.wait()
            with self._reports:
                self.exited = True
                self._reports.notify_all()

    def items_through(self, dispatcher):
        """How many items must be done before ``dispatcher``'s are all done (0: none is its)."""
        function = (dispatcher.py_func.__module__, dispatcher.py_func.__qualname__)
        return max((k + 1 for k, item in enumerate(self.functions) if item == function), default=0)

    def wait(self, count):
        """Block until ``count`` items are done, or the helper has exited; returns whether it has
        nothing more to do for this process (then released)."""
        try:
            with self._reports:
                self._reports.wait_for(lambda: self.reported >= count or self.exited)
        except BaseException:
            self.release()
            raise
        if self.reported < count or self.reported >= len(self.functions):
            self.release()
            return True
        return False

    def do_only(self, count):
        """Have the helper compile only its first ``count`` items, and exit after them."""
        self.functions = self.functions[:count]
        try:
            self.process.stdin.write(b"%d\n" % count)
            self.process.stdin.flush()
        except (OSError, ValueError):       # exited, or released
            pass

    def release(self):
        """Stop giving the helper work: it exits after the item it is compiling."""
        with contextlib.suppress(OSError):
            self.process.stdin.close()


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
    """Compile ``calls`` (as ``submit``'s) that the disk cache lacks, each specialisation once, on
    two cores, now: a helper process takes them from the first (``submit``), this process from the
    last, until the two meet (their costs differ: 7 to 45 s for the step of ``softsim
    stability``'s scenes).  Returns once this process has done its share, the helper maybe still
    compiling its last one (``wait`` for it before calling the kernels); returns how many
    specialisations were compiled or handed over, 0 where no helper starts (``enabled``): then each
    compiles when first called, as it would have without this."""
    if not enabled():
        return 0
    lacking = {}
    for dispatcher, arguments in calls:
        signature = argument_types(dispatcher, arguments)
        if not is_compiled_or_cached(dispatcher, signature):
            lacking.setdefault((dispatcher, signature), arguments)
    if len(lacking) < 2 or not submit([(dispatcher, arguments) for (dispatcher, _), arguments in lacking.items()]):
        return 0
    helper, items = _helper, list(lacking)
    first_here = len(items)             # this process compiles items[first_here:]
    while first_here > 1 and helper.reported < first_here - 1 and not helper.exited:
        dispatcher, signature = items[first_here - 1]
        dispatcher.compile(signature)
        first_here -= 1
    helper.do_only(first_here)
    return len(items)


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


def _compile_items(items, report, wanted):
    """The helper's work: compile each ``(module, qualname, signature)`` of ``items`` that
    ``wanted(k)`` (k its index) when its turn comes, calling ``report()`` after each (compiled or
    not); stops at the first one not wanted."""
    for k, (module, qualname, signature) in enumerate(items):
        if not wanted(k):
            return
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
    A line ``N`` on its standard input after the items leaves it the first N items only; the end of
    its standard input (``_Helper.release``, or its parent gone) stops it after its current item,
    as does nobody reading its reports."""
    items = pickle.load(sys.stdin.buffer)
    limit = [len(items)]                # a list: set by the thread below

    def read_limits():
        for line in sys.stdin.buffer:
            limit[0] = min(limit[0], int(line))
        limit[0] = 0

    threading.Thread(target=read_limits, daemon=True).start()
    reports = os.fdopen(os.dup(sys.stdout.fileno()), "wb", buffering=0)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    from numba.core import entrypoints

    entrypoints.init_all()        # as a dispatcher's first call does, before it compiles

    def report():
        reports.write(DONE)

    try:
        _compile_items(items, report, lambda k: k < limit[0])
    except BrokenPipeError:
        pass
