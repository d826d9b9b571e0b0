"""Could a margin rule on the fit tell the independent bench's right names from its wrong ones?

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (any number of
its output folders)::

    python benchmarks/independent_margins.py reports/indep_s3 reports/indep_s4 reports/indep_s5

Reads every diagnosis the bench ran (``OUT/work/STEM.EFFECTS.diagnosis.json``, the whole
ranking) and the record's truth (``OUT/records/STEM.truth.json``). For each diagnosis that
named an effect which is also the best refitted single candidate, the margin is its delta BIC
minus that of the best other refitted candidate (a pair verdict that names the common member
of the best pairs is left out: its name is not the best single). A name is right when the
effect is among the record's true physics (the generator's ``first_cycle`` is this library's
``incomplete_reset``), wrong otherwise.

Prints the margins of the right and the wrong names, and for a few margins how many of each
a rule "name only when the runner-up is at least this far below" would withhold. The
diagnosis' own rule is 10 (:attr:`identify.diagnosis.Thresholds.bic_significant`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from independent_diagnosis import check_outputs, refitted_singles, saved_diagnoses

MARGINS = (10.0, 30.0, 50.0, 100.0, 300.0)


def named_margins(out: Path) -> list[tuple[str, str, str, float, bool]]:
    """``(record stem, effects in the model, named effect, margin, right)`` for each diagnosis in ``out``."""
    rows = []
    for stem, effects, diagnosis, physics in saved_diagnoses(out):
        if diagnosis.get("status") != "missing_effect":
            continue
        named = diagnosis["missing"]
        refitted = refitted_singles(diagnosis)
        mine = [c["delta_bic"] for c in refitted if c["effect"] == named]
        others = [c["delta_bic"] for c in refitted if c["effect"] != named]
        if not mine or not others or mine[0] < max(others):
            continue
        rows.append((stem, effects, named, mine[0] - max(others), named in physics))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    args = parser.parse_args(argv)
    check_outputs(parser, args.out)
    rows = []
    for out in args.out:
        rows += [(out.name, *row) for row in named_margins(out)]
    right = sorted(row[4] for row in rows if row[5])
    wrong = sorted(row[4] for row in rows if not row[5])
    print(f"{len(rows)} names that are the best single candidate: {len(right)} right, {len(wrong)} wrong")
    print("right names' margins over the runner-up (delta BIC):", ", ".join(f"{m:.0f}" for m in right))
    print("wrong names:")
    for out, stem, effects, named, margin, _ in sorted((row for row in rows if not row[5]), key=lambda r: r[4]):
        print(f"  {out}/{stem} (model: {effects}): '{named}' by {margin:.0f}")
    print("| margin asked for | right names withheld | wrong names withheld |")
    print("|---|---|---|")
    for m in MARGINS:
        print(f"| {m:g} | {sum(x < m for x in right)}/{len(right)} | {sum(x < m for x in wrong)}/{len(wrong)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
