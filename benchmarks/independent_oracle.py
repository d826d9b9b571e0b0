"""Could the record have told the true effect from its rival? The candidates fitted to the noiseless truth.

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (its output
folder keeps each record's noiseless displacement in ``records/STEM.npz``)::

    python benchmarks/independent_oracle.py reports/indep_s21 [--only effects_001,effects_014]

`benchmarks/independent_separability.py` classes the whole-record refits of the *noisy*
record: a bound on the naming given those refits. This script asks the question of the
data instead. For every saved diagnosis whose model lacks a true library effect (as the
separability script selects them), it takes the best missing true effect and the best
effect that is not there (by the noisy refits' delta BIC) and fits the step's model with
each of them to the record's **noiseless** displacement, whitened by the same noise model
the diagnosis used (sigma and AR(1) correlation from the quiet start). With noise added,
each chi-square grows by about the number of samples ``n``, the same for both, so the
noiseless fits give the likelihood gap the decision compares on average over noise
realisations, ``n ln((chi2_other + n) / (chi2_true + n))`` (no charge for parameters, as in
:mod:`identify.diagnosis.decision`). The noise moves that gap by about ``2 ||d||``, ``d`` the
whitened difference of the two fits' predictions (:mod:`identify.diagnosis.evidence`). So:

* ``data separate``: the true effect is ahead by more than
  :attr:`~identify.diagnosis.Thresholds.bic_significant` and by at least
  :attr:`~identify.diagnosis.Thresholds.gap_z` noise standard deviations: a rule
  that names by the fit's evidence without risking a wrong name can name it on most noise
  realisations;
* ``data tie``: the gap is within either margin: on this record's noise level no such
  rule can name the true effect without naming the rival on about as many realisations;
* ``data favour other``: the rival fits the noiseless truth better (by both margins): the
  true effect's form in the library fits this physics worse than the rival does.

The fits are least squares from the diagnosis's starts (``fit_baseline``: several starts,
both threshold signs), so a class can also reflect a fit that missed its best basin; each
candidate is then refitted on the noisy record from its noiseless optimum, and that chi-square
is printed beside the diagnosis's own (a shortfall of the search shows as a diagnosis chi-square
far above it). Prints one row per step and the
count per class.
"""

from __future__ import annotations

import argparse
import json
import math
import time as clock
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
from independent_diagnosis import OPTIONAL, check_outputs, refitted_singles, saved_diagnoses

from identify import Model, estimate_noise, load_record
from identify.data.fileio import atomic_write
from identify.diagnosis import Thresholds, fit_baseline
from identify.fitting.lsq import fit_least_squares
from identify.fitting.noise import whiten

CLASSES = ("data separate", "data tie", "data favour other")


def noiseless_record(csv: Path):
    """``(record, noiseless record)``: the CSV as the diagnosis read it, and the same samples with the
    generator's noiseless displacement (``STEM.npz``)."""
    record = load_record(str(csv))
    truth = np.load(csv.with_suffix(".npz"))
    if truth["time"].shape != record.time.shape or not np.allclose(truth["time"], record.time, rtol=0, atol=1e-6):
        raise SystemExit(f"error: {csv.with_suffix('.npz')}: its time grid is not the CSV's")
    return record, replace(record, displacement=np.asarray(truth["noiseless"], dtype=float))


def steps(out: Path, only: list[str]):
    """``(stem, model effects, best true, best other, diagnosis)`` of every saved
    diagnosis whose model lacks a true library effect and that refitted a true and another candidate."""
    for stem, model, diagnosis, physics in saved_diagnoses(out):
        if only and not any(o in stem for o in only):
            continue
        effects = [] if model == "plain" else model.split("+")
        present = set(physics)
        missing = {p for p in physics if p not in effects and p not in OPTIONAL and p != "outside"}
        if not missing or "outside" in physics:
            continue
        refitted = refitted_singles(diagnosis)
        true = [c for c in refitted if c["effect"] in missing]
        other = [c for c in refitted if c["effect"] not in present]
        if true and other:
            details = diagnosis.get("details", {})

            def closest(c):  # the lowest chi-square (the decision compares fits), else the highest gain
                chi2 = details.get(c["effect"], {}).get("chi2")
                return (0, chi2) if chi2 is not None else (1, -c["delta_bic"])

            yield stem, effects, min(true, key=closest), min(other, key=closest), diagnosis


