"""The posterior's quantiles of a small study, with their Monte Carlo standard errors, as JSON.

Runs :func:`identify.study` (no report) on a simulated clean record of the paper's
transducer (``simulate(fs=10, seed=7)``: 701 samples) and writes, per sampled parameter,
the 2.5 %, 50 % and 97.5 % quantiles of the posterior draws (``posterior.nc``'s, the draws
``summary.json`` is computed from) and their Monte Carlo standard errors
(``arviz.mcse(method="quantile")``, walkers as chains), with the chain's length, tau and
the code's git commit.

``tests/data/posterior_quantiles_before.json`` holds this file for the code before issue 70's
speed-up (commit ff4cb08: ``git archive ff4cb08 | tar -x -C DIR`` and run this script from
``DIR``); ``tests/test_posterior.py`` runs the same study with today's code and checks that
every quantile agrees within Monte Carlo error.

Usage::

    python benchmarks/posterior_quantiles.py [--out FILE] [--seed 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
QUANTILES = (0.025, 0.5, 0.975)
#: The simulated record: sampling rate [Hz] and noise seed.
RECORD = {"fs": 10.0, "seed": 7}


def quantiles_of(seed: int = 3) -> dict:
    """Run the study and return the quantiles, their standard errors and the chain's figures."""
    import identify
    from identify.bench import simulate
    from identify.fitting.posterior import import_arviz

    az = import_arviz()
    record = simulate(**RECORD).record
    with tempfile.TemporaryDirectory() as out:
        result = identify.study(record, out=out, seed=seed, n_starts=2, report=False, quiet=True, progress=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            idata = az.from_netcdf(Path(out) / "posterior.nc")
            posterior = idata.posterior.load()
    post = result.summary["posterior"]
    names = list(posterior.data_vars)
    table = {}
    for name in names:
        draws = posterior[name].values  # (chain, draw)
        values = np.quantile(draws.ravel(), QUANTILES)
        errors = [float(np.ravel(az.mcse(draws, method="quantile", prob=q))[0]) for q in QUANTILES]
        table[name] = {"quantiles": values.tolist(), "mcse": errors}
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {
        "record": RECORD,
        "seed": seed,
        "quantile_levels": list(QUANTILES),
        "n_steps": post["n_steps"],
        "tau_max": post["tau_max"],
        "converged": post["converged"],
        "commit": commit,
        "parameters": table,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="JSON file (default: print)")
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args(argv)
    text = json.dumps(quantiles_of(args.seed), indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
