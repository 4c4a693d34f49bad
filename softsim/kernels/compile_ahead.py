"""Compiling a kernel in a helper process while this one works.

A first run compiles its kernels one after another: Numba compiles in one thread, under a lock
the whole process shares, so a second core sits idle.  The cantilever scene's first run took
about 40 s of compiling on a 2-core machine, its step (``advance_colour``) 9-13 s of it.
``submit`` hands specialisations that Numba's disk cache lacks to a helper process (``main``),
which compiles them into that cache while this process goes on compiling the others; ``wait``, just before this process first calls one of them, blocks until
the helper is done, and the call then loads the machine code from the cache.  The machine code is
the same either way: the helper imports the same modules (and so sets the same LLVM options,
``kernels.jit``) and compiles each function for the same argument types.

Nothing depends on the helper: if it cannot start, fails or dies, this process compiles what it
lacks itself, as it would have without it.  Set ``SOFTSIM_COMPILE_AHEAD=0`` to never start one;
none starts where only one core is available.
"""

import atexit
import importlib
import os
import pickle
import subprocess
import sys
import time

# ``SOFTSIM_COMPILE_AHEAD=0`` in the environment: never start a helper.
ENVIRONMENT_SWITCH = "SOFTSIM_COMPILE_AHEAD"


# Where this process imported softsim from: the helper imports the same files (``python -m``
# would put the working folder first, which may hold another softsim than the one installed).
_IMPORT_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_HELPER_CODE = "import sys; sys.path.insert(0, {path!r}); from softsim.kernels.compile_ahead import main; main()"


class _Helper:
    """A helper process compiling ``count`` specialisations, reporting a line on its standard
    output as each is done."""

    def __init__(self, items):
        self.count = len(items)
        self.reported = 0
        self.process = subprocess.Popen([sys.executable, "-c", _HELPER_CODE.format(path=_IMPORT_ROOT)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        try:
            self.process.stdin.write(pickle.dumps(items))
            self.process.stdin.close()
        except OSError:          # it died at once; whatever it did not compile, the caller will
            self.stop()

    def wait(self):
        """Block until every item is reported, or the helper has exited."""
        while self.reported < self.count and self.process.stdout.readline():
            self.reported += 1
        self.stop()

    def stop(self):
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        self.process.stdout.close()


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
    """The signature ``dispatcher`` compiles for a call with ``arguments`` (a tuple)."""
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
    tuple of arguments of the types it will be called with), in a helper process, those the disk
    cache lacks; returns how many were handed over (0: none lacking, or no helper allowed, or one
    already running).  Call ``wait`` before calling any of them."""
    global _helper
    if _helper is not None or not enabled():
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


def wait():
    """Block until the helper (if one is running) has compiled what it was given; the seconds
    waited count in ``waited_seconds``.  Returns at once when no helper runs."""
    global _helper, _waited_s
    if _helper is None:
        return
    started = time.perf_counter()
    try:
        _helper.wait()
    finally:
        _helper = None
        _waited_s += time.perf_counter() - started


def waited_seconds():
    """Seconds this process has spent in ``wait`` (``jit.compile_timer`` counts them as compiling)."""
    return _waited_s


@atexit.register
def _stop_helper():
    if _helper is not None:
        _helper.stop()


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
    items = pickle.loads(sys.stdin.buffer.read())

    def report():
        sys.stdout.write("compiled\n")
        sys.stdout.flush()

    _compile_items(items, report)


