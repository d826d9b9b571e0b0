"""How often did the whole-record refits single out a true effect, on the independent bench?

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (any number of
its output folders)::

    python benchmarks/independent_separability.py reports/indep_s14 reports/indep_s15

Reads every diagnosis the bench ran (``OUT/work/STEM.EFFECTS.diagnosis.json``) and the
record's truth. A diagnosis counts when its model holds only true effects and a true library
effect is still missing (``initial_state`` is optional and outside effects have no right
name, so neither counts). Among the single candidates refitted on the whole record, compare
the best missing true effect with the best effect that is not there:

* ``truth ahead``: the true effect's delta BIC exceeds every other's by more than
  :attr:`~identify.diagnosis.Thresholds.bic_significant`, the margin the diagnosis
  asks of a name;
* ``tie``: within that margin of each other;
* ``other ahead``: an effect that is not there fits better by more than the margin;
* ``truth not refitted``: no missing true effect was refitted (its screening or short refit
  promised too little; on an adequate baseline only promising candidates are refitted).

Only ``truth ahead`` leaves a rule that names by the fit's evidence anything to name; the
other three bound what any such rule can reach with these fits (the refits themselves can be
improved, which moves a record between the classes, so this is a bound on the diagnosis's
naming given its refits, not on the data). Printed per step: the plain model of the records
with one hidden effect, the plain model and the second step of the records with two.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

from independent_diagnosis import OPTIONAL, check_outputs, refitted_singles, saved_diagnoses

from identify.diagnosis import Thresholds

CLASSES = ("truth ahead", "tie", "other ahead", "truth not refitted")


def separation(diagnosis: dict, missing: set[str], present: set[str], margin: float) -> tuple[str, str]:
    """``(class, detail)`` of one diagnosis whose model lacks the true effects ``missing``;
    ``present`` are every effect of the record (true ones), which are neither missing nor wrong."""
    refitted = refitted_singles(diagnosis)
    true = [c for c in refitted if c["effect"] in missing]
    other = [c for c in refitted if c["effect"] not in present]
    if not true:
        return "truth not refitted", ""
    best_true = max(true, key=lambda c: c["delta_bic"])
    if not other:
        return "truth ahead", f"{best_true['effect']} {best_true['delta_bic']:.0f}, no other refitted"
    best_other = max(other, key=lambda c: c["delta_bic"])
    gap = best_true["delta_bic"] - best_other["delta_bic"]
    detail = (
        f"{best_true['effect']} {best_true['delta_bic']:.0f} against {best_other['effect']} "
        f"{best_other['delta_bic']:.0f}"
    )
    if gap > margin:
        return "truth ahead", detail
    if gap < -margin:
        return "other ahead", detail
    return "tie", detail


def steps(out: Path, margin: float):
    """``(step, record stem, model, class, detail)`` for each diagnosis of ``out`` that counts."""
    for stem, model, diagnosis, physics in saved_diagnoses(out):
        if "outside" in physics:
            continue
        nameable = {p for p in physics if p not in OPTIONAL}
        effects = set() if model == "plain" else set(model.split("+"))
        missing = nameable - effects
        if not missing or not effects <= set(physics):
            continue
        kind = "single" if len(nameable) == 1 else "pair"
        step = f"{kind}, {'plain model' if not effects else 'second step'}"
        cls, detail = separation(diagnosis, missing, set(physics), margin)
        yield step, stem, model, cls, detail


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    parser.add_argument(
        "--margin",
        type=float,
        default=Thresholds().bic_significant,
        help="delta BIC margin (default: the diagnosis's own, %(default)g)",
    )
    parser.add_argument("--list", action="store_true", help="print every diagnosis that counts, not only the table")
    args = parser.parse_args(argv)
    check_outputs(parser, args.out)
    counts: dict[str, Counter] = {}
    for out in args.out:
        for step, stem, model, cls, detail in steps(out, args.margin):
            counts.setdefault(step, Counter())[cls] += 1
            if args.list:
                print(f"{out.name}/{stem} [{model}] {step}: {cls}" + (f" ({detail})" if detail else ""))
    print(f"| step | diagnoses | {' | '.join(CLASSES)} |")
    print("|---|---|" + "---|" * len(CLASSES))
    for step in sorted(counts):
        c = counts[step]
        print(f"| {step} | {sum(c.values())} | " + " | ".join(str(c[k]) for k in CLASSES) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
