"""What ``incomplete_reset``'s optional terms cost beside its plain form, in one run.

Run from the repository root::

    python benchmarks/incomplete_reset_terms.py            # 26 parameter sets x 7001 samples
    python benchmarks/incomplete_reset_terms.py --sets 18 --fs 1000
    python benchmarks/incomplete_reset_terms.py --drive holds   # holds and a quiet end

Times :func:`model.effects.incomplete_reset.incomplete_reset_strain` (the effect's extra strain
on a given GPI output, the part its optional terms change) for ``W`` parameter sets on the
paper's input (or the bench's drive with holds and a quiet end, where the GPI's output repeats
itself at more than half of the steps): the plain form (the strain's own excursion), each term
on alone (``drive``, ``shape``, ``step``, ``stroke``) and every term on, and prints each as the
best of several calls and as a ratio to the plain form (the baseline measured in the same run,
so the machine's speed drops out). The diagnosis fits these terms in every candidate search of a first-cycle record:
a Jacobian evaluates ``W`` = its free parameters + 1 sets at once.
"""

from __future__ import annotations

import argparse

import numpy as np
from shared_batch import best_time  # the best of several calls (benchmarks/shared_batch.py)

from model import Model
from model.effects.incomplete_reset import incomplete_reset_strain
from model.signals import DRIVES, drive_current

#: ``{label: {term: value}}``: the plain form, each optional term alone, every term on.
CASES = {
    "plain": {},
    "drive": {"drive": 0.3},
    "shape": {"shape": 0.7},
    "step": {"onset": 0.4, "sharpness": 5.0},
    "stroke": {"stroke": 1.5},
    "every term": {"drive": 0.3, "shape": 0.7, "onset": 0.4, "sharpness": 5.0, "stroke": 1.5},
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=26, help="parameter sets W (default 26)")
    parser.add_argument("--fs", type=float, default=100.0, help="sampling rate [Hz] (default 100)")
    parser.add_argument("--drive", choices=DRIVES, default="paper", help="the input (default the paper's, 70 s)")
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args(argv)
    time, current = drive_current(args.drive, fs=args.fs)
    plain = Model()
    gpi = plain.evaluate(plain.default_theta(), time, current)[0][0]
    rng = np.random.default_rng(0)
    strain = gpi[None, :] * (1.0 + 0.01 * rng.standard_normal((args.sets, 1)))  # W nearby GPI outputs
    w = args.sets
    common = {"strain": np.full(w, 3.0), "retained": np.full(w, 0.5), "fade": np.full(w, 0.02)}
    times = {}
    for label, terms in CASES.items():
        kwargs = common | {k: np.full(w, v) for k, v in terms.items()}
        times[label] = best_time(lambda kwargs=kwargs: incomplete_reset_strain(current, strain, **kwargs), args.repeats)
    held = float(np.mean(np.diff(gpi) == 0.0))
    print(
        f"incomplete_reset_strain, {w} parameter sets x {time.size} samples of the {args.drive} drive "
        f"(the GPI's output repeated at {100 * held:.0f} % of the steps; best of {args.repeats} calls):"
    )
    for label, seconds in times.items():
        print(f"  {label:<11} {1e3 * seconds:7.3f} ms   {seconds / times['plain']:5.2f} x the plain form")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
