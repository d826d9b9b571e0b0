"""Compensation in closed loop on the virtual bench, over seeds (identify.bench.closed_loop).

For each seed: a bench record with the hidden thermal effect of ``data/bench_default.csv``
(seed 1 *is* that record), the diagnosis of the plain GPI on it, the study with the effect
it names, the feedforward current for a triangle and a multi-sine the study never saw, the
bench's TRUE transducer driven with it. Prints per seed and target the tracking RMS and max
as % of the target's range with compensation and with the best linear drive, and the
coverage of the predicted 95 % bands. Each seed's folder (``--out``/seed-N) keeps the record,
the diagnosis, the study and the compensation folders, so a rerun resumes. About 4-6
minutes per seed on the 2-core machine (the study dominates).

Usage: ``python benchmarks/closed_loop.py [--seeds 1 2 3] [--effects SPEC] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--effects", default=None, help="hidden effects (default: data/bench_default.csv's thermal)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "closed_loop")
    parser.add_argument("--draws", type=int, default=200)
    args = parser.parse_args(argv)
    from identify.bench.closed_loop import DEFAULT_BENCH_EFFECTS, closed_loop

    effects = args.effects or DEFAULT_BENCH_EFFECTS
    print(f"load average {os.getloadavg()[0]:.2f}; hidden effects {effects}; results in {args.out}", flush=True)
    rows = []
    for seed in args.seeds:
        started = time.perf_counter()
        result = closed_loop(
            args.out / f"seed-{seed}",
            effects=effects,
            seed=seed,
            n_draws=args.draws,
            progress=lambda m: print(f"  seed {seed}: {m}", flush=True),
        )
        print(
            f"seed {seed}: diagnosis {result.diagnosis_status} ({result.named}), study effects {result.effects}, "
            f"converged {result.converged}, {time.perf_counter() - started:.0f} s",
            flush=True,
        )
        for case in result.cases:
            rows.append((seed, case))
            print(
                f"  {case.target:<10} compensated RMS {case.rms_pct:.4f} % max {case.max_pct:.4f} % | linear RMS "
                f"{case.linear_rms_pct:.2f} % max {case.linear_max_pct:.2f} % | coverage credible "
                f"{case.credible_coverage:.3f} predictive {case.predictive_coverage:.3f} | predicted RMS "
                f"{case.predicted_rms_pct['median']:.4f} % [{case.predicted_rms_pct['lo95']:.4f}, "
                f"{case.predicted_rms_pct['hi95']:.4f}] | median model {case.model_samples}",
                flush=True,
            )
    if rows:
        for name in sorted({c.target for _, c in rows}):
            cases = [c for _, c in rows if c.target == name]
            print(
                f"{name}: over {len(cases)} seeds: RMS {max(c.rms_pct for c in cases):.4f} % (worst), max "
                f"{max(c.max_pct for c in cases):.4f} % (worst), linear RMS >= "
                f"{min(c.linear_rms_pct for c in cases):.2f} %, "
                f"credible coverage {np.mean([c.credible_coverage for c in cases]):.3f} (mean), predictive "
                f"{np.mean([c.predictive_coverage for c in cases]):.3f} (mean)"
            )
        summary = [dict(seed=s, **c.__dict__) for s, c in rows]
        (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
