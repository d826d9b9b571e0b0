"""How long ``python -m identify --help`` and every command's ``--help`` take, and what they import.

Each is run as its own process (as a user types it), ``--repeat`` times; prints the best
and the median wall time and whether numpy, numba, scipy or matplotlib were imported
(``-X importtime``). Target: under 0.3 s, none of them imported.

Usage: ``python benchmarks/cli_help.py [--repeat N]``
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identify.commands import COMMANDS

HEAVY = ("numpy", "numba", "scipy", "matplotlib")


def run_help(command: str) -> tuple[float, list[str]]:
    """Wall time [s] of ``python -X importtime -m identify COMMAND --help`` and the heavy modules it imported."""
    argv = [sys.executable, "-X", "importtime", "-m", "identify", *command.split(), "--help"]
    started = time.perf_counter()
    result = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, check=True)
    seconds = time.perf_counter() - started
    imported = {line.split("|")[-1].strip() for line in result.stderr.splitlines() if line.startswith("import time:")}
    return seconds, [name for name in HEAVY if name in imported]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per command (default 5)")
    args = parser.parse_args(argv)
    print(f"{'command':<24} {'best [s]':>9} {'median [s]':>11}  heavy imports")
    for command in ["", *COMMANDS]:
        runs = [run_help(command) for _ in range(args.repeat)]
        times = [seconds for seconds, _ in runs]
        heavy = sorted({name for _, names in runs for name in names})
        label = f"{command or '(none)'} --help"
        print(f"{label:<24} {min(times):9.3f} {statistics.median(times):11.3f}  {', '.join(heavy) or 'none'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
