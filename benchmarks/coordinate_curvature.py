"""How Gaussian a converged chain looks in the sampler coordinates: the regression case of the
envelopes' coordinates.

Reads ``study`` results folders (their record, least-squares fit and ``chain.h5``), takes up to
15,000 draws after the burn-in and prints, for each folder and for three coordinate systems,
the fraction of each whitened coordinate explained by quadratic terms of the others (0 for a
Gaussian; the worst and the mean over the coordinates, and the rising and falling envelopes'
blocks):

* the parameters themselves;
* the envelopes as two values (10 % and 90 % of the input range), the slope and the centre
  ``-a2/a1`` (the other blocks as :class:`identify.fitting.coordinates.GPICoordinates`), the
  sampler's envelope coordinates until 2026-12-06, written out here in NumPy;
* :class:`identify.fitting.coordinates.GPICoordinates` as the study samples in (its reference
  point the least-squares solution): three values (10 %, 50 % and 90 %) and the amplitude's
  logarithm for each envelope whose tanh varies at the three inputs there, two values, the
  slope and the centre for the others.

Regression case: ``python -m identify study data/bench_default.csv --out DIR --seed S`` for
S = 0-4, then ``python benchmarks/coordinate_curvature.py DIR...``. On seed 4 the rising
envelope's tanh centre lies at -2.9 A, outside the 0-5 A input range: the record sees its tail,
and amplitude (55-100, at its bound), slope and centre trade along it. With two values, the
slope and the centre its block's worst quadratic fraction was 0.61 and the chain needed 12,000
steps (tau_max 237); with three values and the log-amplitude 0.13 and 5,000 steps (tau_max 97,
2026-12-06). Seeds 0-3: 6,000-8,000 steps before, 5,500-6,500 after.

Usage: ``python benchmarks/coordinate_curvature.py DIR [DIR ...] [--draws N]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def quadratic_fractions(z) -> np.ndarray:
    """Per column of ``z`` (n, D), whitened: the share of its variance that a least-squares fit on
    the other columns, their squares and their products explains beyond a linear fit's
    (whitening removes the linear part)."""
    z = (z - z.mean(axis=0)) / z.std(axis=0)
    w = np.linalg.solve(np.linalg.cholesky(np.cov(z.T)), z.T).T
    out = np.empty(w.shape[1])
    for j in range(w.shape[1]):
        others = np.delete(w, j, axis=1)
        k = others.shape[1]
        products = [others[:, a] * others[:, b] for a in range(k) for b in range(a, k)]
        features = np.column_stack([np.ones(len(w)), others, *products])
        coef, *_ = np.linalg.lstsq(features, w[:, j], rcond=None)
        out[j] = 1.0 - np.var(w[:, j] - features @ coef) / np.var(w[:, j])
    return out


def two_values_slope_centre(coords, x, names):
    """The sampler coordinates with each envelope as two values, the slope and the centre
    (``coords`` must map the weights: its ``rho`` coordinate is the total weight)."""
    if "weights" not in coords.blocks:
        raise ValueError("the two-values comparison needs the weights block (rho and tau free, alpha pinned)")
    u = coords.forward(x)
    index = {n: i for i, n in enumerate(names)}
    low, high = coords.points[0], coords.points[-1]
    total = u[:, index["rho"]]  # the weights block's first coordinate: the total weight S
    for p in "ab":
        k0, k1, k2, k3 = (x[:, index[f"{p}{n}"]] for n in range(4))
        u[:, index[p + "0"]] = total * (k0 * np.tanh(k1 * low + k2) + k3)
        u[:, index[p + "1"]] = k1
        u[:, index[p + "2"]] = -k2 / k1
        u[:, index[p + "3"]] = total * (k0 * np.tanh(k1 * high + k2) + k3)
    return u


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", help="study results folders (fit.json, data.npz, chain.h5)")
    parser.add_argument("--draws", type=int, default=15000)
    args = parser.parse_args(argv)

    from identify.fitting.coordinates import GPICoordinates
    from identify.fitting.posterior import BACKEND_GROUP, ChainBackend, LogPosterior
    from identify.output.results import load_data, load_fit

    for folder in args.folders:
        fit = load_fit(folder)
        log_post = LogPosterior(load_data(folder), fit.model, fit.noise)
        reference = fit.theta[log_post.free]  # the study's reference point: its least-squares solution
        if log_post.free_sigma:
            reference = np.append(reference, np.log(fit.noise.sigma))
        coords = GPICoordinates.from_log_posterior(log_post, reference)
        chain = ChainBackend(str(Path(folder) / "chain.h5"), name=BACKEND_GROUP, read_only=True).get_chain()
        posterior = json.loads((Path(folder) / "summary.json").read_text())["posterior"]
        x = chain[int(posterior["discard"]) :].reshape(-1, chain.shape[2]).astype(float)
        x = x[np.random.default_rng(0).choice(len(x), min(len(x), args.draws), replace=False)]
        names = list(log_post.names)
        blocks = {p: [names.index(f"{p}{n}") for n in range(4)] for p in "ab"}
        centre = float(np.median(-x[:, names.index("a2")] / x[:, names.index("a1")]))
        print(
            f"{folder}: {posterior['n_steps']} steps, tau_max {posterior['tau_max']:.0f}; rising envelope's "
            f"centre {centre:.3g}, input {np.min(log_post.current):.3g} to {np.max(log_post.current):.3g}; "
            f"three values and the log-amplitude for {', '.join(coords.three_values) or 'no envelope'}"
        )
        systems = {
            "the parameters": x,
            "two values, slope, centre": two_values_slope_centre(coords, x, names),
            "as sampled": coords.forward(x),
        }
        for label, z in systems.items():
            f = quadratic_fractions(z)
            print(
                f"  {label:28s} worst {f.max():.3f} mean {f.mean():.3f}   rising envelope "
                f"{np.round(f[blocks['a']], 2)}  falling {np.round(f[blocks['b']], 2)}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
