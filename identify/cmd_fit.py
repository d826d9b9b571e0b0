"""``python -m identify fit DATA.csv``: least squares only, with a parameter table on screen.

Also holds the option helpers that ``study`` shares (record columns/units, effects,
noise, model).
"""

from __future__ import annotations

import argparse
import sys

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
]

#: Files ``fit --out DIR`` writes (roles as in :data:`identify.results.FILES`).
FIT_OUT_FILES = ("data", "fit", "manifest")

HELP = "least-squares fit of the GPI (+ effects) to a record; prints parameters, stderr, RMS vs noise"


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
        "--every", type=_positive_int, default=1, metavar="N",
        help="keep every N-th sample and every input reversal (default 1: all); for long, densely sampled "
        "records, e.g. --every 10 on a 5 kHz record of a 1 Hz drive",
    )  # fmt: skip


def _positive_int(text) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Effects, operators, reading, noise, seed and starts."""
    parser.add_argument(
        "--effects", default="", help="comma-separated effects added to the GPI (e.g. thermal,creep); default none"
    )
    parser.add_argument("--n-operators", type=int, default=12, help="number of play operators N (default 12, the paper's)")
    parser.add_argument("--reading", default="swapped", choices=("swapped", "literal"), help="reading of eqs. (5)-(7) (default swapped)")
    parser.add_argument(
        "--noise-sigma",
        default=None,
        metavar="VALUE|free",
        help="sensor noise std in the output unit, or 'free' to identify it; default: estimated from the "
        "record's unenergised start",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the one random generator (default 0)")
    parser.add_argument("--n-starts", type=int, default=8, help="least-squares starts (default: %(default)s)")


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


def record_from_args(args):
    from .records import keep_every, load_record

    time_column = None if str(args.time_column).lower() == "none" else args.time_column
    record = load_record(
        args.data,
        time_column=time_column,
        input_column=args.input_column,
        output_column=args.output_column,
        input_unit=args.input_unit,
        output_unit=args.output_unit,
    )
    return keep_every(record, getattr(args, "every", 1))


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
    """Print what was assumed while loading ``record`` (its ``notes``), one ``note:`` line each."""
    for note in getattr(record, "notes", ()):
        print(f"note: {note}", file=sys.stderr if file is None else file)


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
    parser.add_argument("--json", default=None, metavar="OUT.json", help="also write the fit (FitResult.to_dict) here")
    parser.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="results folder: data.npz, fit.json and manifest.json (seed, data hash, settings, versions, "
        "thread counts), as study writes them; reproducible with 'python -m identify reproduce DIR'",
    )
    parser.add_argument("--force", action="store_true", help="with --out: replace a different run already in DIR")
    parser.add_argument("--verbose", action="store_true", help="one line per least-squares start")


def _fit_settings(args) -> dict:
    """The fit's settings for the manifest: every option of the computation (not where it writes)."""
    from .cmd_study import settings_from_args

    settings = settings_from_args(args)
    settings.pop("json", None)
    return settings


def run(args) -> int:
    import time as _time
    from pathlib import Path

    import numpy as np

    from .noise import NoQuietSegmentError
    from .records import RecordError
    from .results import FILES, RunMismatchError, build_manifest, check_resumable, finish_manifest, now_iso
    from .results import write_data, write_fit, write_json

    started, t_start = now_iso(), _time.perf_counter()
    try:
        record = record_from_args(args)
        print_record_notes(record)
        model = model_from_args(args, normalise=not args.free_alpha)
        noise = noise_from_args(args, record)
        out = None
        if args.out:
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            manifest = build_manifest(seed=args.seed, record=record, settings=_fit_settings(args), started=started, task="fit")
            if args.force:
                for role in FIT_OUT_FILES:
                    (out / FILES[role]).unlink(missing_ok=True)
            else:
                check_resumable(out, manifest)
        rng = np.random.default_rng(args.seed)
        print(f"fitting {model!r} to {record.source} ({len(record.time)} samples) ...", file=sys.stderr)
        fit = fit_or_explain(record, model, noise=noise, n_starts=args.n_starts, rng=rng, verbose=args.verbose)
    except (RecordError, NoQuietSegmentError, RunMismatchError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_fit_table(fit, record))
    if args.json:
        write_json(args.json, fit.to_dict())
        print(f"wrote {args.json}", file=sys.stderr)
    if out is not None:
        # the manifest last: its presence means the folder is complete
        write_data(out, record)
        write_fit(out, fit)
        manifest = finish_manifest(
            manifest, started=started, seconds=_time.perf_counter() - t_start, status="done",
            phases={"least_squares": fit.seconds},
        )  # fmt: skip
        write_json(out / FILES["manifest"], manifest)
        print(f"wrote {out / FILES['fit']} and {out / FILES['manifest']}", file=sys.stderr)
    return 0
