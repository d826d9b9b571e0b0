"""Speed of each effect's kernel on the time grid a CSV record gives, against an exactly uniform one.

Run from the repository root::

    python benchmarks/effect_kernels.py            # T = 7001 and 70001, 26 parameter sets
    python benchmarks/effect_kernels.py --quick    # T = 70001 only, fewer repeats

A record read from text has sample steps that differ in their last bits (at 1 kHz, times
like ``12.345`` give steps of 1 ms +- 1e-15 s that change at most samples); an exactly
uniform grid (``k * 2**-10`` s) has one step. The filters of the effects (``thermal``'s
nodes, ``creep``'s modes, ``lag``) need ``exp(-step / tau)`` per step and mode, so a kernel
that recomputes them whenever the step changes pays for the CSV grid, one that tabulates
them per distinct step does not. Prints, per effect, the best time of ``Model([effect])``'s
evaluation (the GPI and the effect; the plain GPI first, for reference) for ``W`` parameter
sets (the effect's test parameters, its time constants scaled over a decade; creep's
logarithmic modes on too) on the paper's input on both grids, and their ratio (1.0: the grid
does not matter).
"""

from __future__ import annotations

import argparse

import numpy as np
from shared_batch import best_time  # the best of several calls (benchmarks/shared_batch.py)

from model import EFFECTS, Model, paper_current


def grids(n_samples: int) -> dict:
    """``{label: time}``: the CSV grid (1 kHz or 100 Hz written with 3 decimals and read back)
    and an exactly uniform grid of about the same step."""
    fs = 1000.0 if n_samples > 10000 else 100.0
    csv = np.array([float(f"{k / fs:.3f}") for k in range(n_samples)])
    exact_step = 2.0 ** round(np.log2(1.0 / fs))
    return {"csv": csv, "uniform": np.arange(n_samples) * exact_step}


#: parameters set beside the test parameters, so every part of a kernel runs (creep's
#: logarithmic modes, 12-24 of them, are off in its test parameters)
EXTRA = {"creep": {"creep_log_rate": 0.02, "creep_log_onset": 0.01}}


def parameter_sets(m: Model, name: str, n_sets: int, rng) -> np.ndarray:
    """``(W, P)`` full vectors of ``m`` (the GPI plus effect ``name``): Table 1 and the
    effect's test parameters (and :data:`EXTRA`), each of the effect's time constants (unit
    ``s``, > 0) scaled by 10**U(-0.5, 0.5), within bounds."""
    effect = EFFECTS[name]
    values = dict(effect.get_test_parameters(), **EXTRA.get(name, {}))
    rows = np.tile(m.theta_from_dict(values), (n_sets, 1))
    for p in effect.parameters:
        j = m.names.index(p.name)
        if p.unit == "s" and rows[0, j] > 0:
            rows[:, j] = np.clip(rows[:, j] * 10 ** rng.uniform(-0.5, 0.5, n_sets), p.lower, p.upper)
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="T = 70001 only, 3 repeats")
    parser.add_argument("--sets", type=int, default=26, help="parameter sets per call (default 26: a Jacobian's)")
    args = parser.parse_args(argv)
    sizes = [70001] if args.quick else [7001, 70001]
    repeats = 3 if args.quick else 7
    rng = np.random.default_rng(0)
    print(
        f"Model([effect]).evaluate for {args.sets} parameter sets, best of {repeats}: CSV grid vs exactly uniform grid"
    )
    print(f"{'effect':<18}{'T':>7}{'csv (ms)':>11}{'uniform (ms)':>14}{'ratio':>8}")
    for n_samples in sizes:
        for name in ["(plain GPI)"] + sorted(EFFECTS):
            m = Model() if name.startswith("(") else Model([name])
            thetas = (
                np.tile(m.default_theta(), (args.sets, 1))
                if name.startswith("(")
                else parameter_sets(m, name, args.sets, rng)
            )
            times = {}
            for label, t in grids(n_samples).items():
                current = np.interp(t, *paper_current(fs=1000.0))
                times[label] = best_time(lambda: m.evaluate(thetas, t, current), repeats)
            ratio = times["csv"] / times["uniform"]
            print(f"{name:<18}{n_samples:>7}{1e3 * times['csv']:>11.2f}{1e3 * times['uniform']:>14.2f}{ratio:>8.2f}")


if __name__ == "__main__":
    main()
