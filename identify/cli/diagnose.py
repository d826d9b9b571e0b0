"""``python -m identify diagnose DATA.csv``: least squares plus the diagnosis (no posterior).

Prints a short human summary (verdict, why, candidates) and writes, on request:

``--json OUT.json``
    :meth:`identify.diagnosis.diagnose.Diagnosis.to_dict`: ``effects``, ``noise_sigma``, ``rms``,
    ``max_error_pct``, ``status``, ``missing``, ``tied``, ``rule``, ``ranking`` (best first: ``effect``,
    ``rms_after``, ``delta_bic``, ``explained_fraction``, ``parameters``, ...), and the
    details (``reason``, ``decision``, ``evidence``, ``gaps``, ``adequacy``, ``where``, ``pair``, ``fit``).
``--out DIR``
    ``DIR/diagnosis.json`` (the same content) and the figures ``DIR/diagnosis/*.png``
    (:data:`identify.output.diagnosis_plots.FIGURES`); the report (:mod:`identify.output.report`) of a
    study written to the same ``DIR`` shows them.

Every file is written to a temporary name and renamed, so an interrupted run leaves no
half-written file. ``--effects`` adds effects to the diagnosed model, as for ``fit`` and
``study``: diagnose, add the effect named, diagnose again.

The command waits passively between the model's parallel kernel calls (:func:`passive_waiting`)
unless ``OMP_WAIT_POLICY`` is set: the same results for a fraction of the CPU time.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..logs import say
from . import options
from .common import add_model_arguments, add_record_arguments, model_from_args, noise_from_args, records_from_args

__all__ = ["HELP", "add_arguments", "parse_window", "passive_waiting", "run", "write_outputs"]

HELP = "least squares + diagnosis: is the residual noise, and which physical effect is missing?"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser, several=True)
    add_model_arguments(parser)
    parser.set_defaults(n_starts=6)
    parser.add_argument(
        "--json", default=None, type=options.file_path, metavar="OUT.json", help="write the diagnosis as JSON here"
    )
    parser.add_argument(
        "--out",
        default=None,
        type=options.folder_path,
        metavar="DIR",
        help="write DIR/diagnosis.json and the figures DIR/diagnosis/*.png (DIR is locked while they are written)",
    )
    parser.add_argument(
        "--drop-window",
        default=None,
        metavar="START:STOP",
        help="leave the samples with START <= time < STOP [s] out (e.g. a switch-on ringing no rate-independent "
        "model fits; see identify.data.realdata.drop_window)",
    )


def parse_window(text: str) -> tuple[float, float]:
    """``"START:STOP"`` -> ``(start, stop)`` [s]; ValueError naming the option when malformed."""
    return options.number_pair(text, "--drop-window", form="START:STOP in seconds", example="3.2572:3.2772")


def write_outputs(diagnosis, record, *, json_path=None, out_dir=None) -> list[str]:
    """Write the JSON and (with ``out_dir``) the figures; returns the paths written
    (:func:`identify.output.diagnosis_files.write_diagnosis`)."""
    # deferred: --help imports every command's module; output.diagnosis_files loads numpy/scipy (+1.00 s CPU)
    from ..output.diagnosis_files import write_diagnosis

    return write_diagnosis(diagnosis, record, json_path=json_path, out_dir=out_dir)


def passive_waiting() -> None:
    """``OMP_WAIT_POLICY=PASSIVE`` for this process unless it is set (read once, when numba's
    OpenMP threads first start, so before the first kernel call).

    A diagnosis is thousands of short solver steps, each a few model calls between which the
    process runs Python and SciPy alone; with libgomp's default each OpenMP thread then spins
    for milliseconds after every parallel kernel call, and the calls come closer together than
    that, so the second thread spins through the whole diagnosis: several times the CPU time of
    waiting passively for the same results (every parameter set is computed alone, whatever
    the threads do), and on a machine it shares, slower in wall time too. A study's sampler,
    whose kernel calls are shorter and more frequent, gains from spinning; it runs in its own
    command and is not affected.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def run(args) -> int:
    """Diagnose; exit code 0 done, 2 bad input, 130 interrupted. ``--out DIR`` is locked from the start."""
    passive_waiting()
    # deferred (--help imports every command's module): data.locks: json, fcntl, +7 ms
    from ..data.locks import FolderLock

    if getattr(args, "drop_window", None):
        try:
            parse_window(args.drop_window)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    if args.out is None:
        return _run(args)
    data = " ".join(args.data) if isinstance(args.data, (list, tuple)) else args.data
    with FolderLock(args.out, command=f"python -m identify diagnose {data} --out {args.out}"):
        return _run(args)


def _run(args) -> int:

    # deferred (--help imports every command's module): diagnosis: numpy, scipy, numba, +1.6 s
    import numpy as np

    # deferred: --help imports every command's module; diagnosis loads numpy/scipy (+1.61 s CPU)
    from ..data.records import RecordError
    from ..diagnosis import diagnose
    from ..fitting.noise import NoQuietSegmentError

    try:
        records = records_from_args(args)
        if getattr(args, "drop_window", None):
            # deferred: --help imports every command's module; data.realdata loads numpy/scipy (+0.12 s CPU)
            from ..data.realdata import drop_window

            records = [drop_window(r, *parse_window(args.drop_window)) for r in records]
        model = model_from_args(args)
        if len(records) > 1 and args.noise_sigma is not None:
            raise ValueError(
                "several records are each whitened with their own quiet start: --noise-sigma applies to one"
            )
        noise = noise_from_args(args, records[0]) if len(records) == 1 else None
    except (RecordError, NoQuietSegmentError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    started = time.perf_counter()

    def progress(message):  # INFO: hidden by -q (the old --quiet)
        say(f"[{time.perf_counter() - started:6.1f} s] {message}")

    sources = ", ".join(f"{r.source} ({len(r.time)} samples)" for r in records)
    progress(f"diagnosing {model!r} on {sources}")
    record = records[0] if len(records) == 1 else records
    try:
        result = diagnose(
            record, model, noise=noise, n_starts=args.n_starts, rng=np.random.default_rng(args.seed), progress=progress
        )
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(result.summary())
    for path in write_outputs(result, record, json_path=args.json, out_dir=args.out):
        progress(f"wrote {path}")
    progress(f"done in {result.seconds:.1f} s")
    return 0
