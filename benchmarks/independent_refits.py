"""What one candidate effect's refits fitted on the independent bench, beside each record's truth.

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (any number of
its output folders)::

    python benchmarks/independent_refits.py --effect creep reports/indep_s6 reports/indep_s7

Reads every diagnosis the bench ran (``OUT/work/STEM.EFFECTS.diagnosis.json``) and prints,
for each refit of ``--effect`` on the whole record, the record's true physics, the model
diagnosed, the verdict, the refit's delta BIC and its fitted parameters. For ``creep`` it
also counts the refits whose saturating part sits at a lag's time scale (``creep_tau`` below
0.1 s with ``|creep_amplitude|`` above 0.05) and lists them by true physics: a creep that is
a first-order lag of the output in disguise (``docs/diagnosis.md``, limits).
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

from independent_diagnosis import check_outputs, saved_diagnoses

FAST_TAU = 0.1  # s
MIN_AMPLITUDE = 0.05


def refits(out: Path, effect: str) -> list[dict]:
    """One row per whole-record refit of ``effect`` in the saved diagnoses of ``out``."""
    rows = []
    for stem, model, diagnosis, physics in saved_diagnoses(out):
        for c in diagnosis["ranking"]:
            if c["effect"] == effect and c.get("refitted"):
                rows.append(
                    {
                        "draw": out.name,
                        "record": stem,
                        "physics": "+".join(physics),
                        "model": model,
                        "verdict": diagnosis["missing"] or diagnosis["status"],
                        "delta_bic": c["delta_bic"],
                        "parameters": c["parameters"],
                    }
                )
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    parser.add_argument("--effect", required=True, help="a library effect name, e.g. creep")
    args = parser.parse_args(argv)
    check_outputs(parser, args.out)
    rows = []
    for out in args.out:
        rows += refits(out, args.effect)
    if not rows:
        print(f"no whole-record refit of '{args.effect}' in {', '.join(map(str, args.out))}")
        return 0
    for r in rows:
        values = ", ".join(f"{k} {v:.4g}" for k, v in r["parameters"].items())
        print(
            f"{r['draw']}/{r['record']} (truth {r['physics']}; model {r['model']}; verdict {r['verdict']}): "
            f"delta BIC {r['delta_bic']:.0f}; {values}"
        )
    print(f"{len(rows)} refits of '{args.effect}'")
    if args.effect == "creep":
        fast = [
            r
            for r in rows
            if r["parameters"]["creep_tau"] < FAST_TAU and abs(r["parameters"]["creep_amplitude"]) > MIN_AMPLITUDE
        ]
        print(
            f"{len(fast)} with creep_tau < {FAST_TAU:g} s and |creep_amplitude| > {MIN_AMPLITUDE:g}, by true physics:"
        )
        for physics, n in sorted(Counter(r["physics"] for r in fast).items()):
            taus = [r["parameters"]["creep_tau"] for r in fast if r["physics"] == physics]
            print(f"  {physics}: {n} (creep_tau {1000 * min(taus):.0f}-{1000 * max(taus):.0f} ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
