"""``python -m identify study DATA.csv --out DIR``: the whole identification, resumable.

The options of :func:`identify.workflows.study.study` (steps, resuming, the folder's
checks: see there), with the same defaults. The folder is locked first (a second process
is refused at once), then the model and ``--walkers`` are checked and the record is
loaded, then the study runs.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ..defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS, EXIT_FINDING
from ..workflows.fit import FitFailedError, print_record_notes, say
from . import options
from .app import input_errors
from .common import (
    add_model_arguments,
    add_record_arguments,
    model_from_args,
    record_from_args,
    records_from_args,
    settings_from_args,
)

__all__ = ["HELP", "add_arguments", "run", "run_study"]

HELP = (
    "whole study (noise, least squares, identifiability, emcee posterior, report) of a record, or of several "
    "records of one transducer together, into a results folder"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser, several=True)
    parser.add_argument(
        "--out",
        required=True,
        type=options.folder_path,
        metavar="DIR",
        help="results folder (created; a rerun resumes; locked while the study runs)",
    )
    add_model_arguments(parser)
    parser.add_argument(
        "--walkers",
        type=options.positive_int,
        default=None,
        help="emcee walkers: an even number >= 2 x the sampled parameters (default: 2 x dimension, even, >= 32)",
    )
    parser.add_argument(
        "--max-steps",
        type=options.positive_int,
        default=DEFAULT_MAX_STEPS,
        help=f"cap on the chain length, >= 1 (default {DEFAULT_MAX_STEPS}); raise it to extend a chain that did not "
        "converge",
    )
    parser.add_argument(
        "--check-every",
        type=options.positive_int,
        default=DEFAULT_CHECK_EVERY,
        help=f"convergence check interval in steps, >= 1 (default {DEFAULT_CHECK_EVERY})",
    )
    parser.add_argument(
        "--priors",
        default=None,
        type=options.existing_file,
        metavar="FILE.toml",
        help="priors of some parameters (distribution and bounds, TOML; docs/method.md 'Priors file'); "
        "the others keep the defaults",
    )
    parser.add_argument(
        "--all-terms",
        action="store_true",
        help="sample every optional effect term (default: pin off, after the least squares, those the record "
        "does not support by BIC, e.g. a two-node thermal's second node; docs/effects.md 'Optional terms')",
    )
    parser.add_argument(
        "--moves", default="de", choices=("de", "stretch"), help="emcee moves (default de: differential evolution)"
    )
    parser.add_argument("--force", action="store_true", help="discard a different (or damaged) run already in DIR")
    parser.add_argument(
        "--no-report", action="store_true", help="skip the report (report.html); write it later with 'report DIR'"
    )
    parser.add_argument(
        "--no-diagnose",
        action="store_true",
        help="skip the diagnosis that runs when the residual is above the noise (which effect is missing; "
        "DIR/diagnosis.json, DIR/diagnosis/*.png)",
    )
    parser.add_argument(
        "--compare",
        default=None,
        type=options.existing_folder,
        metavar="EARLIER_DIR",
        help="an earlier study of the same record (e.g. before adding the effect its diagnosis named): the report "
        "shows the error before and after (default: a sibling folder of DIR found by its manifest)",
    )
    parser.add_argument(
        "--progress",
        choices=("auto", "on", "off"),
        default="auto",
        help="the chain's progress: auto (default) = a bar with the projected steps (50 tau) in a terminal, "
        "else a log line every 10 s (IDENTIFY_PROGRESS_SECONDS); on = the bar; off = neither (-q implies off)",
    )


def run(args) -> int:
    """The study; exit code 0 done and converged, 1 done but the chain did NOT CONVERGE, 2 bad input,
    130 interrupted (:data:`identify.cli.app.EXIT_CODES`)."""
    # deferred (--help imports every command's module): fitting.noise: numpy, scipy, numba, +280 ms
    from ..fitting.noise import NoQuietSegmentError

    try:
        return run_study(args)
    except (*input_errors(), NoQuietSegmentError, FitFailedError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def run_study(args) -> int:
    """The study of the parsed options; returns the exit code (0 converged, 1 NOT CONVERGED,
    :attr:`identify.workflows.study.StudyResult.exit_code`)."""
    # deferred (--help imports every command's module): data.locks: json, fcntl, +7 ms
    from ..data.locks import FolderLock

    # deferred (--help imports every command's module): workflows.study: the sampler (numpy, numba, emcee)
    from ..workflows.study import check_priors, check_walkers, study

    if isinstance(args.data, (list, tuple)) and len(args.data) == 1:
        args.data = args.data[0]  # one record: exactly the study of one record
    several = isinstance(args.data, (list, tuple))
    data = " ".join(map(str, args.data)) if several else args.data
    out = Path(args.out)
    lock = FolderLock(out, command=f"python -m identify study {data} --out {args.out}")
    lock.acquire()  # first: a second writer is refused at once, before anything is written
    try:
        if lock.stale_note():
            say(f"note: {lock.stale_note()}")
        try:
            model = model_from_args(args)
            check_walkers(args.walkers, model, args.noise_sigma, flag="--walkers")
        except ValueError as exc:
            raise options.OptionError(str(exc)) from None
        check_priors(args.priors, model)  # before the record is read and anything written (exit code 2)
        if args.compare is not None and not (Path(args.compare) / "summary.json").is_file():
            raise options.OptionError(f"--compare {args.compare}: not the results folder of a study (no summary.json)")
        settings = settings_from_args(args)
        if several:
            if args.noise_sigma is not None:
                raise options.OptionError(
                    "several records are each whitened with the noise of their own quiet start: --noise-sigma "
                    "applies to one record"
                )
            record = records_from_args(args)
            settings["data"] = [str(r.source) for r in record]
            for one in record:
                print_record_notes(one)
        else:
            record = record_from_args(args)
            print_record_notes(record)
        progress = {"auto": None, "on": True, "off": False}[args.progress]
        if progress is None and getattr(args, "quiet", 0):
            progress = False  # -q: no bar and no progress lines
        result = study(
            record,
            model,
            out=out,
            seed=args.seed,
            noise_sigma=args.noise_sigma,
            n_starts=args.n_starts,
            walkers=args.walkers,
            max_steps=args.max_steps,
            check_every=args.check_every,
            moves=args.moves,
            priors=args.priors,
            select_terms=not args.all_terms,
            force=args.force,
            report=not args.no_report,
            diagnose=not args.no_diagnose,
            compare=args.compare,
            progress=progress,
            settings=settings,
            lock=False,
        )
        if not result.converged:  # a warning: -q keeps it
            say(
                f"exit code {EXIT_FINDING}: the chain did NOT CONVERGE (raise --max-steps to extend it)",
                logging.WARNING,
            )
        return result.exit_code
    finally:
        lock.release()
