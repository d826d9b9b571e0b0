"""The noiseless oracle (:mod:`identify.bench.oracle`): its classes as a table, and what it finds."""

from __future__ import annotations

import numpy as np
import pytest

from identify.bench import simulate
from identify.bench.oracle import CLASSES, classify, separability
from identify.diagnosis import Thresholds

TH = Thresholds(bic_significant=10.0, gap_z=2.5)


@pytest.mark.parametrize(
    "gap, sd, kind",
    [
        (200.0, 30.0, "data separate"),  # z 6.7 >= 2.5 + 1.645
        (42.0, 10.0, "data separate"),  # z 4.2, just past the margin
        (40.0, 10.0, "marginal"),  # z 4.0 < 4.145: named on most draws, not 95 %
        (25.0, 10.0, "marginal"),  # z 2.5: named on half the draws
        (9.0, 1.0, "data tie"),  # z 9 but the gap is within bic_significant
        (8.0, 10.0, "data tie"),  # z 0.8 < 2.5 - 1.645
        (0.0, 10.0, "data tie"),
        (-20.0, 10.0, "data tie"),  # the rival ahead, within the margins
        (-30.0, 10.0, "data favour other"),
        (50.0, 0.0, "data separate"),  # no noise: any gap past bic_significant separates
    ],
)
def test_classes_as_a_table(gap, sd, kind):
    assert kind in CLASSES
    assert classify(gap, sd, TH) == kind


def test_a_noiseless_record_of_another_length_is_refused():
    sim = simulate(None, seed=0, noise_sigma=0.5, fs=10.0)
    with pytest.raises(ValueError, match="noiseless displacement has shape"):
        separability(sim.record, sim.clean[:-1], [], "thermal", "creep")


@pytest.mark.slow
def test_the_true_model_fits_the_noiseless_record_to_round_off_and_a_clear_rival_is_separated():
    sim = simulate("thermal", seed=3, noise_sigma=0.5, fs=10.0)
    s = separability(sim.record, sim.clean, [], "thermal", "sensor_drift", rng=np.random.default_rng(0))
    assert s.chi2["thermal"] < 1e-12 < s.chi2["sensor_drift"]
    assert s.gap > 0 and s.z == s.gap / s.gap_sd
    assert s.kind == "data separate"
    same = separability(sim.record, sim.clean, [], "thermal", "thermal", rng=np.random.default_rng(0))
    assert abs(same.gap) < 1e-6 and same.kind == "data tie"
