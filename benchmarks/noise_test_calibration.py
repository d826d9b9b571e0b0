"""Are the noise tests calibrated when the noise reference comes from a short quiet segment?

Run from the repository root::

    python benchmarks/noise_test_calibration.py [--draws 1000] [--seed 0]

Each draw is pure AR(1) noise (no structure at all): the record of the paper's input length
(70 s, the first 10 s quiet) at 100 Hz and at 1 kHz. The noise model is fitted to the quiet
segment and the four tests are applied to the record exactly as the diagnosis does it
(:func:`identify.diagnosis.residuals.residual_profile`; the level test with the drive as the
model's output, a level the noise does not depend on). Under the null each test's ``z``
should have mean 0, sd 1 and a normal tail (the level test: at most a normal tail, it is
conservative by construction); the diagnosis calls a residual structured at ``z > 5``
(:attr:`identify.diagnosis.Thresholds.z_critical`). Printed per noise correlation
``phi`` and rate: the mean, sd and maximum of ``z``, and how often it passes 3 and 5
(a normal tail: 0.13 % and 3e-7).
"""

from __future__ import annotations

import argparse
import time as clock

import numpy as np
from scipy.signal import lfilter

from identify.diagnosis.residuals import residual_profile
from model import paper_current


def ar1(rng, n, phi):
    """Stationary AR(1) noise of unit marginal sd."""
    e = rng.standard_normal(n)
    e[1:] *= np.sqrt(1 - phi * phi)
    return lfilter([1.0], [1.0, -phi], e)


def null_z(rng, phi, fs, draws):
    """z of the four tests on ``draws`` pure-noise records at ``fs`` Hz, as the diagnosis computes them."""
    time, current = paper_current(fs)
    quiet = slice(0, int(np.searchsorted(time, 10.0, side="right")))
    out = {"variance": [], "ljung_box": [], "low_frequency": [], "level": []}
    for _ in range(draws):
        residual = ar1(rng, time.size, phi)
        profile = residual_profile(time, current, residual, quiet, output_range=1.0, level=current)
        for name in out:
            out[name].append(profile.tests[name].z)
    return {k: np.array(v) for k, v in out.items()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--draws", type=int, default=1000, help="pure-noise records per setting (default 1000; 1/10 at 1 kHz)"
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.draws < 10:
        parser.error(f"--draws must be at least 10, got {args.draws}")
    rng = np.random.default_rng(args.seed)
    print("| fs | phi | draws | test | mean z | sd z | max z | z > 3 | z > 5 |")
    print("|---|---|---|---|---|---|---|---|---|")
    start = clock.perf_counter()
    for fs, draws in ((100.0, args.draws), (1000.0, max(args.draws // 10, 10))):
        for phi in (0.0, 0.35, 0.7):
            z = null_z(rng, phi, fs, draws)
            for name, values in z.items():
                print(
                    f"| {fs:g} Hz | {phi:g} | {draws} | {name} | {values.mean():.2f} | {values.std():.2f} | "
                    f"{values.max():.2f} | {100 * np.mean(values > 3):.1f} % | {100 * np.mean(values > 5):.1f} % |",
                    flush=True,
                )
    print(f"\n{clock.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
