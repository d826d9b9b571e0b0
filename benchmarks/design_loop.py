"""Design -> measure -> joint diagnosis, on records whose single diagnosis ties or leaves structure.

Run from the repository root (resumable: a record with a result is not run again)::

    python benchmarks/design_loop.py --out reports/design_loop --own                       # own bench
    python benchmarks/design_loop.py --out reports/design_loop --independent reports/indep_s23

For every record (the own bench: each slow effect hidden on the paper's drive, seeds given; the
independent bench: the records of a ``benchmarks/independent_diagnosis.py`` folder whose first
verdict was ``tied`` or ``unexplained`` with library physics hidden) the script

1. designs the next record (:func:`identify.design`, the tie's contenders, or the record's best
   refitted candidates when it ended ``unexplained``) with a 120 s duration, or, with
   ``--longest S``, longer up to S seconds where no drive of 120 s decides;
2. measures it: the own bench's :func:`identify.bench.synthetic.simulate_like`, or the
   independent generator's ``--like TRUTH --input next_input.csv`` (the same hidden transducer,
   fresh noise);
3. diagnoses both records together and, after each name that is one of the hidden effects while
   some are still unnamed, again with the names added (as a user does); scores the verdict:
   right when every hidden effect is named one after the other, wrong when a name is not one of
   them; and the calibration: each pair's gap in the first joint evidence against the design's
   prediction.

Prints a line per record and the shares; writes ``OUT/results.json``. With ``--designs-from
EARLIER`` only steps 2 and 3 run again, on the drives and with the predictions of that earlier
run's folder (for a change to the joint diagnosis alone).
"""

from __future__ import annotations

import argparse
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

from identify.bench.synthetic import simulate
from identify.data.fileio import atomic_write
from identify.data.records import load_record
from identify.diagnosis import diagnose
from identify.output.design_report import write_design
from identify.workflows.design import RigLimits, design

sys.path.insert(0, str(ROOT / "benchmarks"))
from diagnosis_cases import own_next_record  # the own bench's next record: one seed convention

GENERATOR = ROOT / "benchmarks" / "independent" / "generator.py"
#: Further joint diagnoses after a right name, each with the names so far added (a pair's second).
FOLLOW_UP_ROUNDS = 2
LIBRARY_NAME = {"first_cycle": "incomplete_reset", "rate_dependent_width": "rate_width"}
#: physics the GPI may absorb (``independent_diagnosis.py``'s rule): naming it is right, and so is
#: leaving it unnamed when the last diagnosis ends adequate
OPTIONAL = {"initial_state"}
#: the own bench's slow effects on the paper's drive (about 2 noise sigmas RMS)
OWN = {
    "thermal": "thermal_tau=30,thermal_sensitivity=0.03,thermal_expansion=1.13",
    "creep": "creep_amplitude=0.0153",
    "sensor_drift": "sensor_drift_linear=1.10,sensor_drift_quadratic=0.83",
    "training": "training_deficit=0.08,training_travel=20",
    "incomplete_reset": "incomplete_reset_strain=4.0,incomplete_reset_retained=0.5,incomplete_reset_fade=0.02",
}


def contenders_for(d) -> list | None:
    """The explanations to tell apart: a tie's, or the best two refitted candidates of a record
    left unexplained; None when there is nothing to decide."""
    if d.status == "tied":
        return list(d.tied)
    if d.status == "unexplained":
        ranked = sorted((c for c in d.ranking if c.refitted and c.fit is not None), key=lambda c: -c.delta_bic)
        return [c.effect for c in ranked[:2]] if len(ranked) >= 2 else None
    return None


def follow_up(records, truth: set, joint, rounds: int = FOLLOW_UP_ROUNDS) -> tuple[list, list]:
    """What a user does after the joint diagnosis names an effect: add it and diagnose the records
    again, while each name is one of the hidden effects and some are still unnamed (at most
    ``rounds`` more diagnoses). ``(names in order, every diagnosis)``."""
    names, diagnoses = [], [joint]
    while joint.status == "missing_effect":
        names.append(joint.missing)
        if joint.missing not in truth or truth <= set(names) or len(diagnoses) > rounds:
            break
        joint = diagnose(records, list(names), rng=np.random.default_rng(0))
        diagnoses.append(joint)
    return names, diagnoses


def score(truth: set, names: list, last) -> dict:
    """Right when every hidden effect is named (one after the other), an optional one
    (:data:`OPTIONAL`) also when the last diagnosis ends adequate; wrong when a name is not one of
    them; a tie of the last diagnosis counts apart when it lists a hidden effect not yet named."""
    members = {n for name in last.tied for n in name.split("+")}
    found = set(names) | (truth & OPTIONAL if last.status == "adequate" else set())
    return {
        "verdict": " -> ".join([*names, last.verdict_text()] if last.status != "missing_effect" else names),
        "named": names,
        "right": truth <= found,
        "first_right": bool(names) and names[0] in truth,
        "wrong": any(n not in truth for n in names),
        "tie_with_truth": last.status == "tied" and bool((truth - set(names)) & members),
    }


