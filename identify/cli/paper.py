"""``python -m identify paper``: Table 1 on the paper's input, as the paper's figures, with the
reading's evidence; the work is :mod:`identify.workflows.paper`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..defaults import INPUT_READINGS, READINGS
from . import options

__all__ = ["HELP", "add_arguments", "run"]

HELP = "simulate Table 1 on the paper's input: Figs. 5, 6, 8 and the evidence for the reading of eq. (5)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``paper`` options to ``parser``."""
    parser.add_argument(
        "--out",
        required=True,
        type=options.folder_path,
        metavar="DIR",
        help="folder to write the figures and paper.md into",
    )
    parser.add_argument(
        "--fs", type=float, default=100.0, metavar="HZ", help="sampling rate of the input in Hz (default 100)"
    )
    parser.add_argument(
        "--input",
        choices=INPUT_READINGS,
        default="literal",
        help="reading of eq. (16)'s decay: literal (as printed, default) or centred (as the text says)",
    )
    parser.add_argument(
        "--reading",
        choices=sorted(READINGS),
        default="swapped",
        help="reading of eq. (5): swapped (rising along eq. (6), default) or literal (rising along eq. (7))",
    )


def run(args) -> int:
    """Simulate, write the figures and ``paper.md`` into ``args.out``; 0 on success, 2 on bad options."""
    # deferred (--help imports every command's module): workflows.paper: numpy, scipy, numba, +300 ms
    from ..workflows.paper import FIGURE_FILES, paper_input, write_paper

    try:
        time, current = paper_input(args.fs, args.input)
    except ValueError as error:
        print(f"paper: {error}", file=sys.stderr)
        return 2
    chosen, other = write_paper(args.out, time, current, fs=args.fs, input_reading=args.input, reading=args.reading)
    for evidence in (chosen, other):
        print(
            f"{evidence.reading:>8} reading: rest {evidence.rest_um:9.4f} um, min {evidence.min_um:8.2f}, "
            f"max {evidence.max_um:8.2f}, smallest bound margin {evidence.smallest_margin:+.4f}"
        )
    print(f"wrote {', '.join(FIGURE_FILES.values())} and paper.md to {Path(args.out)}")
    return 0
