"""The joint study of the two bundled records against each record alone: time and the shared
parameters' 95 % intervals.

Runs (unless the folder already holds them) ``python -m identify study`` on
``data/bench_default.csv`` and ``data/bench_default_holds.csv`` together and on each alone, with
``--effects thermal --seed S``, into ``OUT/joint``, ``OUT/alone1``, ``OUT/alone2``; prints each
run's wall time, load, phases and convergence, then a table of every shared free parameter:
its posterior 95 % interval from the joint study and from each record alone, and the width of the
joint interval over the narrower alone.

    python benchmarks/joint_study.py --out /tmp/joint_bench [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORDS = ("data/bench_default.csv", "data/bench_default_holds.csv")
RUNS = {"joint": RECORDS, "alone1": RECORDS[:1], "alone2": RECORDS[1:]}


def run(name: str, records, out: Path, seed: int) -> dict:
    folder = out / name
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    if not (folder / "summary.json").exists() or not json.loads((folder / "summary.json").read_text()).get("posterior"):
        command = [sys.executable, "-m", "identify", "study", *records, "--effects", "thermal", "--seed", str(seed)]
        subprocess.run([*command, "--out", str(folder), "--progress", "off", "-q"], cwd=ROOT, check=False)
    wall = time.perf_counter() - started
    manifest = json.loads((folder / "manifest.json").read_text())
    summary = json.loads((folder / "summary.json").read_text())
    last = manifest["runs"][-1]
    post = summary["posterior"]
    print(
        f"{name}: {last['seconds']:.0f} s in the study ({wall:.0f} s this call; load {load_before:.1f}-"
        f"{os.getloadavg()[0]:.1f}), {'converged' if post['converged'] else 'NOT converged'} after "
        f"{post['n_steps']} steps, tau_max {post['tau_max']:.0f}; phases "
        + ", ".join(f"{k} {v:.0f} s" for k, v in last.get("phases", {}).items())
    )
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    out = Path(args.out)
    summaries = {name: run(name, records, out, args.seed) for name, records in RUNS.items()}
    by_name = {name: {p["name"]: p for p in s["parameters"]} for name, s in summaries.items()}
    print("| parameter | joint 95 % | record 1 alone 95 % | record 2 alone 95 % | joint width / narrower alone |")
    print("|---|---|---|---|---|")
    ratios = []
    for entry in summaries["joint"]["parameters"]:
        name = entry["name"]
        if not entry["vary"] or name not in by_name["alone1"] or not by_name["alone1"][name]["vary"]:
            continue
        alone = [by_name[k][name] for k in ("alone1", "alone2")]
        widths = [a["hi95"] - a["lo95"] for a in alone]
        ratio = (entry["hi95"] - entry["lo95"]) / min(widths)
        ratios.append(ratio)
        cells = [f"[{e['lo95']:.4g}, {e['hi95']:.4g}]" for e in (entry, *alone)]
        print(f"| {name} | {' | '.join(cells)} | {ratio:.2f} |")
    narrower = sum(r < 1 for r in ratios)
    print(f"joint narrower than the narrower alone for {narrower} of {len(ratios)} shared parameters")


if __name__ == "__main__":
    main()
