"""The joint diagnosis of two records of one transducer on the own bench, resumable.

Run from the repository root::

    python benchmarks/joint_own_diagnosis.py --out reports/joint_own [--seeds 51,52,53,54]

For every slow effect of the library (thermal, creep, training, sensor_drift,
incomplete_reset) and every seed, one transducer (Table 1 and the effect at about 2 noise
sigmas RMS, the settings of ``benchmarks/design_loop.py``) is measured twice by the virtual
bench: on the paper's decaying sine (bench seed ``S``) and on the drive with holds at high
current and a quiet end (bench seed ``S + 500``), white noise 0.5 um, 100 Hz. Both records are
diagnosed together (:func:`identify.diagnosis.diagnose` with a list, the seed's generator);
the verdict is right when the hidden effect is named, wrong when another one is, and a tie
counts as right only in the tie column. One JSON line per case goes to ``OUT/results.jsonl``
as it finishes (a rerun skips the cases already there); the script prints a line per case and
the shares at the end. The target of the several-records issue: named right in at least 95 %,
never a wrong name.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# several benches share the cores: the OpenMP threads wait passively between kernel calls
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np
from resumable_rows import append_row, read_rows

from identify.bench.synthetic import simulate
from identify.diagnosis import diagnose

#: each slow effect at about 2 noise sigmas RMS on the paper's drive (as in design_loop.py)
SLOW_EFFECTS = {
    "thermal": "thermal_tau=30,thermal_sensitivity=0.03,thermal_expansion=1.13",
    "creep": "creep_amplitude=0.0153",
    "sensor_drift": "sensor_drift_linear=1.10,sensor_drift_quadratic=0.83",
    "training": "training_deficit=0.08,training_travel=20",
    "incomplete_reset": "incomplete_reset_strain=4.0,incomplete_reset_retained=0.5,incomplete_reset_fade=0.02",
}


def run_case(effect: str, spec: str, seed: int) -> dict:
    """Simulate the pair of records of one transducer, diagnose them together, score the verdict."""
    started = time.perf_counter()
    records = [
        simulate(spec, seed=seed, noise_sigma=0.5).record,
        simulate(spec, seed=seed + 500, noise_sigma=0.5, drive="holds").record,
    ]
    joint = diagnose(records, rng=np.random.default_rng(seed))
    named = joint.missing if joint.status == "missing_effect" else None
    members = {n for name in joint.tied for n in name.split("+")}
    return {
        "case": f"{effect}_s{seed}",
        "truth": effect,
        "verdict": joint.verdict_text(),
        "status": joint.status,
        "right": named == effect,
        "wrong": named is not None and named != effect,
        "tie_with_truth": joint.status == "tied" and effect in members,
        "seconds": time.perf_counter() - started,
        "reason": joint.reason,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--seeds", default="51,52,53,54", help="bench seeds (default 51,52,53,54)")
    parser.add_argument("--effects", default=",".join(SLOW_EFFECTS), help="comma-separated slow effects")
    args = parser.parse_args(argv)
    unknown = [e for e in args.effects.split(",") if e not in SLOW_EFFECTS]
    if unknown:
        parser.error(f"--effects: unknown {unknown}; known: {', '.join(SLOW_EFFECTS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.jsonl"
    done = read_rows(path, key=lambda row: row["case"])
    for seed in [int(s) for s in args.seeds.split(",") if s]:
        for effect in args.effects.split(","):
            name = f"{effect}_s{seed}"
            if name in done:
                continue
            row = run_case(effect, SLOW_EFFECTS[effect], seed)
            append_row(path, row)
            done[name] = row
            print(f"{name:<28} {row['verdict']:<48} ({row['seconds']:.0f} s)", flush=True)
    rows = list(done.values())
    if rows:
        right = sum(r["right"] for r in rows)
        print(
            f"named right {right}/{len(rows)} ({right / len(rows):.0%}), wrong names {sum(r['wrong'] for r in rows)}, "
            f"ties listing the truth {sum(r['tie_with_truth'] for r in rows)}; "
            f"median {np.median([r['seconds'] for r in rows]):.0f} s a case"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
