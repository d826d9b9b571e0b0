"""``python -m identify fit DATA.csv``: least squares only, with a parameter table on screen.

Also holds the option helpers that ``study`` shares (record columns/units, effects,
noise, model).
"""

from __future__ import annotations

import argparse
import sys

from . import options

__all__ = [
    "HELP",
    "add_arguments",
    "run",
    "add_record_arguments",
    "add_model_arguments",
    "record_from_args",
    "model_from_args",
    "noise_from_args",
    "parse_effects",
    "format_fit_table",
    "print_record_notes",
    "FitFailedError",
    "fit_or_explain",
    "FIT_OUT_FILES",
    "LONG_RECORD_SAMPLES",
    "say",
]

#: Files ``fit --out DIR`` writes (roles as in :data:`identify.results.FILES`).
FIT_OUT_FILES = ("data", "fit", "manifest")

HELP = "least-squares fit of the GPI (+ effects) to a record; prints parameters, stderr, RMS vs noise"

#: Records with at least this many samples get progress lines from the least squares.
LONG_RECORD_SAMPLES = 100_000
#: Files above this size [bytes] get progress lines while loading.
_BIG_FILE = 20 * 2**20


def say(message: str) -> None:
    """One progress or note line, logged at INFO through the ``identify`` logger
    (:mod:`identify.logs`: on stderr from the command line, hidden by ``-q``)."""
    from .logs import say as log_line

    log_line(message)


