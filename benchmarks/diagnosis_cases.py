"""The diagnosis's named regression cases (``benchmarks/cases/diagnosis.toml``), rerun.

Run from the repository root (resumable: a case with a result is not run again)::

    python benchmarks/diagnosis_cases.py --out reports/cases [--only NAME,...]

Each case is a record that once revealed a rule of the search or the decision (its name, the
rule and the story are in the table). The record is rebuilt (the independent generator's
effects suite at the case's seed with ``--per-form 1``, or the virtual bench), diagnosed as a
user would (``identify.diagnosis.diagnose``, the case's model), and the answer checked
against the case's expectation: ``name`` (the truth named, or a tie listing it; never another
name), ``named`` (the truth named; a tie is wrong where the records separate),
``tie-or-name`` (the same as ``name``; a tie is expected where the data do not separate),
``unexplained`` or ``adequate``. Prints one line per case and writes ``OUT/results.json``.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np

from identify.bench import simulate
from identify.bench.synthetic import simulate_like
from identify.data.fileio import atomic_write, toml_module
from identify.data.records import load_record
from identify.diagnosis import diagnose

CASES = ROOT / "benchmarks" / "cases" / "diagnosis.toml"
GENERATOR = ROOT / "benchmarks" / "independent" / "generator.py"


#: The noise seed of the own bench's record on a designed drive is its first record's seed plus
#: this (a fresh noise draw of the same transducer).
NEXT_SEED_OFFSET = 1000


def own_next_record(truth: dict, time, current, seed: int):
    """The own bench's record of the transducer ``truth`` (the first record's sidecar, drawn with
    ``seed``) on the drive ``time``, ``current``, with fresh noise."""
    return simulate_like(truth, time, current, seed=seed + NEXT_SEED_OFFSET).record


def record_of(case: dict, cache: Path):
    """The case's record: the independent generator's (generated once per seed into ``cache``) or the
    bench's; a list of two for ``own-pair`` and for ``independent-next`` (the generator's record and
    the one it measures on the case's designed drive)."""
    if case["source"] == "own":
        return simulate(case["effects_hidden"], seed=int(case["seed"]), noise_sigma=0.5).record
    if case["source"] == "own-pair":  # two records of one transducer, diagnosed together
        seed = int(case["seed"])
        return [
            simulate(case["effects_hidden"], seed=seed, noise_sigma=0.5).record,
            simulate(case["effects_hidden"], seed=seed + 500, noise_sigma=0.5, drive="holds").record,
        ]
    if case["source"] == "own-next":  # and the bench's record of the same transducer on the designed drive
        seed = int(case["seed"])
        first = simulate(case["effects_hidden"], seed=seed, noise_sigma=0.5)
        drive = np.loadtxt(_drive_file(case, cache), delimiter=",", skiprows=1, ndmin=2)
        return [first.record, own_next_record(first.truth, drive[:, 0], drive[:, 1], seed)]
    options = [str(o) for o in case.get("generator_options", [])]
    folder = cache / "_".join([f"seed{case['seed']}", *(o.lstrip("-") for o in options)])
    first = _generated(case, folder, options)
    if case["source"] == "independent-next":  # and the designed record of the same hidden transducer
        return [load_record(str(first)), load_record(str(_measured_next(case, first, cache)))]
    return load_record(str(first))


def _generated(case: dict, folder: Path, options: list) -> Path:
    """The CSV of the independent generator's record ``case['stem']`` (generated once per seed)."""
    csv = folder / f"{case['stem']}.csv"
    if not csv.exists():
        matches = sorted(folder.glob(f"{case['stem']}_*.csv")) if folder.is_dir() else []
        if not matches:
            folder.mkdir(parents=True, exist_ok=True)
            command = [sys.executable, str(GENERATOR), "--suite", "effects", "--out", str(folder)]
            command += ["--seed", str(case["seed"]), "--per-form", "1", *options]
            subprocess.run(command, check=True, capture_output=True)
            matches = sorted(folder.glob(f"{case['stem']}_*.csv"))
        if not matches:
            raise SystemExit(f"error: {case['name']}: no record {case['stem']} in the generator's seed {case['seed']}")
        csv = matches[0]
    return csv


def _measured_next(case: dict, first: Path, cache: Path) -> Path:
    """The record the generator measures on the case's designed drive (``next_input``, stored with
    the cases) from the same hidden transducer as ``first`` (``--like``), generated once."""
    target = cache / f"{case['name']}_next"
    csv = target / f"{first.stem}_next.csv"
    if not csv.exists():
        drive = _drive_file(case, cache)
        command = [sys.executable, str(GENERATOR), "--like", str(first.with_suffix(".truth.json"))]
        command += ["--input", str(drive), "--out", str(target), "--stem", csv.stem]
        subprocess.run(command, check=True, capture_output=True)
    return csv


