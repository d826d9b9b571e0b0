"""Time the identification: least squares alone, and the whole ``study`` command.

Prints, for this machine and its current load:

* the baseline: one forward evaluation of the GPI for 36 parameter sets (one emcee step
  evaluates two halves of that) on the 7001-sample record;
* least squares (8 starts) on ``data/bench_clean.csv`` and ``data/bench_default.csv``:
  seconds, and the ratio to the baseline;
* the whole ``python -m identify study data/bench_default.csv`` run in a subprocess, as a
  user runs it: total wall time against the 5-minute budget, each phase (from the
  manifest), steps sampled, milliseconds per step and its ratio to the baseline (the
  sampler's and backend's overhead), and whether the chain converged.

Usage: ``python benchmarks/study.py [--out DIR] [--skip-study]``. The load average is
printed too: other processes on a 2-core machine slow everything down.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def baseline_seconds(record, repeats=20) -> float:
    """Median wall time of one 36-row forward evaluation [s]."""
    from model import Model

    model = Model()
    theta = np.repeat(model.default_theta()[None, :], 36, axis=0)
    model.evaluate(theta, record.time, record.current)  # compile / warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model.evaluate(theta, record.time, record.current)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="results folder for the study (default: a temporary one)")
    parser.add_argument("--skip-study", action="store_true", help="only the least-squares timings")
    args = parser.parse_args(argv)

    from identify.data.records import load_record
    from identify.fitting.lsq import fit_least_squares
    from identify.fitting.parametrisation import normalised_model
    from model import Model

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} (1 min)")
    default = load_record(ROOT / "data" / "bench_default.csv")
    base = baseline_seconds(default)
    print(f"baseline: one forward evaluation of 36 parameter sets x {len(default.time)} samples = {1e3 * base:.2f} ms")

    for name in ("bench_clean", "bench_default"):
        rec = load_record(ROOT / "data" / f"{name}.csv")
        t0 = time.perf_counter()
        fit = fit_least_squares(rec, normalised_model(Model()), rng=np.random.default_rng(0))
        seconds = time.perf_counter() - t0
        print(
            f"least squares, {name}: {seconds:.1f} s (= {seconds / base:.0f} x baseline); rms {fit.rms:.4f} um = "
            f"{fit.rms / fit.noise.sigma:.3f} x noise sigma; {fit.n_agree}/{fit.n_starts} starts agree; "
            f"{'converged' if fit.success else 'NOT converged'}"
        )
    if args.skip_study:
        return 0

    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="study-bench-"))
    command = [
        sys.executable,
        "-m",
        "identify",
        "study",
        str(ROOT / "data" / "bench_default.csv"),
        "--out",
        str(out),
        "--progress",
        "off",
        "--force",
    ]
    print("running:", " ".join(command[1:]))
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        print(done.stderr[-3000:])
        print(f"study FAILED with exit code {done.returncode}")
        return 1
    manifest = json.loads((out / "manifest.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    phases = manifest["runs"][-1].get("phases", {})
    post = summary["posterior"]
    per_step = phases.get("posterior", float("nan")) / max(post["n_steps"], 1)
    print(f"study wall time: {wall:.1f} s = {wall / 300:.2f} x the 5-minute budget")
    for phase, seconds in phases.items():
        print(f"  {phase:<16} {seconds:7.1f} s")
    print(
        f"posterior: {post['n_steps']} steps x {post['n_walkers']} walkers, {1e3 * per_step:.2f} ms/step "
        f"(= {per_step / base:.2f} x baseline), tau_max {post['tau_max']}, acceptance "
        f"{post['acceptance_fraction']:.3f}, "
        f"{'converged' if post['converged'] else 'NOT converged'}"
    )
    print(f"load average after: {os.getloadavg()[0]:.2f}; results in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
