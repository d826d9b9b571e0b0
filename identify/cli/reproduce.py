"""``python -m identify reproduce DIR [--out NEWDIR]``: rerun a run from its manifest and compare."""

from __future__ import annotations

import sys

from . import options

__all__ = ["HELP", "add_arguments", "run"]

HELP = "rerun a finished run from its manifest.json (data hash checked) and say whether it reproduces bit for bit"


def add_arguments(parser) -> None:
    """Options of the ``reproduce`` command."""
    parser.add_argument(
        "directory", type=options.existing_folder, help="results folder of the run (holds manifest.json)"
    )
    parser.add_argument(
        "--out",
        default=None,
        type=options.folder_path,
        help="a new folder for the rerun (default: DIR-reproduced); never an existing study",
    )
    parser.add_argument(
        "--data",
        default=None,
        type=options.existing_file,
        help="the run's data file, if it moved (its SHA-256 must still match the manifest)",
    )


def run(args) -> int:
    """Exit code 0: reproduced exactly; 1: it differs (printed what); 2: cannot rerun (manifest, data,
    damaged results, an existing --out folder)."""
    # deferred (--help imports every command's module): workflows.reproduce: numpy, +100 ms
    from ..workflows.reproduce import REPORT_FILE, DataChangedError, ManifestError, reproduce

    try:
        report = reproduce(args.directory, args.out, data=args.data)
    except (ManifestError, DataChangedError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(report.describe())
    print(f"  details: {report.rerun}/{REPORT_FILE}")
    return 0 if report.identical else 1
