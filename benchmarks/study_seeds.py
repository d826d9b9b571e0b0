"""Wall time of ``python -m identify study`` over seeds, optionally A/B against other source trees.

For every seed, runs the command line as a user does (a subprocess, report included) once
per source tree, alternating the trees so that a change in the machine's load hits both,
and prints one line per run: wall time [s], the study's CPU time [s] (user + system of
the subprocess), the 1-minute load average before and after (a shared 2-core machine),
steps, tau_max, whether the chain converged, the results folder's size and posterior.nc's
[MB], and the phases from the manifest (least squares, posterior, report, ...).
``--warm-up`` first runs a 50-step study per tree (numba's cache of a fresh tree is
compiled then, not in the first timed run).

Usage::

    python benchmarks/study_seeds.py data/bench_clean.csv --seeds 0-4
    python benchmarks/study_seeds.py data/bench_default.csv --effects thermal --seeds 0 \\
        --tree /path/to/baseline-worktree --tree .

A tree is a checkout of this repository: its ``identify`` and ``model`` are imported
(PYTHONPATH and working directory set to it). Default: this checkout only.
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

ROOT = Path(__file__).resolve().parent.parent


def _seeds(text):
    seeds = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    return seeds


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_one(tree: Path, data: Path, effects: str, seed: int, out: Path, extra=()) -> dict:
    command = [
        sys.executable,
        "-m",
        "identify",
        "study",
        str(data),
        "--out",
        str(out),
        "--seed",
        str(seed),
        "--force",
        "--progress",
        "off",
        *extra,
    ] + (["--effects", effects] if effects else [])
    env = dict(os.environ, PYTHONPATH=str(tree))
    load_before = os.getloadavg()[0]
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    sizes = {p.name: p.stat().st_size for p in out.rglob("*") if p.is_file()} if out.exists() else {}
    row = {
        "tree": str(tree),
        "seed": seed,
        "wall": wall,
        "cpu": _children_cpu() - cpu0,
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
        "exit": done.returncode,
        "folder_mb": sum(sizes.values()) / 1e6,
        "posterior_nc_mb": sizes.get("posterior.nc", 0) / 1e6,
    }
    if done.returncode not in (0, 1):
        row["error"] = done.stderr[-500:]
        return row
    post = json.loads((out / "summary.json").read_text())["posterior"]
    manifest = json.loads((out / "manifest.json").read_text())
    phases = (manifest.get("runs") or [{}])[-1].get("phases", {})
    row.update(steps=post["n_steps"], tau_max=post["tau_max"], converged=post["converged"], phases=phases)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--effects", default="")
    parser.add_argument("--seeds", default="0", help="e.g. 0-4 or 0,2")
    parser.add_argument("--tree", action="append", help="source tree (repeat for A/B); default: this checkout")
    parser.add_argument("--json", default=None, help="also write the rows to this JSON file")
    parser.add_argument("--warm-up", action="store_true", help="a 50-step study per tree first (numba's cache)")
    args = parser.parse_args(argv)
    trees = [Path(t).resolve() for t in (args.tree or [ROOT])]
    data = Path(args.data).resolve()
    rows = []
    print(f"{os.cpu_count()} cores; {data.name} effects '{args.effects or 'none'}'")
    if args.warm_up:
        for tree in trees:
            with tempfile.TemporaryDirectory(prefix="study-seeds-") as tmp:
                warm = ("--max-steps", "50", "--no-report", "--n-starts", "1")
                row = run_one(tree, data, args.effects, 0, Path(tmp) / "out", warm)
            print(f"warm-up {tree.name}: {row['wall']:.1f} s, exit {row['exit']}", flush=True)
    print(
        f"{'tree':<28} {'seed':>4} {'wall s':>7} {'CPU s':>6} {'load':>11} {'steps':>6} {'tau':>6} {'conv':>5} "
        f"{'MB':>5} {'nc MB':>5}  phases [s]"
    )
    for seed in _seeds(args.seeds):
        for tree in trees:
            with tempfile.TemporaryDirectory(prefix="study-seeds-") as tmp:
                row = run_one(tree, data, args.effects, seed, Path(tmp) / "out")
            rows.append(row)
            if "error" in row:
                print(f"{tree.name:<28} {seed:>4} FAILED exit {row['exit']}: {row['error']}")
                continue
            phases = ", ".join(f"{k} {v:.1f}" for k, v in row["phases"].items() if v >= 0.05)
            load = f"{row['load_before']:5.2f}-{row['load_after']:<5.2f}"
            print(
                f"{tree.name:<28} {seed:>4} {row['wall']:7.1f} {row['cpu']:6.1f} {load} {row['steps']:>6} "
                f"{row['tau_max']:6.1f} {str(row['converged']):>5} {row['folder_mb']:5.1f} "
                f"{row['posterior_nc_mb']:5.1f}  {phases}",
                flush=True,
            )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
