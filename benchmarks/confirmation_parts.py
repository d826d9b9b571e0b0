"""The design's confirmation by simulation with and without its two cheaper parts, alternated in
one process (the machine's speed drifts by more between two runs of ``design`` than these parts
move it).

The parts: ``trf``'s SVD of a tall Jacobian with ``U`` kept implicit
(:func:`identify.fitting.lapack.trf_svd`; without it the plain :func:`~identify.fitting.lapack.svd`)
and the Jacobian that reuses the residual just evaluated and differences only the columns asked
for (:meth:`identify.fitting.lsq.WhitenedResiduals.jacobian`; without it every column and the
point itself, the way before). The contenders are fitted once; the drive is the design's best
(linear criterion); each round confirms it on every sample with the same random stream, so
both variants do the same refits and their rows agree to the last bits.

Usage::

    python benchmarks/confirmation_parts.py [--record data/bench_default.csv]
        [--candidates creep,thermal,sensor_drift] [--rounds 3] [--draws 6]
"""

from __future__ import annotations

import argparse
import os
import time
from contextlib import contextmanager

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import scipy.optimize._lsq.trf as trf

from identify.data.records import load_record
from identify.diagnosis import Thresholds
from identify.diagnosis.baseline import normalised_model
from identify.fitting import lapack
from identify.fitting.lsq_residuals import WhitenedResiduals
from identify.fitting.noise import estimate_noise
from identify.workflows.design import RigLimits, _misfits, drive_period, fitted_contenders, search
from identify.workflows.design_confirmation import confirm
from model import Model

_JACOBIAN = WhitenedResiduals.jacobian


def _jacobian_before(self, x, columns=None):
    """The Jacobian of every column with the point evaluated again (the way before); the residual
    just evaluated stays cached for the solver's own calls, as it did."""
    cached = (self._cache_x, self._cache_r, self._cache_valid)
    self._cache_x = None  # hidden from the Jacobian only
    try:
        jac = _JACOBIAN(self, x)
    finally:
        self._cache_x, self._cache_r, self._cache_valid = cached
    return jac if columns is None else jac[:, columns]


@contextmanager
def _variant(cheaper: bool):
    lapack.release_the_gil_in_least_squares()
    svd, jacobian = trf.svd, WhitenedResiduals.jacobian
    if not cheaper:
        trf.svd = lapack.svd
        WhitenedResiduals.jacobian = _jacobian_before
    try:
        yield
    finally:
        trf.svd, WhitenedResiduals.jacobian = svd, jacobian


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", default="data/bench_default.csv")
    parser.add_argument("--candidates", default="creep,thermal,sensor_drift")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--draws", type=int, default=6)
    args = parser.parse_args(argv)
    record = load_record(args.record)
    noise = estimate_noise(record)
    model = normalised_model(Model([]))
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    contenders = fitted_contenders([record], model, args.candidates.split(","), [noise], rng=rng)
    limits = RigLimits.from_records([record])
    drive = search(contenders, limits, noise, Thresholds(), rng, drive_period([record]), per_family=10)[0]
    misfits = _misfits(contenders, [record], [noise])
    print(f"contenders fitted and a '{drive.family}' drive found in {time.perf_counter() - t0:.1f} s")
    seconds = {True: [], False: []}
    rows = {}
    for _ in range(args.rounds):
        for cheaper in (True, False):
            with _variant(cheaper):
                t0 = time.perf_counter()
                stream = np.random.default_rng(1)
                out = confirm(drive, contenders, noise, Thresholds(), stream, args.draws, misfits=misfits)
                seconds[cheaper].append(time.perf_counter() - t0)
            rows[cheaper] = [g for row in out for g in row["realised_gaps"]]
    for cheaper in (True, False):
        label = "implicit U, reused point, asked columns" if cheaper else "formed U, every column and the point"
        print(f"{label:42s} " + " ".join(f"{s:6.1f} s" for s in seconds[cheaper]))
    ratio = np.array(seconds[True]) / np.array(seconds[False])
    print(f"ratio per round (cheaper / before): {' '.join(f'{r:.3f}' for r in ratio)}")
    gap = np.max(np.abs(np.array(rows[True]) - np.array(rows[False])))
    print(f"largest difference of a realised gap between the two: {gap:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
