"""az.loo's Pareto-k diagnostics against the number of draws in posterior.nc's pointwise groups.

For a finished study (a results folder), computes the pointwise log-likelihood of ``K``
draws per walker (every ``n/K``-th of the ``n`` draws after burn-in and thinning, at a few
offsets) and runs ``az.loo`` as a user does on ``posterior.nc``: the ``posterior`` group
holds every draw, so ArviZ's relative efficiency is the posterior's mean ESS over the
pointwise draws. Prints, per ``K`` and offset, elpd_loo, p_loo, the largest Pareto k and
how many exceed 0.5, 0.7 and ArviZ's ``good_k = min(1 - 1/log10(S), 0.7)``.

Usage::

    python benchmarks/pointwise_draws.py DIR [--per-walker 8,12,16,24,32] [--offsets 4]

(``DIR`` from ``python -m identify study data/bench_default.csv --out DIR``; the record is
read from ``DIR/data.npz``.)
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--per-walker", default="8,12,16,24,32")
    parser.add_argument("--offsets", type=int, default=4)
    args = parser.parse_args(argv)

    from identify.fitting.inference import pointwise_log_likelihood
    from identify.fitting.posterior import BACKEND_GROUP, ChainBackend, LogPosterior, import_arviz
    from identify.output.results import load_data, load_fit

    az = import_arviz()
    folder = Path(args.folder)
    record, fit = load_data(folder), load_fit(folder)
    log_post = LogPosterior(record, fit.model, fit.noise)
    post = json.loads((folder / "summary.json").read_text())["posterior"]
    chain = ChainBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True).get_chain()
    draws = np.moveaxis(chain[post["discard"] :: post["thin"]], 1, 0)  # (walker, draw, D)
    n_walkers, n_draws, _ = draws.shape
    posterior = {f"p{j}": draws[:, :, j] for j in range(draws.shape[2])}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ess = az.ess(az.convert_to_dataset(posterior), method="mean")
    mean_ess = float(np.mean([float(ess[v]) for v in ess.data_vars]))
    print(f"{folder}: {n_walkers} walkers x {n_draws} draws, posterior mean ESS {mean_ess:.0f}")
    for per_walker in [int(k) for k in args.per_walker.split(",")]:
        step = max(1, n_draws // per_walker)
        for offset in range(min(args.offsets, step)):
            sub = draws[:, offset::step][:, :per_walker]
            flat = sub.reshape(-1, sub.shape[2])
            y, _ = log_post.model.evaluate(log_post.full_theta(flat), log_post.time, log_post.current)
            ll = pointwise_log_likelihood(log_post.data[None] - y, log_post.noise, time=log_post.time)
            ll = ll.reshape(sub.shape[0], sub.shape[1], -1).astype(np.float32)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                loo = az.loo(az.from_dict(log_likelihood={"y": ll}, posterior=posterior), pointwise=True)
            k = loo.pareto_k.values
            n = ll.shape[0] * ll.shape[1]
            good_k = min(1 - 1 / np.log10(n), 0.7)
            print(
                f"S = {n:5d} ({per_walker:2d} per walker) offset {offset}: relative efficiency {mean_ess / n:5.2f}, "
                f"elpd_loo {loo.elpd_loo:.1f}, p_loo {loo.p_loo:.2f}, max k {k.max():.3f}, k > 0.5: {(k > 0.5).sum()}, "
                f"k > 0.7: {(k > 0.7).sum()}, k > good_k ({good_k:.3f}): {(k > good_k).sum()}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