def _drive_file(case: dict, cache: Path) -> Path:
    """The case's designed drive (``next_input``, stored beside the cases), unpacked into ``cache``
    where it is stored gzipped (a long drive at a high rate)."""
    drive = CASES.parent / case["next_input"]
    if drive.suffix != ".gz":
        return drive
    plain = cache / f"{case['name']}_next" / drive.stem
    if not plain.exists():
        plain.parent.mkdir(parents=True, exist_ok=True)
        plain.write_bytes(gzip.decompress(drive.read_bytes()))
    return plain


def calibrated(case: dict, evidence) -> tuple[bool, str]:
    """``(within, what was found)``: whether the joint evidence's gap of the case's ``predicted``
    pair (``[truth, rival, gap, sd]``: the design's simulated prediction for the designed record)
    lies within its 2 sd; ``(True, "")`` for a case without one."""
    if "predicted" not in case:
        return True, ""
    truth, rival, predicted, sd = case["predicted"]
    realised = evidence.lead(truth, rival) if evidence is not None else None
    if realised is None:
        return False, f"; no gap of {truth} and {rival}"
    within = abs(realised - float(predicted)) <= 2.0 * float(sd)
    return within, f"; {rival}'s gap {realised:.0f}, predicted {float(predicted):.0f} ({float(sd):.0f})"


def judge(case: dict, status: str, missing, tied) -> tuple[bool, str]:
    """``(right, what was answered)`` against the case's expectation; a tie that lists one set of
    effects twice (``a+b`` and ``b+a``) is never right."""
    truth = set(case["truth"])
    members = {n for name in tied for n in name.split("+")}
    answer = f"add {missing}" if status == "missing_effect" else (f"tied: {' | '.join(tied)}" if tied else status)
    if len({frozenset(name.split("+")) for name in tied}) < len(tied):
        return False, answer + " (one explanation listed twice)"
    named = status == "missing_effect" and missing in truth
    if case["expect"] == "named":
        return named, answer
    if case["expect"] in ("name", "tie-or-name"):
        return named or (status == "tied" and bool(truth & members)), answer
    return status == case["expect"], answer


def saved(path: Path) -> dict:
    """The results written so far (an empty dict before the first)."""
    return json.loads(path.read_text()) if path.exists() else {}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--only", default="", help="comma-separated case names")
    args = parser.parse_args(argv)
    cases = toml_module().loads(CASES.read_text())["case"]
    only = {n for n in args.only.split(",") if n}
    unknown = only - {c["name"] for c in cases}
    if unknown:
        parser.error(f"unknown case(s): {', '.join(sorted(unknown))}")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.json"
    results = saved(path)
    for case in cases:
        if (only and case["name"] not in only) or case["name"] in results:
            continue
        record = record_of(case, args.out / "records")
        started = time.perf_counter()
        d = diagnose(record, case.get("effects"), rng=np.random.default_rng(0))
        right, answer = judge(case, d.status, d.missing, d.tied)
        within, found = calibrated(case, d.evidence)
        right, answer = right and within, answer + found
        outcome = {
            "right": right,
            "answer": answer,
            "rule": d.rule,
            "seconds": time.perf_counter() - started,
        }
        results = saved(path)  # read again: another run into the same folder may have added cases
        results[case["name"]] = outcome
        atomic_write(path, json.dumps(results, indent=1))
    results = saved(path)  # with any other run's
    still_open = {c["name"] for c in cases if c.get("open")}
    for case in cases:
        r = results.get(case["name"])
        if r is not None and (not only or case["name"] in only):
            mark = "ok" if r["right"] else ("open" if case["name"] in still_open else "WRONG")
            print(
                f"[{mark:>5}] {case['name']:<50} truth {'+'.join(case['truth']):<28} -> {r['answer']} "
                f"({r['rule']}, {r['seconds']:.0f} s)"
            )
    done = {name: r for name, r in results.items() if not only or name in only}
    wrong = [name for name, r in done.items() if not r["right"] and name not in still_open]
    known = [name for name, r in done.items() if not r["right"] and name in still_open]
    print(
        f"{sum(r['right'] for r in done.values())}/{len(done)} right" + (f", {len(known)} still open" if known else "")
    )
    return 0 if not wrong else 1


if __name__ == "__main__":
    raise SystemExit(main())
