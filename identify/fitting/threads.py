"""Thread counts of the numerical libraries: BLAS held to one thread during the small dense
algebra of a fit, numba's thread count chosen by measurement."""

from __future__ import annotations

import functools
import importlib
import math
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor

import numba
from threadpoolctl import ThreadpoolController

__all__ = [
    "single_threaded_blas",
    "fastest_thread_count",
    "cap_numba_threads",
    "numba_thread_cap",
    "use_idle_cores",
    "side_by_side",
    "results_side_by_side",
    "SIDE_BY_SIDE",
]

#: How many independent fits :func:`side_by_side` runs at once (two: the dense algebra of each
#: solver iteration runs on one core).
SIDE_BY_SIDE = 2

_local = threading.local()


def cap_numba_threads(count: int) -> None:
    """From now on the calling thread runs numba on at most ``count`` threads (a fit side by side
    with others: :func:`fastest_thread_count` never measures more there)."""
    _local.cap = int(count)
    numba.set_num_threads(min(int(count), numba.get_num_threads()))  # thread-local


def numba_thread_cap() -> int:
    """The most numba threads the calling thread may use: its cap, else numba's maximum."""
    return int(getattr(_local, "cap", None) or numba.config.NUMBA_NUM_THREADS)


class _Workers:
    """The workers of one :func:`side_by_side` call: how many there are and how many run an action now."""

    def __init__(self, count: int):
        self.count = int(count)
        self.busy = 0
        self.lock = threading.Lock()

    def start(self) -> None:
        with self.lock:
            self.busy += 1

    def stop(self) -> None:
        with self.lock:
            self.busy -= 1


def use_idle_cores() -> None:
    """In a worker of :func:`side_by_side`: numba's thread count for the next kernels, its own core
    plus those of the call's workers that are idle now (a worker idles only when no action is
    left to start, so in the call's last actions). Elsewhere nothing: a fit alone has its count
    from :func:`fastest_thread_count`. A kernel computes every parameter set apart, so the
    count never changes a result."""
    workers = getattr(_local, "workers", None)
    if workers is not None:
        idle = max(0, workers.count - workers.busy)
        numba.set_num_threads(max(1, min(1 + idle, numba.config.NUMBA_NUM_THREADS)))


@functools.cache
def _blas_libraries() -> ThreadpoolController:
    """The process's thread-pool libraries, listed once: listing them scans every loaded shared
    library (``threadpool_limits`` does so at every call, a few milliseconds, thousands of times
    in a diagnosis). SciPy's BLAS is loaded first, so NumPy's and SciPy's are both listed."""
    importlib.import_module("scipy.linalg")
    return ThreadpoolController()


def single_threaded_blas():
    """Limit BLAS to one thread: the small SVDs of the solver are ~50x slower when
    OpenBLAS threads compete with the (numba-parallel) model on a loaded 2-core machine."""
    return _blas_libraries().limit(limits=1, user_api="blas")


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


def side_by_side(actions, catch=()) -> list:
    """``[(result, None) or (None, exception)]`` of ``actions`` (callables without arguments) in
    order, run on the machine's cores at once (at most :data:`SIDE_BY_SIDE`), each worker with
    numba capped at one thread (:func:`cap_numba_threads`) and BLAS on one thread.

    In the call's last actions a worker whose fellows are idle runs numba on their cores too
    (:func:`use_idle_cores`, called before each batch of model evaluations).

    For independent fits (each reads shared inputs and writes nothing shared): a fit's
    iterations alternate the model's kernels, which use the cores together, with the solver's
    dense algebra (SVD, QR), which uses one, so two fits side by side keep both cores busy.
    Every fit computes what it would alone: BLAS stays on one thread, and numba's thread count
    does not change a result (each parameter set is computed apart). As many workers as numba
    may use threads here (:func:`numba_thread_cap`: the cores, or ``NUMBA_NUM_THREADS``), so a
    thread already capped at one (a worker) runs its actions in turn. An exception of the types
    ``catch`` is returned in its action's place, any other raised here.
    """
    actions = list(actions)
    workers = min(SIDE_BY_SIDE, len(actions), numba_thread_cap())

    def run(action):
        try:
            return action(), None
        except catch as exc:
            return None, exc

    if workers <= 1:
        with single_threaded_blas():
            return [run(action) for action in actions]

    pool_workers = _Workers(workers)

    def one_thread(action):
        cap_numba_threads(1)  # this worker thread's fits, their thread-count measurements included
        _local.workers = pool_workers  # idle workers' cores lent at each batch (use_idle_cores)
        pool_workers.start()
        try:
            return run(action)
        finally:
            pool_workers.stop()

    with single_threaded_blas(), ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(one_thread, action) for action in actions]
        try:
            return [future.result() for future in futures]
        except BaseException:
            for future in futures:
                future.cancel()
            raise


def results_side_by_side(actions) -> list:
    """The results of ``actions`` in order, run as :func:`side_by_side`; any exception raised."""
    return [result for result, _ in side_by_side(actions)]
