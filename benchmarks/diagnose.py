"""Wall time of ``python -m identify diagnose`` at 7001 and 70001 samples (targets: < 1 min, < 5 min).

Run from the repository root::

    python benchmarks/diagnose.py            # both sizes
    python benchmarks/diagnose.py --quick    # 7001 samples only

Simulates a virtual-bench record (paper input, Table 1, a hidden creep of ~2x the noise
in RMS, seed 5) at 100 Hz and 1 kHz, runs the diagnosis command in a fresh process
(numba compilation cached, so a first run on a new machine is slower), and prints the
wall time, the verdict, and the ratio of the 70001-sample time to the 7001-sample one
(10x the samples; the screening and the short refits run on a decimated copy, so the
ratio stays well below 10). The machine is shared: the figure is one run, not a best of
several.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_once(fs: float, workdir: Path) -> tuple[float, dict]:
    """Simulate at ``fs`` Hz, diagnose in a subprocess; (seconds, diagnosis JSON)."""
    csv = workdir / f"creep_{int(fs)}.csv"
    out = workdir / f"creep_{int(fs)}_diagnosis.json"
    subprocess.run(
        [sys.executable, "-m", "identify", "simulate", "--out", str(csv), "--effects", "creep_amplitude=0.0153",
         "--fs", str(fs), "--seed", "5"],
        check=True, cwd=ROOT, capture_output=True,
    )  # fmt: skip
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "identify", "diagnose", str(csv), "--json", str(out), "--quiet"],
        check=True, cwd=ROOT, capture_output=True,
    )  # fmt: skip
    return time.perf_counter() - started, json.loads(out.read_text())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="7001 samples only")
    args = parser.parse_args(argv)
    sizes = [(100.0, 60.0)] if args.quick else [(100.0, 60.0), (1000.0, 300.0)]
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fs, target in sizes:
            seconds, result = run_once(fs, Path(tmp))
            times[fs] = seconds
            n = int(round(70 * fs)) + 1
            print(
                f"diagnose, {n:6d} samples: {seconds:6.1f} s (target < {target:.0f} s) "
                f"-> {result['status']}{' (' + result['missing'] + ')' if result['missing'] else ''}, "
                f"RMS {result['rms']:.3f} um vs noise {result['noise_sigma']:.3f} um"
            )
    if len(times) == 2:
        print(f"ratio 70001 / 7001 samples: {times[1000.0] / times[100.0]:.2f} (10x the samples)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
