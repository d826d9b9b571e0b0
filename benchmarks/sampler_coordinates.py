"""The sampler in near-Gaussian coordinates against the sampler in the parameters, on one record.

Fits the plain GPI (normalised) to a record by least squares, then samples its posterior
twice from the same walker start and generator seed: proposals in the parameters
(``coordinates="identity"``, the sampler before issue 19) and in
:class:`identify.fitting.coordinates.GPICoordinates` (``"gpi"``, the default). Both target
the same posterior of the parameters, so their estimates must agree within Monte Carlo
error. Prints, per sampler, steps to convergence, tau_max, seconds and ms per step; per
parameter, the difference of the posterior means and of the 2.5 % / 97.5 % quantiles in
units of their combined Monte Carlo standard error (ArviZ's MCSE for the mean; for a
quantile, the standard error of the quantile from its ESS), and the ratio of the sds.

Usage: ``python benchmarks/sampler_coordinates.py [RECORD] [--seed S] [--max-steps N] [--out DIR]``
(default ``data/bench_clean.csv``; both must converge for the comparison to mean anything,
which the identity sampler needs tens of thousands of steps for on the bundled records).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("record", nargs="?", default=str(ROOT / "data" / "bench_clean.csv"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, default=60000)
    parser.add_argument("--out", default=None, help="folder for the two chains (default: a temporary one)")
    args = parser.parse_args(argv)

    import arviz as az

    from identify.data.records import load_record
    from identify.fitting.lsq import fit_least_squares
    from identify.fitting.parametrisation import normalised_model
    from identify.fitting.posterior import LogPosterior, initial_walkers, sample_posterior
    from model import Model

    record = load_record(args.record)
    fit = fit_least_squares(record, normalised_model(Model()), rng=np.random.default_rng(args.seed))
    log_post = LogPosterior(record, fit.model, fit.noise)
    free = log_post.free
    mean, cov = fit.theta[free], fit.covariance[np.ix_(free, free)]
    out = Path(args.out or tempfile.mkdtemp(prefix="coords_"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"record {args.record}: {record.time.size} samples; load average {os.getloadavg()[0]:.2f}")
    results = {}
    for coords in ("gpi", "identity"):
        t0 = time.perf_counter()
        res = sample_posterior(
            log_post,
            lambda n, r: initial_walkers(log_post, mean, cov, n, r),
            out / f"chain_{coords}.h5",
            np.random.default_rng(args.seed),
            max_steps=args.max_steps,
            coordinates=coords,
            progress=False,
        )
        seconds = time.perf_counter() - t0
        results[coords] = res
        print(
            f"{coords:8s}: {'converged' if res.converged else 'NOT converged'}, {res.n_steps} steps, tau_max "
            f"{res.tau_max:.1f}, {seconds:.1f} s ({1e3 * seconds / res.n_steps:.2f} ms per step), "
            f"{res.samples.shape[0]} samples"
        )
    a, b = results["gpi"], results["identity"]
    print("\nparameter   d(mean)/mcse   d(q2.5)/se   d(q97.5)/se   sd ratio (gpi/identity)")
    worst = 0.0
    for j, name in enumerate(log_post.names):
        xa, xb = a.samples[:, j], b.samples[:, j]
        ess_a = float(az.ess(xa[None, :]))
        ess_b = float(az.ess(xb[None, :]))
        se_mean = np.hypot(xa.std() / np.sqrt(ess_a), xb.std() / np.sqrt(ess_b))
        row = [(xa.mean() - xb.mean()) / se_mean]
        for q in (0.025, 0.975):
            # standard error of a quantile: sqrt(q (1-q) / ESS) / density, density from the sd (normal approximation)

            def dens(x):
                return np.exp(-0.5 * 1.959964**2) / (np.sqrt(2 * np.pi) * x.std())

            se = np.hypot(np.sqrt(q * (1 - q) / ess_a) / dens(xa), np.sqrt(q * (1 - q) / ess_b) / dens(xb))
            row.append((np.quantile(xa, q) - np.quantile(xb, q)) / se)
        worst = max(worst, *np.abs(row))
        print(f"{name:10s} {row[0]:+12.2f} {row[1]:+12.2f} {row[2]:+13.2f} {xa.std() / xb.std():12.3f}")
    print(f"\nlargest |difference| / standard error: {worst:.2f} (over {3 * len(log_post.names)} comparisons)")
    print(f"speed-up in steps: {b.n_steps / a.n_steps:.1f}x; in tau_max: {b.tau_max / a.tau_max:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
