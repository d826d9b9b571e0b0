"""Where the walkers start: the least-squares Laplace approximation drawn in the parameters
against the same approximation carried into the sampler coordinates.

Reads a ``study`` results folder (its record and least-squares fit), builds the study's
log-posterior and prints, for draws of the Laplace approximation made

* in the parameters, with the correlation matrix raised to full rank (the start before the
  walkers were drawn in the sampler coordinates), and
* in the sampler coordinates (:func:`identify.fitting.posterior.initial_walkers`'s way, before
  its typical-set test),

the quantiles of their log-posterior drops below the least-squares solution, the share
outside the support and the share within the typical set (``chi2.ppf(1 - 1e-6, D) / 2``); a
Gaussian posterior's draws drop by half a chi-square with D degrees of freedom. Then the
drops of the walkers ``initial_walkers`` returns.

Regression case: ``python -m identify study data/bench_default.csv --out DIR --seed 4`` (the
rising envelope's amplitude a0 at 98.4 of its bound 100, a3 following it), then
``python benchmarks/initial_walkers.py DIR``: drawn in the parameters (the correlation
eigenvalues from 1.7e-12 of the largest, raised to 1e-6), none of 300 draws lay within the
typical set (47 % outside the support, the others a median 225,000 log-units below the
solution); in the sampler coordinates 39 %; the walkers a median 9.5 below (2026-12-05).

Usage: ``python benchmarks/initial_walkers.py DIR [--draws N] [--seed S]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _drops(log_post, top, draws):
    """Log-posterior drops below ``top`` (inf outside the support or the map's range)."""
    drop = np.full(draws.shape[0], np.inf)
    finite = np.isfinite(draws).all(axis=1)
    with np.errstate(invalid="ignore"):
        drop[finite] = top - log_post(draws[finite])
    return np.where(np.isfinite(drop), drop, np.inf)


def _line(label, drop, within):
    inside = np.isfinite(drop)
    q = np.quantile(drop[inside], (0.1, 0.5, 0.9)) if inside.any() else (np.nan,) * 3
    print(
        f"{label:38s} outside the support {np.mean(~inside):5.1%}   drop q10/q50/q90 "
        f"{q[0]:12.1f} {q[1]:12.1f} {q[2]:12.1f}   within the typical set {np.mean(drop <= within):5.1%}"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", help="a study's results folder (fit.json, data.npz)")
    parser.add_argument("--draws", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    from scipy.stats import chi2

    from identify.fitting.coordinates import coordinates_for
    from identify.fitting.posterior import (
        TYPICAL_SET_TAIL,
        LogPosterior,
        _full_rank,
        _laplace_in_coordinates,
        initial_walkers,
    )
    from identify.output.results import load_data, load_fit

    record = load_data(args.folder)
    fit = load_fit(args.folder)
    log_post = LogPosterior(record, fit.model, fit.noise)
    free = log_post.free
    mean, cov = fit.theta[free], fit.covariance[np.ix_(free, free)]
    top = float(log_post(mean[None, :])[0])
    within = 0.5 * chi2.ppf(1.0 - TYPICAL_SET_TAIL, mean.size)
    sd = np.sqrt(np.diag(cov))
    eigenvalues = np.linalg.eigvalsh(cov / np.outer(sd, sd))
    print(
        f"{args.folder}: {record.time.size} samples, {mean.size} parameters; the covariance's correlation "
        f"eigenvalues from {eigenvalues[0] / eigenvalues[-1]:.2g} of the largest; typical set: drops up to "
        f"{within:.1f} (Gaussian draws: median {0.5 * chi2.median(mean.size):.1f})"
    )
    for name, value, lower, upper in zip(log_post.names, mean, log_post.lower, log_post.upper):
        if name in ("a0", "b0"):
            print(f"  {name} = {value:.4g} (bounds {lower:g}, {upper:g})")
    rng = np.random.default_rng(args.seed)
    for coordinates in ("identity", "gpi"):
        # initial_walkers' own steps, before its typical-set test: the approximation carried into the
        # coordinates, raised to full rank, drawn there and mapped back
        coords, centre, carried = _laplace_in_coordinates(
            coordinates_for(coordinates, log_post, mean), log_post, mean, cov
        )
        draws = coords.inverse(rng.multivariate_normal(centre, _full_rank(carried), size=args.draws, method="eigh"))
        where = "in the parameters" if coordinates == "identity" else "in the sampler coordinates"
        _line(f"{args.draws} draws {where}", _drops(log_post, top, draws), within)
    walkers = initial_walkers(log_post, mean, cov, 36, np.random.default_rng(args.seed))
    _line("36 walkers of initial_walkers", _drops(log_post, top, walkers), within)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
