"""identify.bench.calibration: coverage bookkeeping, its standard error across records, resume checks.

The calibration itself (fits and chains on 20 records) is the slow test in
tests/test_posterior.py; here the arithmetic is checked on hand-made records."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from identify.bench.calibration import WALD_Z95, CoverageResult, RecordCoverage, calibration_truth, interval_coverage
from identify.fitting.parametrisation import normalised_model, to_normalisation
from model import TABLE1, THETA_NAMES, Model


def record(seed, truth, lo, hi, estimate, stderr):
    return RecordCoverage(
        seed=seed,
        names=("a", "b", "c"),
        truth=list(truth),
        posterior_interval=np.column_stack([lo, hi]).tolist(),
        least_squares=list(estimate),
        stderr=list(stderr),
        converged=True,
        n_steps=1000,
        tau_max=10.0,
        seconds=1.0,
    )


def test_inside_counts_the_interval_ends_and_the_wald_width():
    r = record(
        0, [0.0, 1.0, 2.0], [-1.0, 1.0, 2.5], [1.0, 3.0, 3.0], [0.0, 1.0 + WALD_Z95 * 0.999, 2.0 + 2.0], [1.0, 1.0, 1.0]
    )
    assert r.posterior_inside.tolist() == [True, True, False]  # the lower end counts as inside
    assert r.least_squares_inside.tolist() == [True, True, False]  # 1.96 se inside, 2 se outside


def test_coverage_is_the_mean_of_per_record_fractions_with_their_standard_error():
    truth = [0.0, 0.0, 0.0]
    hit = record(0, truth, [-1] * 3, [1] * 3, truth, [1] * 3)
    one_miss = record(1, truth, [-1, -1, 0.5], [1, 1, 1], truth, [1] * 3)
    result = CoverageResult([hit, one_miss])
    mean, se = result.coverage("posterior")
    fractions = np.array([1.0, 2.0 / 3.0])
    assert mean == pytest.approx(fractions.mean())
    assert se == pytest.approx(fractions.std(ddof=1) / np.sqrt(2))
    assert result.misses("posterior") == ["c@1"]
    assert result.per_parameter("posterior") == {"a": 1.0, "b": 1.0, "c": 0.5}
    assert result.n_intervals == 6
    with pytest.raises(ValueError, match="kind"):
        result.coverage("bayes")


def test_records_round_trip_through_json():
    r = record(3, [0.0, 1.0, 2.0], [-1, 0, 1], [1, 2, 3], [0, 1, 2], [1, 1, 1])
    assert RecordCoverage.from_dict(json.loads(json.dumps(r.to_dict()))) == r


def test_the_truths_are_table1_with_b3_on_both_sides_of_the_old_wall_and_scaled():
    from model import bound_overlap, paper_current

    current = paper_current(50.0)[1]
    overlaps = []
    for seed in range(20):
        truth_raw = calibration_truth(seed)
        shift = to_normalisation(truth_raw)[THETA_NAMES.index("b3")] - to_normalisation(TABLE1)[THETA_NAMES.index("b3")]
        shifted = TABLE1.copy()
        shifted[THETA_NAMES.index("b3")] += shift
        assert not np.allclose(truth_raw, shifted)  # scaled: only the normalisation compares them
        assert np.allclose(to_normalisation(truth_raw), to_normalisation(shifted))
        assert -0.25 <= shift <= 0.25
        overlaps.append(bound_overlap(truth_raw, current))
    crossing = sum(o > 0 for o in overlaps)
    assert 7 <= crossing <= 13  # about half of the truths lie beyond where the bounds start to cross
    np.testing.assert_array_equal(calibration_truth(3), calibration_truth(3))


def test_a_stored_record_for_another_truth_is_refused_before_any_work(tmp_path):
    free = normalised_model(Model()).parameters.vary
    other = to_normalisation(TABLE1)[free]  # Table 1, not the calibration truth of seed 0
    stale = record(0, other[:3], [0] * 3, [1] * 3, [0] * 3, [1] * 3).to_dict()
    stale["names"] = list(np.array(normalised_model(Model()).names)[free])
    stale["truth"] = other.tolist()
    stale["posterior_interval"] = [[0.0, 1.0]] * other.size
    (tmp_path / "seed_0.json").write_text(json.dumps(stale))
    with pytest.raises(ValueError, match="another truth"):
        interval_coverage(calibration_truth, [0], tmp_path)


def test_records_written_before_the_wall_was_removed_still_load():
    truth = [0.0, 0.0, 0.0]
    old = record(0, truth, [-1] * 3, [1] * 3, truth, [1] * 3).to_dict()
    old.pop("bound_overlap")
    old["outside_domain_fraction"] = 0.01
    back = RecordCoverage.from_dict(old)
    assert back.bound_overlap is None and CoverageResult([back]).n_crossing == 0


def test_the_likelihood_ratio_check_averages_the_records_that_have_it():
    truth = [0.0, 0.0, 0.0]
    old = record(0, truth, [-1] * 3, [1] * 3, truth, [1] * 3)  # written before delta_chi2 was kept
    assert CoverageResult([old]).likelihood_ratio() is None
    assert "chi-square of the truth" not in CoverageResult([old]).summary()
    a, b = (
        dataclasses.replace(record(s, truth, [-1] * 3, [1] * 3, truth, [1] * 3), delta_chi2=d)
        for s, d in ((1, 2.0), (2, 4.0))
    )
    mean, se, dof = CoverageResult([old, a, b]).likelihood_ratio()
    assert (mean, dof) == (3.0, 3)
    assert se == pytest.approx(np.std([2.0, 4.0], ddof=1) / np.sqrt(2))
    assert "mean 3.0 +- 1.0 (chi-square with 3 degrees of freedom: 3)" in CoverageResult([a, b]).summary()
