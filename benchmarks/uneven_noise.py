"""AR(1) noise on unevenly sampled records: each step's own correlation against one for all.

Run from the repository root::

    python benchmarks/uneven_noise.py [--records 200] [--rho 0.7] [--fs 1000]

Simulates clean virtual-bench records (the paper's input, AR(1) sensor noise of lag-1
correlation ``--rho`` at ``--fs``) and keeps their samples two ways: as the diagnosis'
working copy keeps them (every 18th sample and 50 ms at the full rate around each input
reversal; the noise estimated on the whole record, as the diagnosis does), and with 5 % of
them dropped at random (a logger that misses samples; the noise estimated from the kept
record's own quiet start). The residual of the true model (the noise itself) is whitened
two ways:

* ``per step``: each step its own correlation ``rho^(step / dt)``
  (:meth:`identify.fitting.noise.NoiseModel.step_correlations`);
* ``one rho``: one correlation for every step: ``rho^18`` on the working copy (its
  noise model before each step had its own), the quiet start's ``rho`` on the record with
  dropped samples (an even-grid whitening).

Prints, per thinning, the mean of ``chi2 / T`` (1 for a correct likelihood), the mean lag-1
autocorrelation of the whitened residual (0) and the mean error of the log-likelihood
against the exact multivariate normal of the kept samples under the estimated noise
(covariance ``sigma^2 rho^|i - j|`` over their indices at the full rate) (the records are cut to their
first ``--exact-samples`` kept samples for that, a dense covariance). No timing.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.stats import multivariate_normal

from identify.bench import simulate
from identify.data.records import Record, thinning_indices
from identify.data.reversals import find_reversals
from identify.fitting.noise import NoiseModel, estimate_noise, log_likelihood, whiten


def kept_samples(kind: str, current, rng) -> np.ndarray:
    """The kept indices of one thinning of a record with drive ``current``."""
    n = current.size
    if kind == "working copy (every 18th, 50 ms windows)":
        return thinning_indices(current, 18, find_reversals(current).index, around=50)
    if kind == "5 % dropped at random":
        return np.sort(rng.choice(n, size=int(0.95 * n), replace=False))
    raise ValueError(kind)


KINDS = ("working copy (every 18th, 50 ms windows)", "5 % dropped at random")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=200)
    parser.add_argument("--rho", type=float, default=0.7)
    parser.add_argument("--fs", type=float, default=1000.0)
    parser.add_argument("--exact-samples", type=int, default=1500)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = {kind: {"per step": [], "one rho": []} for kind in KINDS}
    for seed in range(args.records):
        sim = simulate({}, seed=seed, noise_sigma=0.5, noise_rho=args.rho, fs=args.fs)
        record = sim.record
        for kind in KINDS:
            keep = kept_samples(kind, record.current, rng)
            kept = Record(record.time[keep], record.current[keep], record.displacement[keep], source="kept", sha256="")
            # the working copy whitens with the whole record's noise; a record with dropped samples has its own
            noise = estimate_noise(record if kind.startswith("working") else kept)
            residual = kept.displacement - sim.clean[keep]
            # one correlation for every step: the working copy's rho^18 (its noise before each step had its own),
            # the quiet start's rho for the record with dropped samples
            one_rho = noise.rho**18 if kind.startswith("working") else noise.rho
            one = NoiseModel(sigma=noise.sigma, rho=one_rho, kind="ar1" if one_rho else "white")
            m = min(args.exact_samples, keep.size)
            lags = np.abs(np.subtract.outer(keep[:m], keep[:m]))
            exact = multivariate_normal(np.zeros(m), noise.sigma**2 * noise.rho**lags).logpdf(residual[:m])
            for label, model, time in (("per step", noise, kept.time), ("one rho", one, None)):
                w = whiten(residual, model, time=time)
                short = log_likelihood(residual[:m], model, time=None if time is None else time[:m])
                rows[kind][label].append((float(w @ w) / w.size, float(w[1:] @ w[:-1] / (w @ w)), short - exact))
    print(
        f"{args.records} clean records, AR(1) rho {args.rho} at {args.fs:g} Hz, sigma 0.5 um; "
        f"log-likelihood error against the exact density of the first {args.exact_samples} kept samples"
    )
    print("| kept samples | whitening | chi2 / T | lag-1 of the whitened residual | log-likelihood error |")
    print("|---|---|---|---|---|")
    for kind in KINDS:
        for label in ("per step", "one rho"):
            values = np.array(rows[kind][label])
            chi, lag1, err = values.mean(axis=0)
            print(f"| {kind} | {label} | {chi:.3f} | {lag1:+.3f} | {err:+.1f} (sd {values[:, 2].std():.1f}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
