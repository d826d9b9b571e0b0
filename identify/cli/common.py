"""Options shared by ``fit``, ``study`` and ``diagnose``: the record's columns and units, the
model, the noise; and the conversion of parsed options into a record, a model, a noise
model and the manifest's settings."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..defaults import DEFAULT_N_STARTS
from ..workflows.fit import parse_effects, say
from . import options

__all__ = [
    "add_record_arguments",
    "add_model_arguments",
    "record_from_args",
    "records_from_args",
    "check_input_moves",
    "model_from_args",
    "noise_from_args",
    "settings_from_args",
    "NOT_SETTINGS",
]

#: Files above this size [bytes] get progress lines while loading.
BIG_FILE = 20 * 2**20
#: Options that are not settings of the computation (not compared, not all recorded).
NOT_SETTINGS = ("out", "force", "progress", "command", "_module", "quiet", "verbose", "compare")


class _OneOrSeveral(argparse.Action):
    """DATA of a command that takes several records: one path as a string (exactly what the
    command of one record parses, so its settings and manifest do not change), several as a list."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values[0] if len(values) == 1 else list(values))


def add_record_arguments(parser: argparse.ArgumentParser, *, several: bool = False) -> None:
    """DATA (one record, or with ``several`` one or more of one transducer) and the column/unit
    options passed to :func:`identify.data.records.load_record`."""
    if several:
        parser.add_argument(
            "data",
            nargs="+",
            action=_OneOrSeveral,
            metavar="DATA",
            help="measurement CSVs of one transducer (header time,current,displacement by default); several are "
            "fitted together: the transducer shared, each record's run and sensor zero its own",
        )
    else:
        parser.add_argument("data", help="measurement CSV (header time,current,displacement by default)")
    group = parser.add_argument_group(
        "record columns and units (for records from other rigs, e.g. a piezo in V and um)"
    )
    group.add_argument("--time-column", default="time", help="time column [s] (default: time; 'none' = no time column)")
    group.add_argument("--input-column", default="current", help="drive column (default: current)")
    group.add_argument("--output-column", default="displacement", help="output column (default: displacement)")
    group.add_argument("--input-unit", default="A", type=options.unit, help="unit of the drive column (default: A)")
    group.add_argument("--output-unit", default="um", type=options.unit, help="unit of the output column (default: um)")
    group.add_argument(
        "--every",
        type=options.positive_int,
        default=1,
        metavar="N",
        help="keep every N-th sample and every input reversal (default 1: all); for long, densely sampled "
        "records, e.g. --every 10 on a 5 kHz record of a 1 Hz drive",
    )


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Effects, operators, reading, noise, seed and starts."""
    parser.add_argument(
        "--effects",
        default="",
        help="comma-separated effects added to the GPI (e.g. thermal,creep); default none",
    )
    parser.add_argument(
        "--n-operators",
        type=options.n_operators,
        default=12,
        help=f"number of play operators N, 1-{options.MAX_OPERATORS} (default 12, the paper's)",
    )
    parser.add_argument(
        "--reading", default="swapped", choices=("swapped", "literal"), help="reading of eqs. (5)-(7) (default swapped)"
    )
    parser.add_argument(
        "--noise-sigma",
        default=None,
        type=options.noise_sigma,
        metavar="VALUE|free",
        help="sensor noise std in the output unit, or 'free' to identify it; default: estimated from the "
        "record's unenergised start",
    )
    parser.add_argument(
        "--seed", type=options.seed, default=0, help="seed of the one random generator, >= 0 (default 0)"
    )
    parser.add_argument(
        "--n-starts",
        type=options.positive_int,
        default=DEFAULT_N_STARTS,
        help="least-squares starts (default: %(default)s)",
    )


def records_from_args(args, *, hint=True) -> list:
    """The records DATA names (one or more), each as :func:`record_from_args` loads it; the same file
    twice, or records in other units, are an error naming the record."""
    # deferred (--help imports every command's module): fitting.joint: numpy, scipy, numba, emcee, +1.1 s
    from ..fitting.joint import check_records

    paths = args.data if isinstance(args.data, (list, tuple)) else [args.data]
    return check_records([record_from_args(args, hint=hint, path=path) for path in paths])


def record_from_args(args, *, hint=True, path=None):
    """The record the options name (``path``, default DATA; loaded, thinned by ``--every``).

    A big file gets progress lines while it loads; a record far longer than the model
    needs gets a ``note:`` suggesting ``--every`` (:func:`identify.data.records.suggest_every`).
    Column names that coincide are an :class:`identify.cli.options.OptionError`.
    """
    # deferred (--help imports every command's module): data.records: numpy, +110 ms
    from ..data.records import keep_every, load_record, suggest_every

    time_column = None if str(args.time_column).lower() == "none" else args.time_column
    names = [
        ("--time-column", time_column),
        ("--input-column", args.input_column),
        ("--output-column", args.output_column),
    ]
    given = [(flag, name) for flag, name in names if name is not None]
    for i, (flag, name) in enumerate(given):
        for other, other_name in given[i + 1 :]:
            if name == other_name:
                raise options.OptionError(f"{flag} and {other} both name the column {name!r}")
    path = args.data if path is None else path
    try:
        size = Path(path).stat().st_size
    except OSError:
        size = 0
    big = size > BIG_FILE
    if big:
        say(f"reading {path} ({size / 2**20:.0f} MB) ...")
    started = time.perf_counter()
    record = load_record(
        path,
        time_column=time_column,
        input_column=args.input_column,
        output_column=args.output_column,
        input_unit=args.input_unit,
        output_unit=args.output_unit,
        progress=say if big else None,
    )
    if big:
        say(f"read {len(record)} samples in {time.perf_counter() - started:.1f} s")
    check_input_moves(record, args.input_column)
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


def check_input_moves(record, column) -> None:
    """A record whose drive never moves (every sample equal, e.g. an all-zero current) has no
    hysteresis to identify: a :class:`identify.data.records.RecordError` saying so, before a
    least squares that would fail with advice about the model."""
    # deferred (--help imports every command's module): data.records: numpy, +110 ms
    import numpy as np

    # deferred: --help imports every command's module; data.records loads numpy (+0.08 s CPU)
    from ..data.records import RecordError

    current = np.asarray(record.current, dtype=float)
    if current.size and float(np.ptp(current)) == 0.0:
        raise RecordError(
            f"{record.source}: the input never moves: column {column!r} is {current[0]:g} in every sample, so there "
            "is no hysteresis to identify. Is it the drive column? Name it with --input-column"
        )


def model_from_args(args, *, normalise=True):
    """The model the options describe; with the normalisation (alpha pinned) by default."""
    # deferred (--help imports every command's module): fitting.parametrisation: the model and numba, +380 ms
    from model import Model

    # deferred: --help imports every command's module; fitting.parametrisation loads numpy/scipy (+0.32 s CPU)
    from ..fitting.parametrisation import normalised_model

    model = Model(parse_effects(args.effects), n_operators=args.n_operators, reading=args.reading)
    return normalised_model(model) if normalise else model


def noise_from_args(args, record):
    # deferred (--help imports every command's module): fitting.noise: numpy, scipy, numba, +280 ms
    from ..fitting.noise import estimate_noise

    return estimate_noise(record, noise_sigma=args.noise_sigma)


def settings_from_args(args) -> dict:
    """Every option of the computation, JSON-ready (the manifest's ``settings``)."""
    settings = {}
    for key, value in sorted(vars(args).items()):
        if key in NOT_SETTINGS or key.startswith("_"):
            continue
        if key == "all_terms" and not value:
            continue  # recorded when set, as from Python: runs before the option had every term
        settings[key] = value
    settings["data"] = str(args.data)
    if getattr(args, "priors", None):  # the file's content counts, not only its name
        # deferred (--help imports every command's module): workflows.study: the sampler (numpy, numba, emcee)
        from ..workflows.study import priors_settings

        settings.update(priors_settings(args.priors))
    return settings
