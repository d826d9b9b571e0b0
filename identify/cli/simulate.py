"""``python -m identify simulate``: write a virtual-bench measurement (CSV) and its truth (JSON sidecar).

Example::

    python -m identify simulate --out data/run.csv --effects thermal,creep_amplitude=0.02 --seed 7

writes ``data/run.csv`` (``time,current,displacement`` in s, A, um) and ``data/run.json``
(the whole truth: parameters by name, effects, noise, seed, sampling, readings,
software version and git commit). The same options and seed give the same CSV bytes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..defaults import DEFAULT_FS, DEFAULT_NOISE_SIGMA, EFFECT_NAMES, INPUT_READINGS
from . import options

DRIVES = ("paper", "holds")

__all__ = ["HELP", "add_arguments", "run"]

HELP = "simulate a bench measurement (paper input, Table 1 transducer, hidden effects, sensor noise)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``simulate`` options to ``parser``."""
    parser.add_argument(
        "--out",
        required=True,
        type=lambda text: Path(options.file_path(text)),
        help="CSV file to write; the truth goes to the same stem .json",
    )
    parser.add_argument(
        "--effects",
        default="",
        metavar="SPEC",
        help=(
            "comma-separated hidden effects: a name switches an effect on with its test parameters, "
            "PARAM=VALUE sets one parameter, e.g. thermal,creep_amplitude=0.02. Effects: " + ", ".join(EFFECT_NAMES)
        ),
    )
    parser.add_argument(
        "--noise",
        type=float,
        default=DEFAULT_NOISE_SIGMA,
        metavar="SIGMA",
        help=f"sensor noise standard deviation in um (default {DEFAULT_NOISE_SIGMA})",
    )
    parser.add_argument(
        "--noise-rho",
        type=float,
        default=0.0,
        metavar="RHO",
        help="lag-1 autocorrelation of AR(1) noise, -1 < RHO < 1 (default 0: white)",
    )
    parser.add_argument(
        "--fs", type=float, default=DEFAULT_FS, metavar="HZ", help=f"sampling rate in Hz (default {DEFAULT_FS:g})"
    )
    parser.add_argument(
        "--input",
        default="literal",
        metavar="READING|FILE.csv",
        help="the drive: a reading of the paper's eq. (16) decay (literal, centred; default literal), or a CSV "
        "file with the columns time,current (e.g. a designed next_input.csv)",
    )
    parser.add_argument(
        "--drive",
        choices=DRIVES,
        default="paper",
        help="the bench's drive when --input is a reading: the paper's, or cycles that fall and rise again, a hold "
        "at 4.5 A and a quiet end (holds); default paper",
    )
    parser.add_argument(
        "--truth",
        default=None,
        metavar="RUN.json",
        help="simulate the transducer of this sidecar (its model, parameters and noise) instead of --effects",
    )
    parser.add_argument(
        "--seed", type=options.seed, default=0, metavar="N", help="seed of the noise generator, >= 0 (default 0)"
    )


def run(args) -> int:
    """Simulate and write the record and its sidecar; 0 on success, 2 on a bad option."""
    # deferred (--help imports every command's module): data.records: numpy, +110 ms
    from ..data.records import write_record
    from ..output.results import git_head

    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        print(
            f"simulate: error: --out must name a .csv file (the truth goes beside it as .json), got {out}",
            file=sys.stderr,
        )
        return 2
    try:
        simulation = _simulation(args)
    except ValueError as exc:
        print(f"simulate: error: {exc}", file=sys.stderr)
        return 2
    truth = dict(simulation.truth)
    truth["software"] = {**truth["software"], "git_commit": git_head()}
    truth["command"] = _command_line(args)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_record(out, simulation.record, sidecar=truth)
    size = truth["effect_size"]
    effects = ", ".join(f"{n}({', '.join(f'{k}={v:g}' for k, v in p.items())})" for n, p in truth["effects"].items())
    print(f"wrote {out} ({truth['n_samples']} samples at {truth['fs']:g} Hz) and {out.with_suffix('.json')}")
    print(f"  effects: {effects or 'none'}")
    print(f"  noise: sigma {truth['noise']['sigma']:g} um, rho {truth['noise']['rho']:g}; seed {truth['seed']}")
    if truth["effects"]:
        print(
            f"  effect size: RMS {size['rms_um']:.3g} um, max {size['max_abs_um']:.3g} um "
            f"({size['max_pct_of_full_scale']:.2g} % of the {size['full_scale_um']:.4g} um full scale)"
        )
    return 0


def _command_line(args) -> str:
    """The options as a reproducible command line (no absolute paths beyond what was given)."""
    parts = ["python -m identify simulate", f"--out {args.out}"]
    if getattr(args, "truth", None):
        parts.append(f"--truth {args.truth}")
    elif args.effects:
        parts.append(f"--effects {args.effects}")
    if getattr(args, "drive", "paper") != "paper":
        parts.append(f"--drive {args.drive}")
    parts += [
        f"--noise {args.noise:g}",
        f"--noise-rho {args.noise_rho:g}",
        f"--fs {args.fs:g}",
        f"--input {args.input}",
        f"--seed {args.seed}",
    ]
    return " ".join(parts)


def _drive_file(path: str):
    """``(time, current)`` of a drive file (columns time,current), or a one-line error naming it."""
    # deferred (--help imports every command's module): data.records: numpy, +110 ms
    from ..data.records import load_record

    drive = load_record(path, output_column=None, min_samples=2)
    return drive.time, drive.current


def _simulation(args):
    """The simulation the options ask for: the bench's transducer with --effects, or --truth's, on the
    paper's drive, the drive with holds or a given drive file."""
    # deferred (--help imports every command's module): bench.synthetic: the model and numba, +340 ms
    from ..bench.synthetic import simulate, simulate_like

    given = None if args.input in INPUT_READINGS else _drive_file(args.input)
    if args.truth is not None:
        try:
            truth = json.loads(Path(args.truth).read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{args.truth}: cannot read the truth ({exc})") from None
        if given is None:
            # deferred: --help imports every command's module; model.signals loads numpy/scipy (+0.26 s CPU)
            from model.signals import drive_current

            given = drive_current(args.drive, fs=args.fs, reading=args.input)
        return simulate_like(truth, *given, seed=args.seed)
    return simulate(
        args.effects,
        noise_sigma=args.noise,
        noise_rho=args.noise_rho,
        fs=args.fs,
        input_reading=args.input if given is None else "literal",
        seed=args.seed,
        drive=args.drive,
        current=given,
    )
