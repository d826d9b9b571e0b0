"""Could the record have told the true effect from its rival? The candidates fitted to the noiseless truth.

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (its output
folder keeps each record's noiseless displacement in ``records/STEM.npz``)::

    python benchmarks/independent_oracle.py reports/indep_s21 [--only effects_001,effects_014]

`benchmarks/independent_separability.py` classes the whole-record refits of the *noisy*
record: a bound on the naming given those refits. This script asks the question of the
data instead. For every saved diagnosis whose model lacks a true library effect (as the
separability script selects them), it takes the best missing true effect and the best
effect that is not there (by the noisy refits' delta BIC) and fits the step's model with
each of them, and without either, to the record's **noiseless** displacement, whitened by
the same noise model the diagnosis used (sigma and AR(1) correlation from the quiet start).
With noise added, each chi-square grows by about the number of samples, the same for all
three, so the noiseless fits give the delta BIC a candidate gets on average over noise
realisations (its charge for unused terms as the diagnosis computes it), and the gap between the
two candidates. The noise moves that gap by about ``2 ||d||``, ``d`` the whitened difference
of the two fits' predictions (the diagnosis's own rule, ``docs/diagnosis.md``: two
non-nested fits that differ widely can fit about equally well and then their order is the
noise's). So:

* ``data separate``: the true effect is ahead by more than
  :attr:`~identify.diagnosis.diagnose.Thresholds.bic_significant` and by at least
  :attr:`~identify.diagnosis.diagnose.Thresholds.gap_z` noise standard deviations: a rule
  that names by the fit's evidence without risking a wrong name can name it on most noise
  realisations;
* ``data tie``: the gap is within either margin: on this record's noise level no such
  rule can name the true effect without naming the rival on about as many realisations;
* ``data favour other``: the rival gets the higher delta BIC on the noiseless truth (by both
  margins): it fits about as well with fewer parameters charged, or the true effect's form
  fits worse (the saved ``chi2`` of each fit tells which).

The fits are least squares from the diagnosis's starts (``fit_baseline``: several starts,
both threshold signs), so a class can also reflect a fit that missed its best basin; the
noisy refits' delta BIC are printed beside for comparison. Prints one row per step and the
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
from identify.diagnosis.diagnose import Thresholds, _delta_bic, fit_baseline
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
            yield (
                stem,
                effects,
                max(true, key=lambda c: c["delta_bic"]),
                max(other, key=lambda c: c["delta_bic"]),
                diagnosis,
            )


def oracle_step(csv: Path, effects: list[str], names: list[str], n_eff: float | None, seed: int) -> dict:
    """Fit ``effects`` alone and with each of ``names`` to the noiseless record; the expected delta BIC
    of each and the noise sd of the gap between the first two. ``n_eff``: the BIC's sample count
    (the noisy diagnosis's effective count; ``None``: the record's samples)."""
    record, clean = noiseless_record(csv)
    noise = estimate_noise(record)
    n_obs = float(len(record.time))  # a noisy fit's chi-square is this much larger, for every model alike
    n_eff = n_eff or n_obs
    fits = {}
    for key, model_effects in [("base", effects)] + [(name, effects + [name]) for name in names]:
        fits[key] = fit_baseline(clean, Model(model_effects), noise, rng=np.random.default_rng(seed))
    base = fits["base"]
    expected = {}
    for name in names:
        delta_bic, uncharged = _delta_bic(clean, base, base.chi2 + n_obs, fits[name], fits[name].chi2 + n_obs, n_eff)
        expected[name] = (delta_bic, uncharged)
    # the noisy record refitted from each noiseless optimum: the delta BIC a refit reaches from the
    # truth's basin (against the better of the plain fit and the plain fit from its noiseless optimum)
    from_truth = {
        key: fit_least_squares(record, f.model, noise=noise, start=f.theta, n_starts=1) for key, f in fits.items()
    }
    noisy_base = min(
        fit_baseline(record, Model(effects), noise, rng=np.random.default_rng(seed)),
        from_truth["base"],
        key=lambda f: f.chi2,
    )
    reached = {
        name: _delta_bic(record, noisy_base, noisy_base.chi2, from_truth[name], from_truth[name].chi2, n_eff)[0]
        for name in names
    }
    prediction = {name: clean.displacement - fits[name].residual for name in names}
    d = whiten(prediction[names[0]] - prediction[names[1]], noise, time=record.time)
    return {
        "noise_sigma": float(noise.sigma),
        "chi2": {k: float(f.chi2) for k, f in fits.items()},
        "expected": expected,
        "from_truth_basin": reached,
        "gap_sd": 2.0 * float(np.sqrt(np.sum(d * d))),
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
        "| record | model | true | other | noisy delta BIC (true, other) | from the truth's basin (true, other) | "
        "noiseless: expected delta BIC (true, other) | gap | noise sd of gap | z | class | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for out in args.outs:
        for stem, effects, true, other, diagnosis in steps(out, only):
            started = clock.perf_counter()
            n_eff = diagnosis.get("details", {}).get(true["effect"], {}).get("n_eff")
            csv = out / "records" / f"{stem}.csv"
            result = oracle_step(csv, effects, [true["effect"], other["effect"]], n_eff, args.seed)
            (e_true, _), (e_other, _) = result["expected"][true["effect"]], result["expected"][other["effect"]]
            gap, sd = e_true - e_other, result["gap_sd"]
            kind = classify(gap, sd, thresholds)
            counts[kind] += 1
            print(
                f"| {out.name}/{stem} | {'+'.join(effects) or 'plain'} | {true['effect']} | {other['effect']} "
                f"| {true['delta_bic']:.0f}, {other['delta_bic']:.0f} "
                f"| {result['from_truth_basin'][true['effect']]:.0f}, "
                f"{result['from_truth_basin'][other['effect']]:.0f} | {e_true:.0f}, {e_other:.0f} | {gap:.0f} | "
                f"{sd:.0f} "
                f"| {gap / sd if sd > 0 else math.inf:.1f} | {kind} | {clock.perf_counter() - started:.0f} |",
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
