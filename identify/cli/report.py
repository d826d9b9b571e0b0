"""``python -m identify report DIR``: the uncertainty report of a finished study.

Reads the results folder ``DIR`` written by ``python -m identify study`` and writes
every figure as ``DIR/<name>.png`` and ``DIR/report.html`` (one page showing those PNGs by
paths relative to the folder: it opens in any browser without a server, from the folder or a
copy of it). Nothing is refitted; see
:mod:`identify.output.report` for what the page shows. ``study`` runs this at its end; run it
again after adding ``DIR/diagnosis.json`` or to redraw with other draws.

Example::

    python -m identify report reports/default
"""

from __future__ import annotations

import argparse
import sys
import time as _time
from pathlib import Path

from ..data.locks import FolderLock
from . import options

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write DIR/report.html (a page with credible bands) and its figures as PNGs from a finished study"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "dir", metavar="DIR", type=options.existing_folder, help="results folder written by `python -m identify study`"
    )
    parser.add_argument(
        "--draws",
        type=options.integer(2, None, "an integer >= 2"),
        default=200,
        help="posterior draws pushed through the model for the bands, >= 2 (default 200)",
    )
    parser.add_argument(
        "--seed", type=options.seed, default=0, help="seed of the generator choosing the draws, >= 0 (default 0)"
    )


def run(args) -> int:
    """Write the report; exit code 2 with a one-line message for a folder that cannot be reported on."""
    # deferred (--help imports every command's module): output.report: numpy, scipy, matplotlib, +1.4 s; locks +7 ms
    import numpy as np

    # deferred: --help imports every command's module; output.report loads numpy/scipy (+1.21 s CPU)
    from ..fitting.posterior import ChainFileError, chain_info
    from ..output.report import ResultsError, write_report

    started = _time.perf_counter()
    try:
        with FolderLock(args.dir, command=f"python -m identify report {args.dir}"):  # no study writes meanwhile
            try:  # a chain whose steps are not those its count claims is never drawn
                chain_info(Path(args.dir) / "chain.h5")
            except ChainFileError as exc:
                raise ValueError(f"{exc}; delete it and rerun the study to redo the sampling") from None
            path = write_report(args.dir, n_draws=args.draws, rng=np.random.default_rng(args.seed))
    except (ResultsError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"report: {path} ({_time.perf_counter() - started:.1f} s)")
    return 0