def calibration(plan, joint, truth: set) -> list:
    """Each designed pair whose truth is the record's hidden physics (the others' predictions
    are for a transducer that was not measured): the gap the joint evidence shows beside the
    confirmation's prediction (the mean and sd of its simulated gaps) and the linear one (the
    gap at the truth's fit, its noise sd)."""
    simulated = {(c["truth"], c["rival"]): c for c in plan.best.confirmed}
    rows = []
    for p in plan.best.pairs:
        if set(p["truth"].split("+")) != truth:
            continue
        c = simulated.get((p["truth"], p["rival"]), {})
        prediction = {
            "truth": p["truth"],
            "rival": p["rival"],
            "predicted": c.get("gap"),
            "sd": c.get("gap_sd"),
            "linear": p["gap"],
            "linear_noise_sd": p["noise_sd"],
        }
        row = judged(prediction, joint)
        if row is not None:
            rows.append(row)
    return rows


def judged(prediction: dict, joint) -> dict | None:
    """``prediction`` (a row of :func:`calibration` without its outcome) with the gap the joint
    evidence realised and whether it lies within the simulated prediction's and the linear gap's
    2 sd; None where the evidence holds no such gap."""
    truth, rival = prediction["truth"], prediction["rival"]
    realised = joint.evidence.lead(truth, rival) if joint.evidence is not None else None
    if realised is None:
        return None
    predicted, sd = prediction["predicted"], prediction["sd"]
    return prediction | {
        "realised": realised,
        "within_2sd": predicted is not None and abs(realised - predicted) <= 2 * max(sd, 1e-9),
        "linear_within_2sd": abs(realised - prediction["linear"]) <= 2 * max(prediction["linear_noise_sd"], 1e-9),
    }


def run_case(
    name: str, first, truth_names: set, measure, out: Path, duration: float = 120.0, longest: float | None = None
) -> dict:
    started = time.perf_counter()
    alone = diagnose(first, rng=np.random.default_rng(0))
    contenders = contenders_for(alone)
    row = {"case": name, "truth": sorted(truth_names), "alone": alone.verdict_text()}
    if contenders is None:
        return row | {"skipped": f"alone it is {alone.status}", "seconds": time.perf_counter() - started}
    limits = RigLimits.from_records([first], duration=duration, longest=longest)
    started_design = time.perf_counter()

    def say(message):
        print(f"[{time.perf_counter() - started_design:7.1f} s] design {name}: {message}", flush=True)

    plan = design([first], candidates=contenders, limits=limits, rng=np.random.default_rng(0), progress=say)
    write_design(plan, out / "designs" / name)
    second = measure(plan.best.time, plan.best.current)
    joint = diagnose([first, second], rng=np.random.default_rng(0))
    names, diagnoses = follow_up([first, second], truth_names, joint)
    return row | {
        "contenders": contenders,
        "drive": plan.best.family,
        "duration": plan.limits.duration,
        "predicted": plan.best.pairs,
        **score(truth_names, names, diagnoses[-1]),
        "calibration": calibration(plan, joint, truth_names),
        "seconds": time.perf_counter() - started,
    }


def rerun_joint(first, truth_names: set, measure, earlier: dict, designs: Path) -> dict:
    """Steps 2-3 again on the drive an earlier run designed (``designs / NAME / next_input.csv``)
    and with its predictions (``earlier``: that run's row): for a change to the joint diagnosis
    alone, the design being the same code. The row of :func:`run_case`, its seconds the joint part's."""
    started = time.perf_counter()
    drive = np.loadtxt(designs / "next_input.csv", delimiter=",", skiprows=1, ndmin=2)
    second = measure(drive[:, 0], drive[:, 1])
    joint = diagnose([first, second], rng=np.random.default_rng(0))
    names, diagnoses = follow_up([first, second], truth_names, joint)
    rows = [row for row in (judged(c, joint) for c in earlier["calibration"]) if row is not None]
    kept = ("case", "truth", "alone", "contenders", "drive", "predicted")
    return {k: earlier[k] for k in kept if k in earlier} | {
        **score(truth_names, names, diagnoses[-1]),
        "calibration": rows,
        "seconds": time.perf_counter() - started,
        "designs_from": str(designs),
    }


def own_cases(seeds):
    for seed in seeds:
        for effect, spec in OWN.items():
            sim = simulate(spec, seed=seed, noise_sigma=0.5)

            def measure(t, i, sim=sim, seed=seed):
                return own_next_record(sim.truth, t, i, seed)

            yield f"own_{effect}_s{seed}", sim.record, {effect}, measure