def add_record_arguments(parser: argparse.ArgumentParser) -> None:
    """DATA and the column/unit options passed to :func:`identify.records.load_record`."""
    parser.add_argument("data", help="measurement CSV (header time,current,displacement by default)")
    group = parser.add_argument_group("record columns and units (for records from other rigs, e.g. a piezo in V and um)")
    group.add_argument("--time-column", default="time", help="time column [s] (default: time; 'none' = no time column)")
    group.add_argument("--input-column", default="current", help="drive column (default: current)")
    group.add_argument("--output-column", default="displacement", help="output column (default: displacement)")
    group.add_argument("--input-unit", default="A", help="unit of the drive column (default: A)")
    group.add_argument("--output-unit", default="um", help="unit of the output column (default: um)")
    group.add_argument(
        "--every", type=options.positive_int, default=1, metavar="N",
        help="keep every N-th sample and every input reversal (default 1: all); for long, densely sampled "
        "records, e.g. --every 10 on a 5 kHz record of a 1 Hz drive",
    )  # fmt: skip


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Effects, operators, reading, noise, seed and starts."""
    parser.add_argument(
        "--effects", default="",
        help="comma-separated effects added to the GPI (e.g. thermal,creep); default none",
    )  # fmt: skip
    parser.add_argument(
        "--n-operators", type=options.n_operators, default=12,
        help=f"number of play operators N, 1-{options.MAX_OPERATORS} (default 12, the paper's)",
    )  # fmt: skip
    parser.add_argument("--reading", default="swapped", choices=("swapped", "literal"), help="reading of eqs. (5)-(7) (default swapped)")
    parser.add_argument(
        "--noise-sigma",
        default=None,
        type=options.noise_sigma,
        metavar="VALUE|free",
        help="sensor noise std in the output unit, or 'free' to identify it; default: estimated from the "
        "record's unenergised start",
    )
    parser.add_argument("--seed", type=options.seed, default=0, help="seed of the one random generator, >= 0 (default 0)")
    parser.add_argument("--n-starts", type=options.positive_int, default=8, help="least-squares starts (default: %(default)s)")


def parse_effects(text) -> list[str]:
    """``"thermal, creep"`` -> ``["thermal", "creep"]``; unknown names raise a ValueError listing the known ones."""
    from model import EFFECTS

    if text is None:
        return []
    names = [n.strip() for n in str(text).split(",") if n.strip()]
    if names in (["none"], ["gpi"]):
        return []
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(map(repr, unknown))}; known effects: {', '.join(EFFECTS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"an effect is named twice in --effects {text!r}")
    return names


def record_from_args(args, *, hint=True):
    """The record the options name (loaded, thinned by ``--every``).

    A big file gets progress lines while it loads; a record far longer than the model
    needs gets a ``note:`` suggesting ``--every`` (:func:`identify.records.suggest_every`).
    Column names that coincide are an :class:`identify.options.OptionError`.
    """
    import time
    from pathlib import Path

    from .records import keep_every, load_record, suggest_every

    time_column = None if str(args.time_column).lower() == "none" else args.time_column
    names = [("--time-column", time_column), ("--input-column", args.input_column), ("--output-column", args.output_column)]
    given = [(flag, name) for flag, name in names if name is not None]
    for i, (flag, name) in enumerate(given):
        for other, other_name in given[i + 1 :]:
            if name == other_name:
                raise options.OptionError(f"{flag} and {other} both name the column {name!r}")
    try:
        size = Path(args.data).stat().st_size
    except OSError:
        size = 0
    big = size > _BIG_FILE
    if big:
        say(f"reading {args.data} ({size / 2**20:.0f} MB) ...")
    started = time.perf_counter()
    record = load_record(
        args.data,
        time_column=time_column,
        input_column=args.input_column,
        output_column=args.output_column,
        input_unit=args.input_unit,
        output_unit=args.output_unit,
        progress=say if big else None,
    )
    if big:
        say(f"read {len(record)} samples in {time.perf_counter() - started:.1f} s")
    every = getattr(args, "every", 1)
    if hint and every == 1:
        suggestion = suggest_every(record)
        if suggestion is not None:
            n, (k, per) = len(record), suggestion
            say(
                f"note: {n} samples, about {per:.0f} per input half-cycle: far more than the rate-independent GPI "
                f"needs. --every {k} keeps every input reversal and about {per / k:.0f} samples per half-cycle "
                f"(about {k}x less time and memory; the GPI's output at the kept samples is unchanged; with "
                "time-dependent effects keep their time constants well resolved)"
            )
    if every > 1 and len(record) > 200_000:
        say(f"thinning {len(record)} samples (--every {every}) ...")
    return keep_every(record, every)


def model_from_args(args, *, normalise=True):
    """The model the options describe; with the normalisation (alpha pinned) by default."""
    from model import Model

    from .identifiability import normalised_model

    model = Model(parse_effects(args.effects), n_operators=args.n_operators, reading=args.reading)
    return normalised_model(model) if normalise else model


def noise_from_args(args, record):
    from .noise import estimate_noise

    return estimate_noise(record, noise_sigma=args.noise_sigma)


class FitFailedError(ValueError):
    """The least squares could not run; the message says what failed and what to try."""


def fit_or_explain(record, model, **options):
    """:func:`identify.lsq.fit_least_squares`, with a failure turned into a :class:`FitFailedError`.

    Parameters
    ----------
    record, model
        As for :func:`identify.lsq.fit_least_squares`.
    **options
        Passed on (noise, n_starts, rng, verbose, ...).

    Raises
    ------
    FitFailedError
        The fit raised a ValueError (e.g. no start with a finite model output); the message
        names the model and the record and suggests options that change the starts.
    """
    from .lsq import fit_least_squares

    try:
        return fit_least_squares(record, model, **options)
    except ValueError as exc:
        raise FitFailedError(
            f"least squares of {model!r} on {record.source} failed: {exc}. Try: the paper's "
            "12 operators (--n-operators 12) or fewer, more starts (--n-starts), another --seed, "
            "or fewer --effects"
        ) from exc


def print_record_notes(record, file=None) -> None:
    """What was assumed while loading ``record`` (its ``notes``), one ``note:`` line each: logged
    (INFO, :func:`say`), or printed to ``file`` when one is given."""
    for note in getattr(record, "notes", ()):
        if file is None:
            say(f"note: {note}")
        else:
            print(f"note: {note}", file=file)


def format_fit_table(fit, record=None) -> str:
    """Human summary: parameter, value, stderr, unit, Table 1; then RMS vs noise, max error, chi2."""
    import math

    from model import TABLE1, THETA_NAMES

    from .lsq import parameter_units

    units = parameter_units(fit.model, record)
    lines = [f"{'parameter':<24} {'value':>13} {'stderr':>11}  {'unit':<8} {'Table 1':>10}", "-" * 72]
    for i, name in enumerate(fit.model.names):
        stderr = "pinned" if not fit.vary[i] else f"{fit.stderr[i]:11.4g}"
        table1 = f"{TABLE1[THETA_NAMES.index(name)]:10.4f}" if name in THETA_NAMES else ""
        lines.append(f"{name:<24} {fit.theta[i]:13.6g} {stderr:>11}  {units[i]:<8} {table1:>10}")
    out_unit = getattr(record, "output_unit", "um") if record is not None else "um"
    noise = fit.noise
    sigma_note = {"quiet_segment": f"from {noise.n_quiet} quiet samples", "user": "user-given", "free": "estimated (free)"}[noise.source]
    ratio = fit.rms / noise.sigma if noise.sigma > 0 else math.nan
    lines += [
        "-" * 72,
        f"noise: sigma = {noise.sigma:.4g} {out_unit} ({sigma_note}), {noise.kind}"
        + (f", lag-1 rho = {noise.rho:.3f}" if noise.kind == "ar1" else ""),
        f"residual RMS (energised part) = {fit.rms:.4g} {out_unit} = {ratio:.3f} x noise sigma",
        f"max |error| = {fit.max_error_pct:.3f} % of the displacement range",
        f"reduced chi-square = {fit.reduced_chi2:.4f}",
        f"starts: {fit.n_agree} of {fit.n_starts} agree (chi-square within 1 of the best); "
        f"solver: {'converged' if fit.success else 'NOT converged'} ({fit.message}); {fit.seconds:.1f} s",
    ]
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser)
    add_model_arguments(parser)
    parser.add_argument(
        "--free-alpha", action="store_true", help="do not pin alpha (the normalisation); the fit is then degenerate"
    )
    parser.add_argument(
        "--json", default=None, type=options.file_path, metavar="OUT.json",
        help="also write the fit (FitResult.to_dict) here (a file; its folder is created)",
    )  # fmt: skip
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
    from .cmd_study import settings_from_args

    settings = settings_from_args(args)
    settings.pop("json", None)
    return settings


def _fit_exit_code(fit) -> int:
    """0 when the solver converged; 1 (:data:`identify.defaults.EXIT_FINDING`, a warning line
    says so) when it stopped without converging: the parameters are then not a minimum."""
    import logging

    from .defaults import EXIT_FINDING
    from .logs import say as log_line

    if fit.success:
        return 0
    log_line(f"exit code {EXIT_FINDING}: the least-squares solver did NOT converge ({fit.message}); "
             "try more --n-starts or another --seed", logging.WARNING)  # fmt: skip
    return EXIT_FINDING


def run(args) -> int:
    """Fit; exit code 0 done (solver converged), 1 the solver did not converge, 2 bad input
    (one ``error:`` line), 130 interrupted."""
    import time as _time
    from pathlib import Path

    import numpy as np

    from .locks import FolderLock
    from .noise import NoQuietSegmentError
    from .results import FILES, build_manifest, check_resumable, finish_manifest, last_status, load_fit, now_iso
    from .results import remove_run, write_data, write_fit, write_json

    started, t_start = now_iso(), _time.perf_counter()
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
                manifest = build_manifest(seed=args.seed, record=record, settings=_fit_settings(args), started=started, task="fit")
                if not args.force:
                    # 'verbose' was a setting of fit before -v/-q (identify.logs): not compared
                    old = check_resumable(out, manifest, ignore=("verbose",))
                    if old is not None and last_status(old) == "done" and (out / FILES["fit"]).exists():
                        fit = load_fit(out)
                        print(format_fit_table(fit, record))
                        say(f"{out} already holds this fit (same data, seed and settings): reused, nothing rewritten "
                            "(--force to fit again)")  # fmt: skip
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
                manifest, started=started, seconds=_time.perf_counter() - t_start, status="done",
                phases={"least_squares": fit.seconds},
            )  # fmt: skip
            write_json(out / FILES["manifest"], manifest)
            say(f"wrote {out / FILES['fit']} and {out / FILES['manifest']}")
        return _fit_exit_code(fit)
    finally:
        if lock is not None:
            lock.release()
