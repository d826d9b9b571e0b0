"""``python -m identify design REC.csv [MORE.csv ...] --out DIR``: the next record that decides a tie.

Diagnoses the records (together when several), takes the explanations they leave tied (or
``--candidates a,b,c``), and proposes the drive that best tells them apart within the rig's
limits (:func:`identify.workflows.design.design`). Writes into ``DIR``:

``next_input.csv``
    ``time,current``: the drive to apply, from 0 s at the records' sampling rate, starting with
    the quiet segment the noise needs.
``design.json``
    The contenders, the limits, every ordered pair's predicted chi-square gap (after the rival is
    refitted to mimic the truth on all records), its noise sd, the chance that the joint diagnosis
    names the right one, and the gaps the confirmation by simulation realised.
``design.html``, ``design_drive.png``, ``design_predictions.png``
    The page: the drive, each contender's predicted response to it and where they diverge.

The limits default to what the records show; each can be given. Exit 0 when written; 2 with one
``error:`` line (bad limits, an unknown candidate, a record that cannot be read), nothing written.
"""

from __future__ import annotations

import argparse
import sys
import time

from ..workflows.fit import say
from . import options
from .common import add_model_arguments, add_record_arguments, model_from_args, records_from_args

__all__ = ["HELP", "add_arguments", "run"]

HELP = "design the next experiment: the drive that decides between the effects the records leave tied"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser, several=True)
    add_model_arguments(parser)
    parser.set_defaults(n_starts=4)
    parser.add_argument("--out", required=True, type=options.folder_path, metavar="DIR", help="folder to write")
    parser.add_argument(
        "--candidates",
        default=None,
        metavar="A,B,...",
        help="the explanations to tell apart (effects, or pairs a+b); default the tie of the records' diagnosis",
    )
    parser.add_argument(
        "--drives",
        type=options.positive_int,
        default=40,
        metavar="N",
        help="drives drawn per family of drives in the search (default 40)",
    )
    limits = parser.add_argument_group("the rig's limits (default: what the records show)")
    limits.add_argument("--current-range", default=None, metavar="LO:HI", help="the drive's range")
    limits.add_argument("--max-slew", type=options.positive_float, default=None, metavar="A/s", help="largest slew")
    limits.add_argument("--duration", type=options.positive_float, default=None, metavar="S", help="record length")
    limits.add_argument(
        "--longest",
        type=options.positive_float,
        default=None,
        metavar="S",
        help="the longest record the rig can take: where no drive of --duration decides, longer ones up to S "
        "are designed too (default --duration)",
    )
    limits.add_argument(
        "--max-rms-current", type=options.positive_float, default=None, metavar="A", help="heating limit"
    )
    limits.add_argument("--fs", type=options.positive_float, default=None, metavar="HZ", help="sampling rate")


def run(args) -> int:

    # deferred (--help imports every command's module): workflows.design: numpy, scipy, numba, +1.5 s
    import numpy as np

    # deferred: --help imports every command's module; workflows.design loads numpy/scipy (+1.64 s CPU)
    from ..data.records import RecordError
    from ..output.design_report import write_design
    from ..workflows.design import RigLimits, design

    started = time.perf_counter()

    def progress(message):
        say(f"[{time.perf_counter() - started:6.1f} s] {message}")

    try:
        records = records_from_args(args)
        given = {
            "current_range": options.number_pair(args.current_range, "--current-range") if args.current_range else None,
            "max_slew": args.max_slew,
            "duration": args.duration,
            "longest": args.longest,
            "max_rms_current": args.max_rms_current,
            "fs": args.fs,
        }
        limits = RigLimits.from_records(records, **given)
        candidates = None if args.candidates is None else [c.strip() for c in args.candidates.split(",") if c.strip()]
        result = design(
            records,
            model_from_args(args),
            candidates,
            limits=limits,
            n_starts=args.n_starts,
            rng=np.random.default_rng(args.seed),
            per_family=args.drives,
            progress=progress,
        )
    except (RecordError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    paths = write_design(result, args.out, input_unit=records[0].input_unit, output_unit=records[0].output_unit)
    print(result.reason)
    print(f"wrote {paths['drive']}, {paths['json']} and {paths['page']} ({time.perf_counter() - started:.1f} s)")
    return 0
