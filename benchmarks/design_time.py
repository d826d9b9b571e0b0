"""The ``design`` command's time on a record, for one code or several alternated.

Each run is ``python -m identify design RECORD --candidates ... --out TMP --quiet`` in a fresh
process, run from the checkout it times as the working directory and with that checkout first on
``PYTHONPATH`` (the working directory comes before ``PYTHONPATH`` on ``sys.path`` for ``-m``, so
a run from another folder would time that folder's code). With several checkouts the runs
alternate, round after round, so that the machine's drift (its speed moves by up to about 2x over
a day) falls on every code alike; the ratios are against the first checkout's runs of the same
round.

Usage::

    python benchmarks/design_time.py [--checkout DIR ...] [--rounds 2]
        [--record data/bench_default.csv] [--candidates creep,thermal,sensor_drift]

Prints per run the wall and CPU seconds, the design's own seconds (``design.json``), the drive
family and each ordered pair's confirmed gap (sd), and per round the wall ratio to the first.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def one_run(checkout: Path, record: str, candidates: str) -> dict:
    """One ``design`` run of ``checkout``'s code: its seconds and what it proposed."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "design"
        env = dict(os.environ, PYTHONPATH=str(checkout))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "identify", "design", record, "--candidates", candidates, "--out", str(out)]
            + ["--quiet"],
            cwd=checkout,
            env=env,
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode != 0:
            raise SystemExit(f"{checkout}: design failed ({done.returncode}): {done.stderr.strip()[-400:]}")
        found = json.loads((out / "design.json").read_text())
    pairs = found["best"].get("confirmed") or []
    return {
        "wall": wall,
        "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "design": found["seconds"],
        "family": found["best"]["family"],
        "gaps": [(p["truth"], p["rival"], p["gap"], p["gap_sd"]) for p in pairs],
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", action="append", type=Path, help="a checkout to time (repeat; default this one)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--record", default="data/bench_default.csv", help="relative to each checkout, or absolute")
    parser.add_argument("--candidates", default="creep,thermal,sensor_drift")
    args = parser.parse_args(argv)
    checkouts = [c.resolve() for c in (args.checkout or [ROOT])]
    for checkout in checkouts:
        if not (checkout / "identify" / "__init__.py").is_file():
            parser.error(f"--checkout {checkout}: not a checkout of this project (no identify/__init__.py)")
    for k in range(1, args.rounds + 1):
        walls = []
        for checkout in checkouts:
            run = one_run(checkout, args.record, args.candidates)
            walls.append(run["wall"])
            gaps = ", ".join(f"{t}|{r} {g:.0f} ({s:.0f})" for t, r, g, s in run["gaps"] if g is not None)
            print(
                f"round {k} {checkout}: {run['wall']:.1f} s wall, {run['cpu']:.1f} s CPU, design {run['design']:.1f} s;"
                f" {run['family']}; {gaps}",
                flush=True,
            )
        if len(walls) > 1:
            print(f"round {k} wall ratios to the first: " + " ".join(f"{w / walls[0]:.3f}" for w in walls), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
