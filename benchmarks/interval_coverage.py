"""Interval calibration: 95 % coverage of the posterior and least-squares intervals.

Runs :func:`identify.bench.calibration.interval_coverage` on clean bench records (paper input
at 50 Hz, 3501 samples, noise 0.5 um) whose truths are Table 1 with the falling-envelope
offset b3 shifted within +-0.25 A (:func:`identify.bench.calibration.calibration_truth`: about
half of them with crossing operator bounds) and the GPI scaling k = 1.3 applied, and
prints:

* the posterior and least-squares coverage with its standard error across records,
* coverage per parameter,
* convergence, autocorrelation times and wall time per record.

Each finished record is kept in ``--out`` (default ``benchmarks/out/coverage``), so an
interrupted run continues where it stopped. About 50 s per record on a 2-core machine.

Usage: ``python benchmarks/interval_coverage.py [--records 30] [--first 0] [--out DIR] [--truth off-wall]``
(``--first``: the first seed, so that two processes can share a calibration: ``--first 0
--records 50`` and ``--first 50 --records 50`` into the same ``--out``; each prints
the summary of its own seeds; a run over all of them, ``--first 0 --records 100``, then
reads every finished record back and prints the pooled summary without recomputing)
(``off-wall``: the earlier bench's single truth, Table 1 with b3 + 0.5 A, scaled by k = 1.3).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=30, help="number of seeded records (default 30)")
    parser.add_argument("--first", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "coverage")
    parser.add_argument(
        "--truth",
        choices=("both-sides", "off-wall"),
        default="both-sides",
        help="both-sides (default): calibration_truth(seed), b3 within +-0.25 A of Table 1; off-wall: the 2026-11-22 "
        "bench's one truth for every record, Table 1 with b3 + 0.5 A (operator bounds apart), scaled by k = 1.3",
    )
    args = parser.parse_args(argv)
    from identify.bench.calibration import GPI_SCALING_K, calibration_truth, interval_coverage

    truths = calibration_truth
    if args.truth == "off-wall":
        from identify.fitting.parametrisation import gpi_scaling
        from model import TABLE1, THETA_NAMES

        shifted = TABLE1.copy()
        shifted[THETA_NAMES.index("b3")] += 0.5
        truths = gpi_scaling(shifted, GPI_SCALING_K)

    start = time.perf_counter()
    print(f"load average {os.getloadavg()[0]:.2f}; results in {args.out}", flush=True)
    result = interval_coverage(
        truths, range(args.first, args.first + args.records), args.out, log=lambda line: print(line, flush=True)
    )
    print(result.summary())
    post = result.per_parameter("posterior")
    lsq = result.per_parameter("least_squares")
    print("per parameter (posterior / least squares):")
    print("  " + ", ".join(f"{n} {post[n]:.2f}/{lsq[n]:.2f}" for n in result.names))
    seconds = [r.seconds for r in result.records]
    print(
        f"seconds per record {np.median(seconds):.0f} (median), {max(seconds):.0f} (max); "
        f"this run {time.perf_counter() - start:.0f} s; load average {os.getloadavg()[0]:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
