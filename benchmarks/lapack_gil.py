"""Two threads calling the least-squares solvers' LAPACK routines: the wrappers SciPy's solvers
use against :mod:`identify.fitting.lapack`'s, which call the same routines without the GIL.

Prints, for ``numpy.linalg.lstsq`` (``dogbox``) and ``scipy.linalg.svd`` (``trf``) and their
replacements (``trf_svd`` with the product ``U^T b``, all ``trf`` asks of ``U``), the time of one
call on one thread and how much faster two threads get the same work done (2: no call waits for
the other; 1: they run in turn), on a Jacobian of the shape a diagnosis's working copy gives
(3500 x 21), BLAS on one thread as in a fit.

Usage::

    python benchmarks/lapack_gil.py [--rows 3500] [--columns 21] [--calls 200]
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from identify.fitting.lapack import lstsq, svd, trf_svd


def _timed(function, calls):
    def work():
        for _ in range(calls):
            function()

    work()  # warm
    t0 = time.perf_counter()
    work()
    one = time.perf_counter() - t0
    threads = [threading.Thread(target=work) for _ in range(2)]
    t0 = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    two = time.perf_counter() - t0
    return one / calls, 2.0 * one / two


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=3500)
    parser.add_argument("--columns", type=int, default=21)
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    a = rng.normal(size=(args.rows, args.columns))
    b = rng.normal(size=args.rows)
    cases = [
        ("numpy.linalg.lstsq (dogbox's)", lambda: np.linalg.lstsq(a, b, rcond=-1)),
        ("identify.fitting.lapack.lstsq", lambda: lstsq(a, b, rcond=-1)),
        ("scipy.linalg.svd (trf's)", lambda: scipy.linalg.svd(a, full_matrices=False)),
        ("identify.fitting.lapack.svd", lambda: svd(a, full_matrices=False)),
        ("scipy.linalg.svd, then U^T b", lambda: scipy.linalg.svd(a, full_matrices=False)[0].T.dot(b)),
        ("identify...trf_svd, then U^T b", lambda: trf_svd(a, full_matrices=False)[0].T.dot(b)),
    ]
    print(f"{args.rows} x {args.columns}, {args.calls} calls a thread, BLAS on one thread")
    with threadpool_limits(1):
        for name, function in cases:
            per_call, speedup = _timed(function, args.calls)
            print(f"  {name:32s} {per_call * 1e3:6.3f} ms a call; two threads {speedup:4.2f} x one")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
