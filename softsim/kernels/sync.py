"""Atomic counters for threads that share one parallel region, written as LLVM IR (Numba's CPU
target has no atomics).

``integrators.symplectic_euler.advance`` runs all the steps of a call in one parallel region:
each thread waits, spinning, until every part of the previous colour is done (``load_acquire``
of a counter of parts done), then claims the colour's parts, its own first, one at a time
(``compare_exchange`` of a part's count of steps claimed: the first to raise it takes it).  A thread leaves a colour only
when each of its parts is claimed, so it never waits for work nobody has begun: one thread alone
takes every part in order and never waits, and the region cannot deadlock whether the thread
pool runs its chunks side by side or one after the other.

- ``fetch_add(counters, i, value)``: ``counters[i] += value`` as one atomic read-modify-write
  (sequentially consistent); returns the value before.
- ``compare_exchange(counters, i, expected, value)``: ``counters[i] = value`` only if it holds
  ``expected``, atomically; returns whether it did (of threads claiming the same part of the
  same step, one succeeds).
- ``load_acquire(counters, i)``: ``counters[i]``, read atomically (acquire: later reads see every
  write made before the matching ``fetch_add``).
- ``spin_pause()``: a hint that the thread is spinning (x86 ``pause``: it frees the core's other
  hyperthread and avoids a pipeline flush on leaving the loop); elsewhere nothing.
- ``yield_thread()``: ``sched_yield()``: let the OS run another thread on this core (the one that
  holds the awaited part may be waiting for it).

(``fetch_add`` and ``load_acquire`` are LLVM's ``atomicrmw add`` and ``load atomic``; the C
library's ``sched_yield`` is found by name in the running process, so a cached function needs no
address of this session's.)
"""

import sys

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .simd import _data, _int64, _is_c_array, _is_x86


def _is_int64_c_array(t):
    return _is_c_array(t, 1) and t.dtype == types.int64


@intrinsic
def fetch_add(typingctx, counters, index, value):
    """``counters[index] += value`` atomically; returns the old value.  counters: 1D C-contiguous int64."""
    if not (_is_int64_c_array(counters) and isinstance(index, types.Integer) and isinstance(value, types.Integer)):
        return None
    sig = types.int64(counters, index, value)

    def codegen(context, builder, signature, args):
        pointer = builder.gep(_data(context, builder, signature.args[0], args[0]),
                              [_int64(context, builder, args[1], signature.args[1])], inbounds=True)
        return builder.atomic_rmw("add", pointer, _int64(context, builder, args[2], signature.args[2]), "seq_cst")

    return sig, codegen


@intrinsic
def compare_exchange(typingctx, counters, index, expected, value):
    """``counters[index] = value`` if it holds ``expected``, as one atomic operation (sequentially
    consistent); returns whether it did.  counters: 1D C-contiguous int64."""
    if not (_is_int64_c_array(counters) and all(isinstance(a, types.Integer) for a in (index, expected, value))):
        return None
    sig = types.boolean(counters, index, expected, value)

    def codegen(context, builder, signature, args):
        pointer = builder.gep(_data(context, builder, signature.args[0], args[0]),
                              [_int64(context, builder, args[1], signature.args[1])], inbounds=True)
        result = builder.cmpxchg(pointer, _int64(context, builder, args[2], signature.args[2]),
                                 _int64(context, builder, args[3], signature.args[3]), "seq_cst", "seq_cst")
        return builder.extract_value(result, 1)

    return sig, codegen


@intrinsic
def load_acquire(typingctx, counters, index):
    """``counters[index]``, an atomic load with acquire ordering.  counters: 1D C-contiguous int64."""
    if not (_is_int64_c_array(counters) and isinstance(index, types.Integer)):
        return None
    sig = types.int64(counters, index)

    def codegen(context, builder, signature, args):
        pointer = builder.gep(_data(context, builder, signature.args[0], args[0]),
                              [_int64(context, builder, args[1], signature.args[1])], inbounds=True)
        return builder.load_atomic(pointer, "acquire", 8)

    return sig, codegen


def _pause(context, builder):
    if _is_x86(context):
        name = "llvm.x86.sse2.pause"
        function = builder.module.globals.get(name) or ir.Function(
            builder.module, ir.FunctionType(ir.VoidType(), []), name)
        builder.call(function, [])
    return context.get_dummy_value()


@intrinsic
def spin_pause(typingctx):
    """x86 ``pause`` (``llvm.x86.sse2.pause``); elsewhere nothing."""
    return types.void(), lambda context, builder, signature, args: _pause(context, builder)


@intrinsic
def yield_thread(typingctx):
    """``sched_yield()`` of the C library (POSIX), resolved by name when the code is loaded; on
    Windows, which has none, ``spin_pause``."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        if sys.platform == "win32":
            return _pause(context, builder)
        name = "sched_yield"
        function = builder.module.globals.get(name) or ir.Function(
            builder.module, ir.FunctionType(ir.IntType(32), []), name)
        builder.call(function, [])
        return context.get_dummy_value()

    return sig, codegen
