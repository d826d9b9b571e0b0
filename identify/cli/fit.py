"""``python -m identify fit DATA.csv``: least squares only, with a parameter table on screen."""

from __future__ import annotations

import argparse
import logging
import sys
import time as _time
from pathlib import Path

from ..data.locks import FolderLock
from ..defaults import EXIT_FINDING
from ..workflows.fit import (
    LONG_RECORD_SAMPLES,
    FitFailedError,
    fit_or_explain,
    fit_records,
    format_fit_table,
    format_joint_fit_table,
    print_record_notes,
    say,
)
from . import options
from .app import input_errors
from .common import (
    add_model_arguments,
    add_record_arguments,
    model_from_args,
    noise_from_args,
    record_from_args,
    records_from_args,
    settings_from_args,
)

__all__ = ["HELP", "add_arguments", "run", "FIT_OUT_FILES"]

#: Files ``fit --out DIR`` writes (roles as in :data:`identify.output.results.FILES`).
FIT_OUT_FILES = ("data", "fit", "manifest")

HELP = (
    "least-squares fit of the GPI (+ effects) to a record, or to several records of one transducer together; "
    "prints parameters, stderr, RMS vs noise"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser, several=True)
    add_model_arguments(parser)
    parser.add_argument(
        "--free-alpha", action="store_true", help="do not pin alpha (the normalisation); the fit is then degenerate"
    )
    parser.add_argument(
        "--json",
        default=None,
        type=options.file_path,
        metavar="OUT.json",
        help="also write the fit (FitResult.to_dict) here (a file; its folder is created)",
    )
    parser.add_argument(
        "--out",
        default=None,
        type=options.folder_path,
        metavar="DIR",
        help="results folder: data.npz, fit.json and manifest.json (seed, data hash, settings, versions, "
        "thread counts), as study writes them; reproducible with 'python -m identify reproduce DIR'",
    )
    parser.add_argument("--force", action="store_true", help="with --out: replace a different run already in DIR")


def _fit_settings(args) -> dict:
    """The fit's settings for the manifest: every option of the computation (not where it writes)."""
    settings = settings_from_args(args)
    settings.pop("json", None)
    return settings


def _fit_exit_code(fit) -> int:
    """0 when the solver converged; 1 (:data:`identify.defaults.EXIT_FINDING`, a warning line
    says so) when it stopped without converging: the parameters are then not a minimum."""
    if fit.success:
        return 0
    say(
        f"exit code {EXIT_FINDING}: the least-squares solver did NOT converge ({fit.message}); "
        "try more --n-starts or another --seed",
        logging.WARNING,
    )
    return EXIT_FINDING


