"""``python -m identify export DIR --out OUT``: the identified model and its inverse as C and FMI units.

From a finished study (:func:`identify.export.export`), writes ``OUT`` (default ``DIR/export``)
all at once:

``OUT/c/``
    C99 source and header, libm only: the forward model (GPI and the study's effects) and its
    inverse as streaming step functions (a state struct, one sample in, one sample out), the
    parameters of the posterior median (or ``--draw N``), a README with the compiler line and
    a usage example.
``OUT/model.fmu``, ``OUT/compensator.fmu``
    FMI 2.0 co-simulation units built from the same C with the local compiler (``$CC``, else
    cc, gcc, clang): input ``current``, output ``displacement``; input ``target``, output
    ``current`` with the current range as parameters. Their model description carries the
    study's provenance.
``OUT/export.json``
    What was exported.

Exit code 0 when written; 2 with one ``error:`` line and nothing written (a folder that is not
a finished study, an unknown draw, an effect that cannot be streamed, an ``OUT`` holding other
files); 2 also when no C compiler is found, after writing ``OUT/c/`` (the line names the
compilers tried).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..logs import say
from . import options
from .predict import parse_span, timed_progress

__all__ = ["HELP", "add_arguments", "run"]

HELP = "export the identified model and its inverse as C source and FMI 2.0 co-simulation units (FMUs)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", metavar="DIR", help="results folder of a finished `python -m identify study`")
    parser.add_argument("--out", default=None, metavar="OUT", help="output folder (default DIR/export)")
    parser.add_argument(
        "--draw",
        type=options.integer(0, None, "an integer >= 0 (a posterior draw)"),
        default=None,
        metavar="N",
        help="export posterior draw N (an index into the posterior samples) instead of the posterior median",
    )
    parser.add_argument(
        "--current-range",
        default=None,
        metavar="LO:HI",
        help="the compensator's current limits (default as compensate: 0:5 for a study in A, else the training "
        "drive's range)",
    )
    parser.add_argument(
        "--horizon",
        type=options.positive_float,
        default=None,
        metavar="SECONDS",
        help="the run's length for creep's logarithmic modes and sensor_drift (default the study record's duration)",
    )


def run(args) -> int:

    # deferred (--help imports every command's module): workflows.use: numpy, scipy, numba, matplotlib, +1.6 s
    from ..export import CompilerError, ExportError, export
    from ..workflows.use import UseError

    started, progress = timed_progress()
    out = Path(args.out) if args.out else Path(args.dir) / "export"
    try:
        limits = parse_span(args.current_range, "--current-range") if args.current_range else None
        result = export(args.dir, out, draw=args.draw, horizon=args.horizon, current_range=limits, progress=progress)
    except CompilerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (UseError, ExportError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    spec = result.spec
    effects = ", ".join(spec.effects) or "none"
    print(
        f"exported the {spec.provenance['parameters']} of {spec.provenance['study']}: {spec.n_operators} operators, "
        f"effects: {effects}"
    )
    lo, hi = spec.current_range
    print(
        f"compensator: current {lo:g}..{hi:g} {spec.units['input']}, output scale {spec.output_scale:.6g} "
        f"{spec.units['output']}"
    )
    for note in spec.notes:
        say(f"note: {note}")
    print(
        f"wrote {out / 'c'}, {out / 'model.fmu'} and {out / 'compensator.fmu'} ({time.perf_counter() - started:.1f} s)"
    )
    return 0
