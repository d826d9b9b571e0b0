"""How precisely the quiet start gives the noise sigma: the estimate against the generator's.

Run from the repository root, after ``benchmarks/independent_diagnosis.py`` (any number of
its output folders; each holds the records it generated with their truth files)::

    python benchmarks/noise_precision.py reports/indep_s17 reports/indep_s18

For every record ``OUT/records/STEM.csv`` with its ``STEM.truth.json`` (a record found in
several folders, by its seed and name, counts once), estimates the noise from the record's
quiet start as the diagnosis does (:func:`identify.fitting.noise.estimate_noise`) and prints
the ratio of the estimated sigma to the generator's, by noise kind and sampling rate: its
mean (the bias) and standard deviation (the precision). The diagnosis measures every misfit
in units of this sigma; its rules that compare a residual's RMS with the noise (the targeted
check's "nothing to explain" floor, the bench's "RMS within 10 % of sigma") cannot be finer
than this precision.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path

from identify.data.records import load_record
from identify.fitting.noise import estimate_noise


def ratios(outs: list[Path]) -> dict[tuple[str, float], list[float]]:
    """``{(noise kind, rate [Hz]): [estimated / true sigma, ...]}`` over the records of ``outs``."""
    seen, groups = set(), defaultdict(list)
    for out in outs:
        for truth_path in sorted((out / "records").glob("*.truth.json")):
            truth = json.loads(truth_path.read_text())
            key = (json.dumps(truth.get("seed")), truth_path.name)
            if key in seen:
                continue
            seen.add(key)
            record = load_record(truth_path.with_name(truth_path.name.replace(".truth.json", ".csv")))
            estimate = estimate_noise(record)
            groups[(truth["noise"]["kind"], float(truth["fs"]))].append(estimate.sigma / truth["noise"]["sigma"])
    return groups


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outs", nargs="+", type=Path, help="output folders of benchmarks/independent_diagnosis.py")
    args = parser.parse_args(argv)
    for out in args.outs:
        if not (out / "records").is_dir():
            parser.error(f"{out}: no records/ folder (not an output of benchmarks/independent_diagnosis.py)")
    groups = ratios(args.outs)
    if not groups:
        parser.error("no records with a .truth.json in the given folders")
    print("noise  rate [Hz]  records  mean(est/true)  sd(est/true)")
    for (kind, fs), values in sorted(groups.items()):
        n = len(values)
        mean = sum(values) / n
        sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else float("nan")
        print(f"{kind:6s} {fs:9.0f}  {n:7d}  {mean:14.4f}  {100 * sd:10.2f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
