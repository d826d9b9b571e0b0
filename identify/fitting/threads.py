"""Thread counts of the numerical libraries: BLAS held to one thread during the small dense
algebra of a fit, numba's thread count chosen by measurement."""

from __future__ import annotations

import math
import threading
import time as _time

import numba
from threadpoolctl import threadpool_limits

__all__ = ["single_threaded_blas", "fastest_thread_count", "cap_numba_threads", "numba_thread_cap"]

_local = threading.local()


def cap_numba_threads(count: int) -> None:
    """From now on the calling thread runs numba on at most ``count`` threads (a fit side by side
    with others: :func:`fastest_thread_count` never measures more there)."""
    _local.cap = int(count)
    numba.set_num_threads(min(int(count), numba.get_num_threads()))  # thread-local


def numba_thread_cap() -> int:
    """The most numba threads the calling thread may use: its cap, else numba's maximum."""
    return int(getattr(_local, "cap", None) or numba.config.NUMBA_NUM_THREADS)


def single_threaded_blas():
    """Limit BLAS to one thread: the small SVDs of the solver are ~50x slower when
    OpenBLAS threads compete with the (numba-parallel) model on a loaded 2-core machine."""
    return threadpool_limits(1, user_api="blas")


def fastest_thread_count(fn, argument, repeats=3) -> int:
    """Set numba's thread count (1 or the most the calling thread may use, :func:`numba_thread_cap`)
    that runs ``fn(argument)`` fastest now.

    On a loaded 2-core machine a parallel region waits for its second thread to be
    scheduled (measured: 8 ms for 18 parameter sets on 2 threads vs 3.2 ms on 1),
    while on an idle one 2 threads are faster; callers re-measure from time to time.
    Every parameter set is computed independently, so results do not depend on it.

    Returns
    -------
    int
        The thread count now set (restore the previous one with
        ``numba.set_num_threads`` when done).
    """
    counts = sorted({1, numba_thread_cap()})
    best_count, best_time = counts[-1], math.inf
    for count in counts:
        numba.set_num_threads(count)
        timings = []
        for _ in range(repeats):
            t0 = _time.perf_counter()
            fn(argument)
            timings.append(_time.perf_counter() - t0)
        if min(timings) < best_time:
            best_count, best_time = count, min(timings)
    numba.set_num_threads(best_count)
    return best_count
