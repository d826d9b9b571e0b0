"""The own-bench confusion matrix of the diagnosis, resumable (the cases of the slow test).

Run from the repository root::

    python benchmarks/own_diagnosis.py --out reports/own_bench [--seeds 11,12,13,14,15]

Builds exactly the records of ``tests/test_diagnose_slow.py::test_confusion_matrix``
(every library effect hidden alone at about 2 noise sigmas RMS in its test form, a virgin
initial state, a clean record, three effects outside the library; seeds 11-15), diagnoses
each (``identify.diagnosis.diagnose.diagnose``, the seed's generator), writes one JSON line per
record to ``OUT/results.jsonl`` as it finishes (a rerun skips the records already there),
and prints the matrix in the slow test's format with the wall time per diagnosis. The
slow test asserts the same verdicts; this script only measures, so an interrupted run
keeps what it did.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

# Benches run side by side on the cores: numba's OpenMP threads then wait passively between
# kernel calls, or each process keeps a core spinning (two diagnoses at once: about 50 s
# each instead of about 100 s, benchmarks/diagnose.py --side-by-side 2). Read when the
# threads start, at the first diagnosis. A value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from resumable_rows import append_row, read_rows
from test_diagnose_slow import CASES, SEEDS, _case_record, format_confusion

from identify.diagnosis import diagnose


class _Result:
    """The fields of a Diagnosis that ``format_confusion`` reads."""

    def __init__(self, status, missing):
        self.status, self.missing = status, missing


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--seeds", default=",".join(map(str, SEEDS)))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.jsonl"
    done = read_rows(path, key=lambda row: (row["case"], row["seed"]))
    seeds = [int(s) for s in args.seeds.split(",") if s]
    for seed in seeds:
        for case in CASES:
            if (case, seed) in done:
                continue
            record = _case_record(case, seed)
            started = time.perf_counter()
            cpu = time.process_time()
            d = diagnose(record, rng=np.random.default_rng(seed))
            best = d.best
            row = {
                "case": case,
                "seed": seed,
                "status": d.status,
                "missing": d.missing,
                "rms_over_sigma": d.rms / d.noise_sigma,
                "rms_after_over_sigma": None if best is None else best.rms_after / d.noise_sigma,
                "adequate_after": None if best is None else best.adequate_after,
                "wall_s": time.perf_counter() - started,
                "cpu_s": time.process_time() - cpu,
                "reason": d.reason,
            }
            append_row(path, row)
            done[case, seed] = row
            verdict = d.missing if d.status == "missing_effect" else d.status
            print(
                f"{case:<14} seed {seed}: {verdict:<16} RMS {row['rms_over_sigma']:.3f} sigma, {row['wall_s']:.0f} s "
                f"(CPU {row['cpu_s']:.0f} s)",
                flush=True,
            )
    results = {key: _Result(row["status"], row["missing"]) for key, row in done.items() if key[1] in seeds}
    print(format_confusion(results))
    walls = sorted(row["wall_s"] for key, row in done.items() if key[1] in seeds)
    if walls:
        print(
            f"{len(walls)} diagnoses, wall {sum(walls) / 60:.1f} min, median {walls[len(walls) // 2]:.0f} s, max "
            f"{walls[-1]:.0f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
