"""The sampler's own parts, per call, on a study's results folder: what a step costs beside the model.

Reads ``DIR`` (a ``study`` results folder: its record, least-squares fit and chain), takes the
last stored step's walkers and times, each the best of several rounds of many calls:

* the way back of 18 proposals from the sampler coordinates (``GPICoordinates.back``: the
  inverse map from each proposal's walker, the log-determinants) and the inverse alone (started
  afresh);
* ``DifferentialMove.get_proposal`` beside emcee's ``DEMove.get_proposal`` (the same draws);
* ``SnookerMove.get_proposal`` for 9 walkers;
* the log-likelihood's pass over 9 and 18 model rows of the record at 1 and 2 numba threads
  (``log_likelihood_of_rows``);
* a flush of 122 steps into ``chain.h5`` with 64-step chunks (the present) and 256-step chunks,
  replaying the folder's chain (the flush is timed; the file's size after compaction printed).

Run with ``PYTHONPATH`` set to another checkout to time its code (parts it lacks are skipped).

Usage: ``python benchmarks/sampler_parts.py DIR [--rounds R]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import timeit
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.append(str(ROOT))  # last: PYTHONPATH picks another checkout's code


def _best(fn, number, rounds) -> float:
    """Best time of one call [us] over ``rounds`` rounds of ``number`` calls."""
    return 1e6 * min(timeit.repeat(fn, number=number, repeat=rounds)) / number


def _line(label, microseconds) -> None:
    print(f"{label:64s} {microseconds:7.1f} us")


def _flush_ms(chain, log_prob, chunk, folder) -> tuple[float, float]:
    """(ms per flush of 122 steps, MB after compaction) of the chain replayed with ``chunk``-step chunks."""
    import time

    import emcee

    import identify.fitting.chain_file as chain_file

    kept = chain_file.CHAIN_CHUNK_STEPS
    chain_file.CHAIN_CHUNK_STEPS = chunk
    try:
        path = Path(folder) / f"chunks_{chunk}.h5"
        backend = chain_file.BufferedHDFBackend(path, flush_every=10**9, flush_seconds=1e9)
        backend.reset(chain.shape[1], chain.shape[2])
        state = np.random.RandomState(0).get_state()
        total, flushes = 0.0, 0
        for i in range(chain.shape[0]):
            backend.save_step(
                emcee.State(chain[i], log_prob=log_prob[i], random_state=state), np.ones(chain.shape[1], bool)
            )
            if (i + 1) % 122 == 0:
                t0 = time.perf_counter()
                backend.flush()
                total += time.perf_counter() - t0
                flushes += 1
        backend.flush()
        size = chain_file.compact_chain_file(path)[1]
    finally:
        chain_file.CHAIN_CHUNK_STEPS = kept
    return 1e3 * total / max(flushes, 1), size / 1e6


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", help="a study's results folder (fit.json, data.npz, chain.h5)")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)

    import emcee
    import h5py
    import numba

    import identify
    from identify.fitting.coordinates import coordinates_for
    from identify.fitting.noise import log_likelihood_of_rows
    from identify.fitting.posterior import LogPosterior
    from identify.output.results import load_data, load_fit

    record, fit = load_data(args.folder), load_fit(args.folder)
    log_post = LogPosterior(record, fit.model, fit.noise)
    mean = fit.theta[log_post.free]
    with h5py.File(Path(args.folder) / "chain.h5", "r") as f:
        chain = np.asarray(f["mcmc/chain"][:], dtype=float)
        log_prob = np.asarray(f["mcmc/log_prob"][:], dtype=float)
    walkers = chain[-1]
    n = walkers.shape[0] // 2
    print(
        f"{args.folder}: {record.time.size} samples, {walkers.shape[1]} coordinates, {walkers.shape[0]} walkers; "
        f"code {Path(identify.__file__).parent.parent}; load {os.getloadavg()[0]:.2f}"
    )
    rounds = args.rounds

    coords = coordinates_for("gpi", log_post, mean)
    rng = np.random.default_rng(0)
    s, u, others = walkers[:n], coords.forward(walkers[:n]), coords.forward(walkers[n:])
    pick = rng.integers(walkers.shape[0] - n, size=(2, n))
    q_u = u + 2.38 / np.sqrt(2 * u.shape[1]) * (others[pick[0]] - others[pick[1]])
    log_det, factors = coords.log_det(s), np.zeros(n)
    back = getattr(coords, "back", None)
    if back is not None:
        back(s, q_u, factors, log_det)
        _line(
            f"way back of {n} proposals (inverse, log-determinants)",
            _best(lambda: back(s, q_u, factors, log_det), 2000, rounds),
        )
    coords.inverse(q_u)
    _line(f"inverse map of {n} proposals, started afresh", _best(lambda: coords.inverse(q_u), 2000, rounds))

    random = np.random.RandomState(1)
    stock = emcee.moves.DEMove()
    stock.setup(walkers)
    _line(
        f"emcee's DEMove.get_proposal, {n} walkers",
        _best(lambda: stock.get_proposal(s, [others], random), 5000, rounds),
    )
    try:
        from identify.fitting.moves import DifferentialMove, SnookerMove
    except ImportError:  # an older checkout: no moves module
        DifferentialMove = None
        from identify.fitting.posterior import SnookerMove
    if DifferentialMove is not None:
        move = DifferentialMove()
        move.setup(walkers)
        _line(
            f"DifferentialMove.get_proposal, {n} walkers",
            _best(lambda: move.get_proposal(s, [others], random), 5000, rounds),
        )
    quarter = walkers.shape[0] // 4
    groups = [walkers[quarter * k : quarter * (k + 1)] for k in range(1, 4)]
    snooker = SnookerMove()
    first = walkers[:quarter]
    _line(
        f"SnookerMove.get_proposal, {quarter} walkers",
        _best(lambda: snooker.get_proposal(first, groups, random), 5000, rounds),
    )

    theta = log_post.full_theta(walkers)
    y, _valid = log_post.model.evaluate(theta, log_post.time, log_post.current)
    threads = numba.get_num_threads()
    for rows in (9, 18):
        for count in sorted({1, threads}):
            numba.set_num_threads(count)
            index = np.arange(rows)

            def call(index=index):
                return log_likelihood_of_rows(log_post.data, y, index, log_post.noise)

            call()
            _line(
                f"log-likelihood's pass over {rows} rows x {y.shape[1]} samples, {count} thread(s)",
                _best(call, 2000, rounds),
            )
    numba.set_num_threads(threads)

    with tempfile.TemporaryDirectory() as folder:
        for chunk in (64, 256):
            ms, mb = _flush_ms(chain, log_prob, chunk, folder)
            print(
                f"chain.h5 flush of 122 steps in {chunk}-step chunks: {ms:.2f} ms a flush; {mb:.2f} MB after compaction"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