def run(args) -> int:
    """Fit; exit code 0 done (solver converged), 1 the solver did not converge, 2 bad input
    (one ``error:`` line), 130 interrupted."""
    # deferred (--help imports every command's module): fitting.noise: numpy, scipy, numba, +280 ms; data.locks +7 ms
    import numpy as np

    # deferred: --help imports every command's module; output.results loads numpy/scipy (+0.93 s CPU)
    from ..fitting.noise import NoQuietSegmentError
    from ..output.results import (
        FILES,
        build_manifest,
        check_resumable,
        finish_manifest,
        last_status,
        load_fit,
        now_iso,
        remove_run,
        write_data,
        write_fit,
        write_json,
    )

    started, t_start = now_iso(), _time.perf_counter()
    if isinstance(args.data, (list, tuple)) and len(args.data) == 1:
        args.data = args.data[0]  # one record: exactly the command of one record
    if isinstance(args.data, (list, tuple)):
        return _run_records(args, started, t_start)
    out = Path(args.out) if args.out else None
    lock = FolderLock(out, command="python -m identify fit " + str(args.data)) if out is not None else None
    try:
        if lock is not None:
            lock.acquire()  # before anything is written into the folder
            if lock.stale_note():
                say(f"note: {lock.stale_note()}")
        try:
            record = record_from_args(args)
            print_record_notes(record)
            model = model_from_args(args, normalise=not args.free_alpha)
            noise = noise_from_args(args, record)
            if out is not None:
                manifest = build_manifest(
                    seed=args.seed, record=record, settings=_fit_settings(args), started=started, task="fit"
                )
                if not args.force:
                    # 'verbose' was a setting of fit before -v/-q (identify.logs): not compared
                    old = check_resumable(out, manifest, ignore=("verbose",))
                    if old is not None and last_status(old) == "done" and (out / FILES["fit"]).exists():
                        fit = load_fit(out)
                        print(format_fit_table(fit, record))
                        say(
                            f"{out} already holds this fit (same data, seed and settings): reused, nothing rewritten "
                            "(--force to fit again)"
                        )
                        if args.json:
                            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
                            write_json(args.json, fit.to_dict())
                        return _fit_exit_code(fit)
            rng = np.random.default_rng(args.seed)
            say(f"fitting {model!r} to {record.source} ({len(record.time)} samples) ...")
            verbose = args.verbose or len(record) >= LONG_RECORD_SAMPLES
            fit = fit_or_explain(record, model, noise=noise, n_starts=args.n_starts, rng=rng, verbose=verbose)
        except (NoQuietSegmentError, FitFailedError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(format_fit_table(fit, record))
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            write_json(args.json, fit.to_dict())
            say(f"wrote {args.json}")
        if out is not None:
            if args.force:
                remove_run(out)  # the run replaced: none of its files may mix with this one
            # the manifest last: its presence means the folder is complete
            write_data(out, record)
            write_fit(out, fit)
            manifest = finish_manifest(
                manifest,
                started=started,
                seconds=_time.perf_counter() - t_start,
                status="done",
                phases={"least_squares": fit.seconds},
            )
            write_json(out / FILES["manifest"], manifest)
            say(f"wrote {out / FILES['fit']} and {out / FILES['manifest']}")
        return _fit_exit_code(fit)
    finally:
        if lock is not None:
            lock.release()


def _check_several(args) -> None:
    """Options that mean one record only."""
    if args.noise_sigma is not None:
        raise options.OptionError(
            "several records are each whitened with the noise of their own quiet start: --noise-sigma applies to "
            "one record"
        )
    if args.free_alpha:
        raise options.OptionError("--free-alpha applies to one record (the joint fit is normalised)")


def _run_records(args, started, t_start) -> int:
    """``fit A.csv B.csv ...``: the joint least squares (:func:`identify.workflows.fit.fit_records`);
    with ``--out`` the folder holds each record's data (``data.npz``, ``data_record<k>.npz``),
    ``fit.json`` (:meth:`identify.fitting.joint.JointFit.to_json`: record 1's fit plus ``joint``
    and a ``records`` list) and the manifest. Every input is checked before anything is written."""
    # deferred: --help imports every command's module; numpy: +0.09 s CPU
    import numpy as np

    # deferred: --help imports every command's module; fitting.joint loads numpy/scipy (+0.93 s CPU)
    from ..fitting.joint import joint_manifest_data, record_noises
    from ..fitting.noise import NoQuietSegmentError
    from ..output.results import (
        FILES,
        build_manifest,
        check_resumable,
        finish_manifest,
        record_data_file,
        remove_run,
        write_data,
        write_json,
    )

    out = Path(args.out) if args.out else None
    lock = FolderLock(out, command="python -m identify fit " + " ".join(map(str, args.data))) if out else None
    try:
        if lock is not None:
            lock.acquire()
        try:
            _check_several(args)
            records = records_from_args(args)
            for record in records:
                print_record_notes(record)
            model = model_from_args(args)
            noises = record_noises(records)
            if out is not None:
                manifest = build_manifest(
                    seed=args.seed, record=records[0], settings=_fit_settings(args), started=started, task="fit"
                )
                manifest["data"] = joint_manifest_data(records)
                if not args.force:
                    check_resumable(out, manifest, ignore=("verbose",))
            say(f"fitting {model!r} to {len(records)} records together ...")
            fit = fit_records(
                records,
                model,
                noises=noises,
                n_starts=args.n_starts,
                rng=np.random.default_rng(args.seed),
                progress=say,
            )
        except (*input_errors(), NoQuietSegmentError, FitFailedError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(format_joint_fit_table(fit))
        if not fit.consistency.get("consistent", True):
            say(f"warning: {fit.consistency['message']}", logging.WARNING)
        content = fit.to_json()
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            write_json(args.json, content)
            say(f"wrote {args.json}")
        if out is not None:
            if args.force:
                remove_run(out)
            for r, record in enumerate(records, start=1):
                write_data(out, record, record_data_file(r))
            write_json(out / FILES["fit"], content)
            manifest = finish_manifest(
                manifest,
                started=started,
                seconds=_time.perf_counter() - t_start,
                status="done",
                phases={"least_squares": fit.seconds},
            )
            write_json(out / FILES["manifest"], manifest)
            say(f"wrote {out / FILES['fit']} and {out / FILES['manifest']}")
        return _fit_exit_code(next((f for f in fit.separate if not f.success), fit.separate[0]))
    finally:
        if lock is not None:
            lock.release()
