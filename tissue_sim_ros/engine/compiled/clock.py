"""Clocks that compiled code reads without the GIL: the thread's CPU time and the monotonic clock.

A slice of substeps run in one compiled call (:mod:`.substeps`) must still say how much
of its time was the force kernel (``Simulation.kernel_s``: thread CPU seconds, what
``time.thread_time`` reads around the kernel in Python) and stop at the caller's wall-clock
deadline (``time.perf_counter``). :func:`clock_ns` calls the C library's ``clock_gettime``
(POSIX; declared by name in the compiled module, so the function caches like any other) with
Linux's clock ids, the ones CPython uses for those two functions. ``AVAILABLE`` is False where
those ids do not hold (not Linux): callers then keep the Python path.
"""
import sys

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ['AVAILABLE', 'MONOTONIC', 'THREAD_CPU', 'clock_ns']

#: clock ids of Linux's <time.h>: CLOCK_MONOTONIC (time.perf_counter), CLOCK_THREAD_CPUTIME_ID
#: (time.thread_time)
MONOTONIC, THREAD_CPU = 1, 3
AVAILABLE = sys.platform.startswith('linux')


@intrinsic
def clock_ns(typingctx, clock_id):
    """The clock ``clock_id``'s time in integer nanoseconds (``clock_gettime``; a timespec of two
    64-bit fields, as on every 64-bit Linux)."""
    if not isinstance(clock_id, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        int32, int64 = ir.IntType(32), ir.IntType(64)
        timespec = ir.LiteralStructType([int64, int64])
        value = cgutils.alloca_once(builder, timespec)
        function = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(int32, [int32, timespec.as_pointer()]), 'clock_gettime')
        builder.call(function, [builder.trunc(args[0], int32), value])
        seconds = builder.load(cgutils.gep_inbounds(builder, value, 0, 0))
        nanoseconds = builder.load(cgutils.gep_inbounds(builder, value, 0, 1))
        return builder.add(builder.mul(seconds, ir.Constant(int64, 1_000_000_000)), nanoseconds)
    return types.int64(clock_id), codegen
