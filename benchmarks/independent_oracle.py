"""Could the record have told the true effect from its rival? The candidates fitted to the noiseless truth.

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (its output
folder keeps each record's noiseless displacement in ``records/STEM.npz``)::

    python benchmarks/independent_oracle.py reports/indep_s21 [--only effects_001,effects_014]

`benchmarks/independent_separability.py` classes the whole-record refits of the *noisy*
record: a bound on the naming given those refits. This script asks the question of the
data instead (:mod:`identify.bench.oracle`, where the classes are defined). For every saved
diagnosis whose model lacks a true library effect (as the separability script selects them),
it takes the best missing true effect and the best effect that is not there (by the noisy
refits' delta BIC) and fits the step's model with each of them to the record's **noiseless**
displacement, whitened by the same noise model the diagnosis used (sigma and AR(1)
correlation from the quiet start): the expected likelihood gap and what the noise gives it.

The fits are least squares from the diagnosis's starts (``fit_baseline``: several starts,
both threshold signs) and from the diagnosis's own fit of each candidate on the noisy record
(the baseline's GPI with the candidate's parameters, as its JSON saves them), the lower
kept; a class can still reflect a fit that missed its best basin. Each
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

from identify import estimate_noise, load_record
from identify.bench.oracle import CLASSES, separability
from identify.data.fileio import atomic_write
from identify.fitting.lsq import fit_least_squares
from identify.fitting.parametrisation import normalised_model
from model import Model


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


def diagnosis_starts(diagnosis: dict, effects: list[str], names: list[str]) -> dict:
    """``{name: [start]}``: each of ``names`` as the diagnosis fitted it on the noisy record (the
    baseline's GPI with the candidate's fitted parameters), an extra start of its noiseless fit:
    the noisy optimum lies near the noiseless one, which the oracle's own starts can miss."""
    gpi = (diagnosis.get("fit") or {}).get("theta")
    if not isinstance(gpi, dict):
        return {}
    starts = {}
    for c in diagnosis.get("ranking", []):
        if c["effect"] not in names or not c.get("parameters"):
            continue
        model = normalised_model(Model([*effects, *c["effect"].split("+")]))
        values = {k: v for k, v in {**gpi, **c["parameters"]}.items() if k in model.names}
        starts[c["effect"]] = [model.theta_from_dict(values)]
    return starts


def oracle_step(csv: Path, effects: list[str], names: list[str], seed: int, starts: dict | None = None) -> dict:
    """:func:`identify.bench.oracle.separability` of ``names`` (true, other) on the record (with
    ``starts``, ``{name: [vectors]}``, beside its own), and each model refitted on the noisy record
    from its noiseless optimum."""
    record, clean = noiseless_record(csv)
    noise = estimate_noise(record)
    result = separability(
        record,
        clean.displacement,
        effects,
        names[0],
        names[1],
        noise=noise,
        rng=np.random.default_rng(seed),
        starts=starts,
    )
    from_truth = {
        name: fit_least_squares(record, fit.model, noise=noise, start=fit.theta, n_starts=1)
        for name, fit in result.fits.items()
    }
    return {
        "noise_sigma": float(noise.sigma),
        "chi2": result.chi2,
        "gap": result.gap,
        "gap_sd": result.gap_sd,
        "class": result.kind,
        "from_truth_basin": {k: float(f.chi2) for k, f in from_truth.items()},
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outs", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    parser.add_argument("--only", default="", help="comma-separated substrings: only records whose stem contains one")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fits' random starts (default 0)")
    args = parser.parse_args(argv)
    check_outputs(parser, args.outs)
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
            result = oracle_step(csv, effects, names, args.seed, diagnosis_starts(diagnosis, effects, names))
            gap, sd = result["gap"], result["gap_sd"]
            kind = result["class"]
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
                json.dumps({"true": true["effect"], "other": other["effect"], **result}, indent=1),
            )
    total = sum(counts.values())
    print()
    for kind in CLASSES:
        print(f"* {kind}: {counts[kind]}/{total}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
