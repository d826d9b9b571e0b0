"""What a finite-difference Jacobian's batch costs the forward model, against a batch of as many distinct sets.

Run from the repository root::

    python benchmarks/shared_batch.py            # T = 7001 and 70001
    python benchmarks/shared_batch.py --quick    # T = 7001 only, fewer repeats

A forward-difference Jacobian evaluates ``P + 1`` parameter sets that differ from the
first in one parameter each. :func:`model.gpi.gpi` computes each distinct set once and
lets a set that differs from another only in Omega's parameters (``c``, ``d``: 8 of the
19) reuse that set's operator memories, and :meth:`model.Model.evaluate` runs each effect
once per distinct input. This prints, on the paper's input, the time of such a batch
(the plain GPI's 18 free parameters, and GPI + ``thermal`` + ``training``) against a
batch of the same size whose sets all differ in a play parameter (nothing to share),
best of several repeats on one and on two numba threads, with their ratio, and checks
that each row of the shared batch equals its set evaluated alone, bit for bit.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from model import EFFECTS, TABLE1, THETA_NAMES, Model, paper_current


def best_time(fn, repeats: int) -> float:
    """Best wall time of ``repeats`` calls [s] (the machine is shared: the best is the least disturbed)."""
    fn()
    best = np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - started)
    return best


def jacobian_rows(theta: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The forward-difference batch: ``theta`` and one row per free parameter stepped alone."""
    rows = np.repeat(theta[None, :], free.size + 1, axis=0)
    rows[np.arange(1, free.size + 1), free] += np.sqrt(np.finfo(float).eps) * np.maximum(np.abs(theta[free]), 0.01)
    return rows


def distinct_rows_like(rows: np.ndarray) -> np.ndarray:
    """As many sets, each with its own ``rho`` (a play parameter) and its own value of every
    effect parameter: no two share a stage, so nothing is computed once for several."""
    out = rows.copy()
    k = np.arange(1, rows.shape[0] + 1)[:, None]
    out[:, 1] *= 1.0 + 1e-6 * k[:, 0]
    gpi = len(THETA_NAMES)  # the effect parameters follow the GPI's
    out[:, gpi:] += 1e-9 * k * np.maximum(np.abs(rows[0, gpi:]), 1.0)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="T = 7001 only, fewer repeats")
    args = parser.parse_args(argv)
    repeats = 10 if args.quick else 20
    rates = [100.0] if args.quick else [100.0, 1000.0]
    models = [("GPI", Model()), ("GPI + thermal + training", Model(["training", "thermal"]))]
    print(
        f"{'model':26s} {'T':>6s} {'threads':>7s} {'W':>3s} {'Jacobian batch':>15s} {'distinct batch':>15s} "
        f"{'ratio':>6s}"
    )
    threads_before = numba.get_num_threads()
    try:
        for fs in rates:
            time_, current = paper_current(fs=fs)
            for name, m in models:
                theta = m.default_theta()
                theta[: len(TABLE1)] = TABLE1
                for effect in m.effect_names:
                    for key, value in EFFECTS[effect].get_test_parameters().items():
                        theta[m.names.index(key)] = value
                free = np.flatnonzero(m.parameters.vary)
                free = free[free != 0]  # alpha pinned, as in the normalised fits
                shared = jacobian_rows(theta, free)
                distinct = distinct_rows_like(shared)
                if not np.isfinite(m(distinct, time_, current)).all():
                    raise SystemExit(f"{name}: the distinct batch has a non-finite output")
                y = m(shared, time_, current)
                for w in range(shared.shape[0]):
                    if not np.array_equal(y[w], m(shared[w], time_, current)):
                        raise SystemExit(f"{name}: row {w} of the shared batch differs from its set alone")
                for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
                    numba.set_num_threads(threads)
                    t_shared = best_time(lambda: m(shared, time_, current), repeats)
                    t_distinct = best_time(lambda: m(distinct, time_, current), repeats)
                    print(
                        f"{name:26s} {current.size:6d} {threads:7d} {shared.shape[0]:3d} "
                        f"{t_shared * 1e3:12.2f} ms {t_distinct * 1e3:12.2f} ms {t_shared / t_distinct:6.2f}"
                    )
    finally:
        numba.set_num_threads(threads_before)
    print("each row of every shared batch equals its set evaluated alone, bit for bit")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
