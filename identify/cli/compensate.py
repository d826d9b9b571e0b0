"""``python -m identify compensate DIR --target TARGET.csv``: the drive current that follows a target.

The inverse of the study's identified model (:func:`identify.workflows.use.compensate`, method in
:mod:`model.inverse`): for the target displacement trajectory ``TARGET.csv`` (CSV
``time,displacement``, seconds and the study's output unit), the feedforward current of the
posterior-median model within ``--current-range`` (default the rig's 0-5 A), each posterior
draw's own inverse, and the tracking error the posterior predicts for the feedforward.
Writes ``OUT`` (default ``DIR/compensate-<TARGET stem>``), all at once:

``compensation.csv``
    ``time,current``: the feedforward current, one row per target sample.
``compensation.json``
    The predicted tracking error (RMS and max |error|, median and 95 % interval over the
    draws, also in % of the target's range), the median model's own tracking, the
    inverse's statistics (:meth:`identify.workflows.use.Compensation.to_dict`).
``compensation_bands.csv``, ``compensation.html``, ``comp_*.png``
    Per-sample bands (current, error), the page and its figures.

Exit code 0 when written; 2 with one ``error:`` line (a target outside the displacement
the model reaches within the current limits, a malformed target, a folder that is not a
finished study), nothing written.
"""

from __future__ import annotations

import argparse
import time

from . import options
from .predict import compute_and_write, parse_span, timed_progress

__all__ = ["HELP", "add_arguments", "run"]

HELP = "inverse of the identified model: the drive current that makes it follow a target trajectory"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", metavar="DIR", help="results folder of a finished `python -m identify study`")
    parser.add_argument(
        "--target", required=True, metavar="TARGET.csv", help="desired trajectory, CSV time,displacement"
    )
    parser.add_argument(
        "--out", default=None, metavar="OUT", help="output folder (default DIR/compensate-<TARGET stem>)"
    )
    parser.add_argument(
        "--current-range",
        default=None,
        metavar="LO:HI",
        help="limits of the drive (default 0:5 for a study in A, the rig's; else the training record's drive range)",
    )
    parser.add_argument(
        "--draws",
        type=options.integer(2, None, "an integer >= 2"),
        default=200,
        help="posterior draws inverted and driven (default 200)",
    )
    parser.add_argument("--seed", type=options.seed, default=0, help="seed choosing the draws (default 0)")


def run(args) -> int:

    # deferred (--help imports every command's module): workflows.use: numpy, scipy, numba, matplotlib, +1.6 s
    import numpy as np

    # deferred: --help imports every command's module; workflows.use loads numpy/scipy (+2.09 s CPU)
    from ..workflows.use import compensate, load_study, load_target, write_compensation

    started, progress = timed_progress()

    def compute():
        limits = parse_span(args.current_range, "--current-range") if args.current_range else None
        study = load_study(args.dir)
        target = load_target(args.target, output_column=study.record.output_name)
        progress(f"inverting the model of {study.path} for {target.source} ({target.time.size} samples)")
        return compensate(
            study,
            target,
            current_range=limits,
            n_draws=args.draws,
            rng=np.random.default_rng(args.seed),
            progress=progress,
        )

    done = compute_and_write(args, args.target, "compensate", compute, write_compensation)
    if done is None:
        return 2
    result, out = done
    s = result.summary
    te, unit = s["tracking_error"], s["unit"]
    print(
        f"feedforward current {s['current']['min']:.4g} to {s['current']['max']:.4g} {s['input_unit']} "
        f"(limits {result.current_range[0]:g}:{result.current_range[1]:g})"
    )
    print(
        f"predicted tracking error: RMS {te['rms']['median']:.3g} {unit} [95 %: {te['rms']['lo95']:.3g}, "
        f"{te['rms']['hi95']:.3g}] = {te['rms_pct']['median']:.3g} % of the target's range; max |error| "
        f"{te['max_abs']['median']:.3g} {unit} = {te['max_abs_pct']['median']:.3g} %"
    )
    counts = s["model_tracking"]["samples"]
    print(
        f"median model on its own inverse: {counts['exact']} samples exact, {counts['saturated']} at a current limit, "
        f"{counts['branch']} in an Omega gap (max {s['model_tracking']['max_abs']:.3g} {unit})"
    )
    for note in result.notes:
        print(f"note: {note}")
    print(f"wrote {out / 'compensation.csv'} and {out / 'compensation.json'} ({time.perf_counter() - started:.1f} s)")
    return 0
