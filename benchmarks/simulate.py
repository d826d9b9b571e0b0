"""Speed of the virtual bench: 70 s at 1 kHz (70 001 samples) with every effect on.

Prints the best of several runs (after a warm-up that compiles the numba kernels) for
the plain GPI (the baseline, measured in the same run), the full simulation with every
effect at its test parameters, and writing the CSV + sidecar. Target: the simulation
well under one second. Then, for identification, the cost of one batch evaluation
(W = 64 parameter sets, paper input at 100 Hz) with each single effect, as a ratio to the
plain GPI measured in the same run.

Usage: ``python benchmarks/simulate.py [--repeat N]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from identify.bench import simulate
from identify.data.records import write_record
from model import EFFECTS, TABLE1, Model, gpi, paper_current


def best_of(function, repeat):
    """Smallest wall time [s] of ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    spec = ",".join(EFFECTS)
    _, current = paper_current(fs=1000.0)
    sim = simulate(spec, fs=1000.0, seed=1)  # warm-up: compiles every kernel
    gpi(TABLE1, current)

    plain = best_of(lambda: gpi(TABLE1, current), args.repeat)
    full = best_of(lambda: simulate(spec, fs=1000.0, seed=1), args.repeat)
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "bench.csv"
        write = best_of(lambda: write_record(out, sim.record, sim.truth), args.repeat)

    print(f"samples: {sim.record.n_samples} (70 s at 1 kHz); effects: {spec}")
    print(f"plain GPI (baseline):          {plain * 1e3:8.1f} ms")
    print(f"simulate, every effect on:     {full * 1e3:8.1f} ms  ({full / plain:.1f} x the plain GPI)")
    print(f"write CSV + sidecar:           {write * 1e3:8.1f} ms")
    print(f"target: simulation < 1000 ms -> {'met' if full < 1.0 else 'NOT met'}")

    time_100, current_100 = paper_current(fs=100.0)
    n_sets = 64
    print(f"\nbatch evaluation, W = {n_sets}, T = {time_100.size}:")
    baseline = None
    for name in [None, *EFFECTS]:
        m = Model([] if name is None else [name])
        theta = m.default_theta() if name is None else m.theta_from_dict(EFFECTS[name].get_test_parameters())
        batch = np.tile(theta, (n_sets, 1))
        m.evaluate(batch, time_100, current_100)  # warm-up
        seconds = best_of(lambda: m.evaluate(batch, time_100, current_100), args.repeat)
        baseline = seconds if name is None else baseline
        print(f"  {name or 'plain GPI (baseline)':24s} {seconds * 1e3:8.1f} ms  ({seconds / baseline:.2f} x)")


if __name__ == "__main__":
    main()