def oracle_step(csv: Path, effects: list[str], names: list[str], seed: int) -> dict:
    """Fit ``effects`` with each of ``names`` to the noiseless record: the expected likelihood gap
    of the second against the first and its noise sd; and each refitted on the noisy record from
    its noiseless optimum."""
    record, clean = noiseless_record(csv)
    noise = estimate_noise(record)
    n_obs = float(len(record.time))  # a noisy fit's chi-square is this much larger, for every model alike
    fits = {
        name: fit_baseline(clean, Model(effects + [name]), noise, rng=np.random.default_rng(seed)) for name in names
    }
    first, second = (fits[n] for n in names)
    gap = n_obs * math.log((second.chi2 + n_obs) / (first.chi2 + n_obs))
    d = whiten((clean.displacement - first.residual) - (clean.displacement - second.residual), noise, time=record.time)
    from_truth = {
        name: fit_least_squares(record, f.model, noise=noise, start=f.theta, n_starts=1) for name, f in fits.items()
    }
    return {
        "noise_sigma": float(noise.sigma),
        "chi2": {k: float(f.chi2) for k, f in fits.items()},
        "gap": float(gap),
        "gap_sd": 2.0 * float(np.sqrt(np.sum(d * d))),
        "from_truth_basin": {k: float(f.chi2) for k, f in from_truth.items()},
    }


def classify(gap: float, sd: float, thresholds: Thresholds) -> str:
    z = gap / sd if sd > 0 else math.copysign(math.inf, gap)
    if gap > thresholds.bic_significant and z >= thresholds.gap_z:
        return "data separate"
    if gap < -thresholds.bic_significant and z <= -thresholds.gap_z:
        return "data favour other"
    return "data tie"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outs", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    parser.add_argument("--only", default="", help="comma-separated substrings: only records whose stem contains one")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fits' random starts (default 0)")
    args = parser.parse_args(argv)
    check_outputs(parser, args.outs)
    thresholds = Thresholds()
    only = [o for o in args.only.split(",") if o]
    counts = Counter()
    print(
        "| record | model | true | other | diagnosis chi2 (true, other) | from the truth's basin (true, other) | "
        "noiseless chi2 (true, other) | gap | noise sd of gap | z | class | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for out in args.outs:
        for stem, effects, true, other, diagnosis in steps(out, only):
            started = clock.perf_counter()
            csv = out / "records" / f"{stem}.csv"
            names = [true["effect"], other["effect"]]
            result = oracle_step(csv, effects, names, args.seed)
            gap, sd = result["gap"], result["gap_sd"]
            kind = classify(gap, sd, thresholds)
            counts[kind] += 1
            details = diagnosis.get("details", {})
            noisy = [details.get(n, {}).get("chi2") or float("nan") for n in names]
            basin = [result["from_truth_basin"][n] for n in names]
            clean = [result["chi2"][n] for n in names]
            print(
                f"| {out.name}/{stem} | {'+'.join(effects) or 'plain'} | {names[0]} | {names[1]} "
                f"| {noisy[0]:.0f}, {noisy[1]:.0f} | {basin[0]:.0f}, {basin[1]:.0f} | {clean[0]:.1f}, {clean[1]:.1f} "
                f"| {gap:.1f} | {sd:.1f} | {gap / sd if sd > 0 else math.inf:.1f} | {kind} "
                f"| {clock.perf_counter() - started:.0f} |",
                flush=True,
            )
            atomic_write(
                out / "work" / f"{stem}.{'+'.join(effects) or 'plain'}.oracle.json",
                json.dumps({"true": true["effect"], "other": other["effect"], "class": kind, **result}, indent=1),
            )
    total = sum(counts.values())
    print()
    for kind in CLASSES:
        print(f"* {kind}: {counts[kind]}/{total}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
