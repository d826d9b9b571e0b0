"""``python -m identify predict DIR NEW.csv``: a finished study's model on another record, no refit.

Applies the posterior draws and the least-squares vector of the study in ``DIR`` to the
record ``NEW.csv`` (same rig: the study's columns and units; ``--window T0:T1`` scores
part of it, e.g. the rest of a record whose first part trained the study) and writes
``OUT`` (default ``DIR/predict-<NEW stem>``), all at once:

``prediction.json``
    ``rms``, ``max_error_pct``, ``noise_sigma``, ``inside_predictive_band``, ``verdict``
    (:data:`identify.workflows.use.VERDICTS`), ``missing``, the training figures, the window, the
    noise tests and, when run, the diagnosis (:meth:`identify.workflows.use.Prediction.to_dict`).
``prediction.html`` and ``*.png``
    The page: measured vs predicted displacement and loops with the 95 % credible and
    predictive bands, validation beside training, where the prediction fails, the
    diagnosis' verdict (:mod:`identify.output.use_report`).

Exit code 0 when written; 2 with one ``error:`` line (a folder that is not a finished
study, a record with other columns or units, an empty window), nothing written.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

from ..logs import say
from . import options

__all__ = ["HELP", "add_arguments", "run", "parse_span", "timed_progress", "compute_and_write"]

HELP = "apply a finished study's model to another record (validation, no refit): report, bands, verdict"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", metavar="DIR", help="results folder of a finished `python -m identify study`")
    parser.add_argument(
        "data",
        metavar="NEW.csv",
        nargs="+",
        help="record(s) of the same rig (the study's columns and units); several are each validated on their own",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="OUT",
        help="output folder (default DIR/predict-<NEW stem>); with several records OUT/predict-<NEW stem> each",
    )
    parser.add_argument(
        "--window",
        default=None,
        metavar="T0:T1",
        help="score only T0 <= time <= T1 [s]; the model still runs from the record's start",
    )
    parser.add_argument(
        "--draws",
        type=options.integer(2, None, "an integer >= 2"),
        default=200,
        help="posterior draws pushed through the model (default 200)",
    )
    parser.add_argument(
        "--seed", type=options.seed, default=0, help="seed choosing the draws (and of a diagnosis; default 0)"
    )
    parser.add_argument(
        "--diagnosis",
        choices=("auto", "adequacy"),
        default="auto",
        help="auto (default): when the validation residual is not noise, search which effect the record reveals; "
        "adequacy: only test whether it is noise",
    )
    parser.add_argument(
        "--n-starts", type=options.positive_int, default=6, help="least-squares starts of a diagnosis (default 6)"
    )
    group = parser.add_argument_group("record columns and units (default: the study's)")
    for option in ("time-column", "input-column", "output-column"):
        group.add_argument(f"--{option}", default=None)
    for option in ("input-unit", "output-unit"):
        group.add_argument(f"--{option}", default=None, type=options.unit)


def parse_span(text: str, option: str) -> tuple[float, float]:
    """``"A:B"`` -> ``(A, B)`` floats; ValueError naming ``option`` when malformed."""
    return options.number_pair(text, option)


def timed_progress():
    """``(started, progress)``: the start time and a ``progress(message)`` that says the message
    with the seconds since then (INFO: hidden by -q, the old --quiet)."""
    started = time.perf_counter()

    def progress(message):
        say(f"[{time.perf_counter() - started:6.1f} s] {message}")

    return started, progress


def compute_and_write(args, data_path, prefix: str, compute, write):
    """The frame ``predict`` and ``compensate`` share: ``result = compute()``, written by
    ``write(result, out)`` into ``--out`` (default ``DIR/<prefix>-<stem of data_path>``).

    Returns ``(result, out)``, or None after one ``error:`` line for a
    :class:`identify.workflows.use.UseError` or ValueError (nothing written).
    """
    # deferred (--help imports every command's module): workflows.use: numpy, scipy, numba, matplotlib, +1.6 s
    from ..workflows.use import UseError

    try:
        result = compute()
        out = Path(args.out) if args.out else Path(args.dir) / f"{prefix}-{Path(data_path).stem}"
        write(result, out)
    except (UseError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    return result, out


def run(args) -> int:
    """Validate one record, or several each on its own (every record and the study are read and
    checked before anything is written); exit code 0, or 2 after one ``error:`` line."""
    if isinstance(args.data, (list, tuple)) and len(args.data) == 1:
        args.data = args.data[0]  # one record: exactly the command of one record
    if not isinstance(args.data, (list, tuple)):
        return _run_one(args)
    return _run_several(args)


def _run_several(args) -> int:
    # deferred: --help imports every command's module; workflows.use loads numpy/scipy (+2.09 s CPU)
    from ..workflows.use import UseError, load_record_for_study, load_study

    paths = [Path(p) for p in args.data]
    stems = [p.stem for p in paths]
    try:
        repeated = next((p for p, stem in zip(paths, stems) if stems.count(stem) > 1), None)
        if repeated is not None:
            raise UseError(
                f"{repeated}: a record named twice (or two records with its name, whose folders would clash)"
            )
        study = load_study(args.dir)
        columns = {k: getattr(args, k) for k in ("time_column", "input_column", "output_column")}
        units = {k: getattr(args, k) for k in ("input_unit", "output_unit")}
        for path in paths:  # every record read and checked before anything is written
            load_record_for_study(str(path), study, **columns, **units)
    except (UseError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    code = 0
    for path in paths:
        one = copy.copy(args)
        one.data = str(path)
        if args.out:
            one.out = str(Path(args.out) / f"predict-{path.stem}")
        code = max(code, _run_one(one))
    return code


def _run_one(args) -> int:
    # deferred (--help imports every command's module): workflows.use: numpy, scipy, numba, matplotlib, +1.6 s
    import numpy as np

    # deferred: --help imports every command's module; workflows.use loads numpy/scipy (+2.09 s CPU)
    from ..workflows.use import load_record_for_study, load_study, predict, write_prediction

    started, progress = timed_progress()

    def compute():
        window = parse_span(args.window, "--window") if args.window else None
        study = load_study(args.dir)
        record = load_record_for_study(
            args.data,
            study,
            time_column=args.time_column,
            input_column=args.input_column,
            output_column=args.output_column,
            input_unit=args.input_unit,
            output_unit=args.output_unit,
        )
        progress(f"predicting {record.source} ({len(record)} samples) with the study {study.path}")
        return predict(
            study,
            record,
            window=window,
            n_draws=args.draws,
            rng=np.random.default_rng(args.seed),
            diagnosis=args.diagnosis,
            n_starts=args.n_starts,
            progress=progress,
        )

    done = compute_and_write(args, args.data, "predict", compute, write_prediction)
    if done is None:
        return 2
    prediction, out = done
    unit = prediction.record.output_unit
    t = prediction.training
    print(
        f"validation: RMS {prediction.rms:.4g} {unit} = {prediction.rms / prediction.noise_sigma:.3f} sigma "
        f"(training {t['rms']:.4g} {unit}), max error {prediction.max_error_pct:.3g} % of the range "
        f"(training {t['max_error_pct']:.3g} %), {100 * prediction.inside_predictive_band:.1f} % inside the 95 % "
        "predictive band"
    )
    print(
        f"verdict: {prediction.verdict}"
        + (f" -> the record reveals '{prediction.missing}'" if prediction.missing else "")
    )
    for note in prediction.notes:
        print(f"note: {note}")
    print(f"wrote {out / 'prediction.json'} and {out / 'prediction.html'} ({time.perf_counter() - started:.1f} s)")
    return 0