def independent_cases(folder: Path):
    for path in sorted((folder / "results").glob("*.json")):
        result = json.loads(path.read_text())
        history = result.get("history") or []
        physics = [LIBRARY_NAME.get(p, p) for p in result.get("physics", [])]
        if not history or history[0]["status"] not in ("tied", "unexplained") or "outside" in physics or not physics:
            continue
        csv = folder / "records" / f"{path.stem}.csv"
        truth_json = csv.with_suffix(".truth.json")

        def measure(t, i, csv=csv, truth_json=truth_json):
            drive = folder / "work" / f"{csv.stem}.next.csv"
            np.savetxt(drive, np.c_[t, i], delimiter=",", header="time,current", comments="", fmt="%.10g")
            target = folder / "work" / "next"
            subprocess.run(
                [
                    sys.executable,
                    str(GENERATOR),
                    "--like",
                    str(truth_json),
                    "--input",
                    str(drive),
                    "--out",
                    str(target),
                    "--stem",
                    csv.stem + "_next",
                ],
                check=True,
                capture_output=True,
            )
            return load_record(str(target / f"{csv.stem}_next.csv"))

        yield path.stem, load_record(str(csv)), set(physics), measure


def saved(path: Path) -> dict:
    """The results written so far (an empty dict before the first)."""
    return json.loads(path.read_text()) if path.exists() else {}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--own", action="store_true", help="the own bench's slow effects")
    parser.add_argument("--seeds", default="41,42", help="the own bench's seeds (default 41,42)")
    parser.add_argument("--independent", type=Path, default=None, help="a folder of independent_diagnosis.py")
    parser.add_argument("--duration", type=float, default=120.0, help="the designed record's length, s (default 120)")
    parser.add_argument(
        "--longest",
        type=float,
        default=None,
        help="the longest record the design may propose where none of --duration decides, s (default --duration)",
    )
    parser.add_argument("--only", default="", help="comma-separated substrings: only cases whose name contains one")
    parser.add_argument(
        "--designs-from",
        type=Path,
        default=None,
        help="an earlier run's --out folder: its designed drives and predictions again, only the measurement "
        "and the joint diagnoses run (for a change to the joint diagnosis alone)",
    )
    args = parser.parse_args(argv)
    only = [o for o in args.only.split(",") if o]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.json"
    results = saved(path)
    cases = []
    if args.own:
        cases += list(own_cases([int(s) for s in args.seeds.split(",") if s]))
    if args.independent is not None:
        cases += list(independent_cases(args.independent))
    earlier = saved(args.designs_from / "results.json") if args.designs_from is not None else None
    for name, first, truth, measure in cases:
        if name in results or (only and not any(o in name for o in only)):
            continue
        if earlier is None:
            r = run_case(name, first, truth, measure, args.out, args.duration, args.longest)
        elif "verdict" in earlier.get(name, {}):
            r = rerun_joint(first, truth, measure, earlier[name], args.designs_from / "designs" / name)
        else:
            continue
        results = saved(path)  # read again: another run into the same folder may have added records
        results[name] = r
        atomic_write(path, json.dumps(results, indent=1, default=float))
        print(
            f"{name:<40} truth {'+'.join(sorted(truth)):<24} alone {r['alone']:<32} -> "
            f"{r.get('verdict', r.get('skipped'))} ({r['seconds']:.0f} s)",
            flush=True,
        )
    results = saved(path)  # with any other run's
    done = [r for r in results.values() if "verdict" in r]
    if done:
        right = sum(r["right"] for r in done)
        first = sum(r.get("first_right", r["right"]) for r in done)
        wrong = sum(r["wrong"] for r in done)
        calib = [c for r in done for c in r["calibration"]]
        # a results file from before the simulated prediction holds the linear check as "within_2sd"
        simulated = [c for c in calib if "linear" in c]
        within = sum(c["within_2sd"] for c in simulated)
        linear = sum(c.get("linear_within_2sd", c["within_2sd"]) for c in calib)
        # informative: a prediction whose sd is under half its gap (a wide one holds whatever happens)
        informative = [c for c in simulated if c["predicted"] is not None and c["sd"] < 0.5 * abs(c["predicted"])]
        print(
            f"every hidden effect named {right}/{len(done)} (one named first {first}), wrong names {wrong}, "
            f"ties listing an unnamed truth {sum(r['tie_with_truth'] for r in done)}; realised gaps within the "
            f"simulated prediction's 2 sd: {within}/{len(simulated)}, of the informative ones (sd < gap / 2) "
            f"{sum(c['within_2sd'] for c in informative)}/{len(informative)} (within the linear gap's 2 noise sd: "
            f"{linear}/{len(calib)})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
