"""Tests of identify.diagnosis.residuals: the "where it fails" statistics and the noise tests (pure arrays, fast)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.signal import lfilter

from identify.data.reversals import branch_direction, find_reversals, input_rate, time_since_reversal
from identify.diagnosis.adequacy import assess_adequacy
from identify.diagnosis.explanation import where_text
from identify.diagnosis.residuals import (
    ARNoise,
    autocorrelation,
    binned_residual,
    cycle_statistics,
    extremum_levels,
    fit_ar_noise,
    level_test,
    ljung_box,
    low_frequency_test,
    residual_profile,
    variance_ratio_test,
)
from identify.output.diagnosis_plots import residual_rate_figure
from model import paper_current


def ar1(rng, n, rho, sigma=1.0):
    """Stationary AR(1) noise of marginal sd ``sigma``."""
    e = rng.standard_normal(n)
    e[1:] *= np.sqrt(1 - rho * rho)
    return sigma * lfilter([1.0], [1.0, -rho], e)


# -- reversals and geometry --------------------------------------------------------------


def test_reversals_of_the_paper_input_are_where_eq_15_puts_them():
    # eq. (15): v = 2.5 sin(0.2 pi t - pi/2) + 2.5 from 10 s: troughs at 10 + 10k s (v = 0,
    # untouched by the literal decay of eq. 16), peaks at 15 + 10k s before the decay starts;
    # the decay (1 - 0.01 (t - 20)) moves later peaks earlier by atan(0.01 T/2pi...) < 0.1 s.
    time, current = paper_current(100.0)
    rev = find_reversals(current)
    assert np.array_equal(rev.kind, np.tile([-1, 1], 6))
    np.testing.assert_allclose(time[rev.troughs], [10, 20, 30, 40, 50, 60], atol=0.011)
    np.testing.assert_allclose(time[rev.peaks], [15, 25, 35, 45, 55, 65], atol=0.1)


def test_small_wiggles_do_not_count_as_reversals():
    time, current = paper_current(100.0, reading="centred")
    rng = np.random.default_rng(1)
    # read-back noise of 0.1 % of the range while energised (the quiet start is an exact 0)
    noisy = current + np.where(current > 0, 0.005 * rng.standard_normal(current.size), 0.0)
    clean_rev = find_reversals(current)
    noisy_rev = find_reversals(noisy)
    assert len(noisy_rev) == len(clean_rev)
    assert np.array_equal(noisy_rev.kind, clean_rev.kind)
    # a reversal of a noisy signal is found within the flat top of the sine (|dv| < noise there)
    assert np.max(np.abs(time[noisy_rev.index] - time[clean_rev.index])) < 0.3


def test_branch_direction_and_time_since_reversal():
    time, current = paper_current(100.0)
    rev = find_reversals(current)
    direction = branch_direction(time.size, rev)
    since = time_since_reversal(time, rev)
    assert (direction[: rev.index[0] + 1] == 0).all() and np.isnan(since[: rev.index[0]]).all()
    # between a trough and the next peak the input rises, then falls
    t0, p0 = rev.index[0], rev.index[1]
    assert (direction[t0 + 1 : p0 + 1] == 1).all()
    assert (direction[p0 + 1 : rev.index[2] + 1] == -1).all()
    assert (np.diff(current[t0 + 1 : p0 + 1]) >= 0).all()
    assert since[rev.index].tolist() == [0.0] * len(rev)
    np.testing.assert_allclose(since[p0 - 1], time[p0 - 1] - time[t0])


def test_input_rate_is_the_derivative():
    time = np.linspace(0, 1, 101)
    np.testing.assert_allclose(input_rate(time, 3.0 * time**2)[1:-1], 6.0 * time[1:-1], atol=1e-9)
    with pytest.raises(ValueError, match="non-finite"):
        input_rate(time, np.where(time > 0.5, np.nan, time))


def test_binned_residual_means_counts_and_errors():
    x = np.repeat(np.arange(4.0), 25)  # 4 groups of 25 samples
    r = np.repeat([1.0, -2.0, 0.5, 3.0], 25) + np.tile(np.linspace(-0.1, 0.1, 25), 4)
    binned = binned_residual(x, r, edges=[-0.5, 0.5, 1.5, 2.5, 3.5, 4.5])
    assert binned.count.tolist() == [25, 25, 25, 25, 0]
    np.testing.assert_allclose(binned.mean[:4], [1.0, -2.0, 0.5, 3.0], atol=1e-12)
    assert np.isnan(binned.mean[4]) and np.isnan(binned.sem[4])
    spread = np.linspace(-0.1, 0.1, 25)
    np.testing.assert_allclose(binned.sem[0], spread.std(ddof=1) / 5, rtol=1e-9)
    mask = x < 2
    assert binned_residual(x, r, n_bins=2, mask=mask).count.sum() == 50
    with pytest.raises(ValueError, match="increasing"):
        binned_residual(x, r, edges=[1.0, 0.0])


def test_cycle_statistics_and_extremum_levels_on_a_constructed_residual():
    time, current = paper_current(100.0)
    rev = find_reversals(current)
    troughs = rev.troughs
    residual = np.zeros(time.size)
    for k, (a, b) in enumerate(zip(troughs[:-1], troughs[1:])):
        residual[a:b] = k + 1.0  # cycle k has a constant error k + 1
    cycles = cycle_statistics(time, residual, rev, output_range=200.0)
    assert len(cycles) == len(troughs) - 1
    np.testing.assert_allclose(cycles.rms, np.arange(1, len(cycles) + 1))
    np.testing.assert_allclose(cycles.max_error_pct, 100 * np.arange(1, len(cycles) + 1) / 200.0)
    levels = extremum_levels(time, current, residual, rev, half_window=0)
    np.testing.assert_allclose(levels.residual[rev.kind > 0][: len(cycles)], np.arange(1, len(cycles) + 1))
    with pytest.raises(ValueError, match="output_range"):
        cycle_statistics(time, residual, rev, output_range=0.0)


# -- noise model and tests ---------------------------------------------------------------


def test_autocorrelation_of_ar1_noise():
    rng = np.random.default_rng(2)
    x = ar1(rng, 20000, 0.6)
    acf = autocorrelation(x, 3)
    # sampling sd of the lag-k autocorrelation ~ 1/sqrt(n) = 0.007 (Bartlett, inflated for AR(1))
    np.testing.assert_allclose(acf, [1, 0.6, 0.36, 0.216], atol=0.03)
    with pytest.raises(ValueError, match="max_lag"):
        autocorrelation(x[:5], 5)


def test_ar_noise_fit_recovers_the_generator():
    rng = np.random.default_rng(3)
    model = fit_ar_noise(ar1(rng, 5000, 0.7, sigma=0.5))
    assert model.order >= 1
    assert abs(model.coefficients[0] - 0.7) < 0.05  # Yule-Walker sd ~ sqrt((1-rho^2)/n) = 0.01
    assert abs(model.sigma - 0.5) < 0.03
    white = fit_ar_noise(rng.standard_normal(5000))
    assert np.all(np.abs(white.coefficients) < 0.06)
    # a drifting quiet segment: the straight line is removed, the noise level is the noise's
    drift = fit_ar_noise(rng.standard_normal(2000) + np.linspace(0, 50, 2000))
    assert abs(drift.sigma - 1.0) < 0.06
    with pytest.raises(ValueError, match="at least 20"):
        fit_ar_noise(np.zeros(10))
    with pytest.raises(ValueError, match="constant"):
        fit_ar_noise(np.ones(100), detrend=False)


def test_ar1_block_mean_variance_matches_the_closed_form():
    rho, sigma, L = 0.5, 2.0, 20
    model = ARNoise(np.array([rho]), sigma * np.sqrt(1 - rho**2), sigma, 1000)
    k = np.arange(1, L)
    closed = sigma**2 / L**2 * (L + 2 * np.sum((L - k) * rho**k))
    assert model.block_mean_variance(L) == pytest.approx(closed, rel=1e-9)
    assert model.variance_inflation() == pytest.approx((1 + rho**2) / (1 - rho**2), rel=1e-6)


def test_whitening_recovers_the_innovations():
    rng = np.random.default_rng(4)
    innovations = rng.standard_normal(500)
    x = lfilter([1.0], [1.0, -0.8], innovations * 0.3)
    model = ARNoise(np.array([0.8]), 0.3, 0.3 / np.sqrt(1 - 0.64), 1000)
    np.testing.assert_allclose(model.whiten(x), innovations[1:], atol=1e-12)


def test_ljung_box_is_calibrated_on_white_noise_and_sees_a_sine():
    rng = np.random.default_rng(5)
    p_values = np.array([ljung_box(rng.standard_normal(2000), 20).p_value for _ in range(300)])
    # p uniform under the null: 5 % below 0.05, binomial sd 1.3 % over 300 draws
    assert 0.01 < np.mean(p_values < 0.05) < 0.10
    t = np.arange(2000)
    structured = ljung_box(rng.standard_normal(2000) + 0.3 * np.sin(2 * np.pi * t / 200), 20)
    assert structured.p_value < 1e-6 and structured.z > 5


def test_ljung_box_with_an_estimated_filter_has_a_normal_tail():
    """White innovations whitened by a filter whose coefficient is off by N(0, 1/n_q), as a
    filter fitted on a quiet segment of n_q samples is: Q = chi2_40 + (n/n_q) chi2_1. A normal
    z of Q (or a scaled chi2 of the same mean and variance) puts ~1.6 % of these draws above
    3 and some above 5 (the (n/n_q) chi2_1 tail); the p-value of the sum keeps z normal."""
    rng = np.random.default_rng(3)
    n, n_quiet = 7000, 1000
    z = []
    for _ in range(1000):
        e = rng.standard_normal(n + 1)
        w = e[1:] - rng.standard_normal() / np.sqrt(n_quiet) * e[:-1]
        z.append(ljung_box(w, 40, filter_error=n / n_quiet, filter_dof=1).z)
    z = np.array(z)
    assert 0.9 < z.std() < 1.12 and abs(z.mean()) < 0.15
    assert np.mean(z > 3.0) < 0.008 and z.max() < 4.5
    # no filter error: the plain chi2_m tail
    plain = ljung_box(rng.standard_normal(2000), 20)
    assert plain.p_value == pytest.approx(stats.chi2.sf(plain.statistic, 20), rel=1e-9)
    with pytest.raises(ValueError, match="filter_dof"):
        ljung_box(rng.standard_normal(200), 10, filter_error=1.0, filter_dof=0)


def test_variance_and_low_frequency_tests_measure_the_structure():
    rng = np.random.default_rng(6)
    noise = ARNoise(np.zeros(0), 1.0, 1.0, 1000)
    n = 6000
    t = np.arange(n)
    white = rng.standard_normal(n)
    assert abs(variance_ratio_test(white, noise).z) < 4
    assert abs(low_frequency_test(white, noise, 20).z) < 4
    slow = 0.3 * np.sin(2 * np.pi * t / 1000)  # mean square 0.045 sigma^2
    lf = low_frequency_test(white + slow, noise, 20)
    assert lf.z > 5
    # the block-mean estimate of the slow part's mean square: sd ~ sqrt(2/300)/20 = 0.004
    assert lf.structure_variance == pytest.approx(0.045, abs=0.015)
    inflated = variance_ratio_test(1.3 * white, noise)
    assert inflated.z > 5 and inflated.structure_variance == pytest.approx(0.69, abs=0.1)
    # a misfit far beyond the noise: p-values below the double range still give a finite,
    # large z (it goes into JSON), growing with the misfit
    for amplitude in (30.0, 300.0):
        huge = white + amplitude * np.sin(2 * np.pi * t / 1000)
        zs = [
            low_frequency_test(huge, noise, 20).z,
            variance_ratio_test(huge, noise).z,
            ljung_box(huge, 40, filter_error=6.0).z,
        ]
        assert all(np.isfinite(z) and z > 30 for z in zs)


def test_no_false_alarm_with_the_quiet_segment_as_reference():
    """The tests' null (noise model estimated on a 1000-sample quiet segment, then applied to a
    7001-sample record): over 60 seeds of white and AR(1) noise no test reaches z = 5, the
    diagnosis' threshold (identify.diagnosis.Thresholds.z_critical)."""
    time, current = paper_current(100.0)
    quiet = slice(0, 1001)
    worst = 0.0
    for seed in range(60):
        rng = np.random.default_rng(100 + seed)
        rho = 0.0 if seed % 2 else 0.5
        residual = ar1(rng, time.size, rho, sigma=0.5)
        profile = residual_profile(time, current, residual, quiet, output_range=300.0)
        worst = max(worst, max(t.z for t in profile.tests.values()))
    assert worst < 5.0


def test_block_mean_variance_error_matches_the_ar1_delta_method():
    # AR(1): ln V_L -> ln f(0) = ln sigma_e^2 - 2 ln(1 - phi) for long blocks, so
    # var(ln V) = 4 (1 + phi) / ((1 - phi) n) + 2 / n (Yule-Walker: var(phi) = (1 - phi^2) / n)
    n = 1000
    for phi in (0.0, 0.35, 0.7):
        model = ARNoise(np.array([phi]), 1.0, 1.0 / np.sqrt(1 - phi**2), n)
        closed = np.sqrt(4 * (1 + phi) / ((1 - phi) * n) + 2 / n)
        assert model.block_mean_variance_relative_sd(2000) == pytest.approx(closed, rel=0.02)
    # fitted as white: only the level's error
    assert ARNoise(np.zeros(0), 1.0, 1.0, n).block_mean_variance_relative_sd(20) == pytest.approx(np.sqrt(2 / n))


def test_low_frequency_test_is_calibrated_with_an_estimated_reference():
    """The low-frequency z under the null when the noise model comes from a 1000-sample quiet
    segment: unit sd and a normal tail. Without the error of the fitted AR coefficients in its
    null the sd is ~1.5 at phi = 0.6 (the reference's long-run variance is uncertain by ~13 %,
    its sigma^2 by ~6 %) and z passes 5 about once in a few hundred records."""
    rng = np.random.default_rng(21)
    z = []
    for _ in range(300):
        e = ar1(rng, 7001, 0.6)
        z.append(low_frequency_test(e, fit_ar_noise(e[:1001]), 20).z)
    z = np.array(z)
    # sd of a sample sd over 300 draws ~ 0.04; of the mean ~ 0.06
    assert 0.85 < z.std() < 1.15
    assert abs(z.mean()) < 0.35
    assert np.mean(z > 3.0) < 0.02 and z.max() < 4.5


def _levels(time):
    """A drive-like output: a triangle of falling amplitude (levels visited at many times)."""
    return 100.0 * np.abs((time / 7.0) % 2.0 - 1.0) * np.exp(-time / 40.0)


def test_level_test_is_conservative_on_noise_with_an_estimated_reference():
    """On noise (white, AR(1) of either sign) with the noise model fitted on a 1000-sample
    quiet segment, the level test's z has at most a normal tail: the bound on the interval
    means' variance and the correction over intervals only make it smaller."""
    rng = np.random.default_rng(5)
    t = np.arange(7000) / 100.0
    level = _levels(t)
    for phi in (0.0, 0.6, -0.3):
        z = []
        for _ in range(150):
            e = ar1(rng, 8001, phi)
            z.append(level_test(level, e[1001:], fit_ar_noise(e[:1001])).z)
        z = np.array(z)
        assert np.all(np.isfinite(z))
        assert np.mean(z > 2.0) <= 0.05 and z.max() < 4.0


def test_level_test_finds_a_mean_at_the_top_levels_that_the_tests_in_time_dilute():
    """An end stop's mark after a fit: a mean of -0.6 sigma over the top 2 % of the output levels.
    The low-frequency test spreads it over the whole record; the level test finds it, at the top."""
    rng = np.random.default_rng(8)
    t = np.arange(7000) / 100.0
    level = _levels(t)
    noise = ARNoise(np.zeros(0), 1.0, 1.0, 1000)
    residual = rng.standard_normal(t.size)
    top = level >= np.quantile(level, 0.98)
    residual[top] -= 0.6
    found = level_test(level, residual, noise)
    assert found.z > 5 and low_frequency_test(residual, noise, 20).z < 5
    lo, hi = found.details["level_range"]
    assert found.details["mean"] < 0 and lo >= np.quantile(level, 0.9) and hi == level.max()
    # its size: the mean square of that mean over the record, 0.02 * 0.36 (within the noise's error)
    assert found.structure_variance == pytest.approx(0.0072, abs=0.004)
    # the same residual in time order is no evidence of a mean by level: shuffled levels
    assert level_test(rng.permutation(level), residual, noise).z < 4.0


def test_level_test_without_intervals_to_test():
    noise = ARNoise(np.zeros(0), 1.0, 1.0, 1000)
    few = level_test(np.arange(40.0), np.zeros(40), noise)
    assert few.details["intervals"] == 0 and few.p_value == 1.0 and few.z == 0.0
    with pytest.raises(ValueError, match="level"):
        level_test(np.arange(39.0), np.zeros(40), noise)


def test_residual_profile_runs_the_level_test_where_the_model_output_is_given():
    time, current = paper_current(100.0)
    rng = np.random.default_rng(9)
    residual = 0.5 * rng.standard_normal(time.size)
    level = 10.0 * current
    without = residual_profile(time, current, residual, slice(0, 1001), output_range=50.0)
    assert "level" not in without.tests
    residual[level > np.quantile(level, 0.97)] += 0.5
    with_level = residual_profile(time, current, residual, slice(0, 1001), output_range=50.0, level=level)
    assert with_level.tests["level"].z > 5
    assert with_level.to_dict()["tests"]["level"]["details"]["intervals"] > 0
    adequacy = assess_adequacy(with_level)
    assert "level" in adequacy.failed and not adequacy.adequate
    # the explanation says where: the levels of the interval with the mean
    lo, hi = with_level.tests["level"].details["level_range"]
    assert f"at model outputs {lo:.4g} to {hi:.4g}" in where_text(with_level)
    assert "model outputs" not in where_text(without)
    # the view by level: bins of equal count over the energised samples, and its panel
    assert without.by_level is None and "by_level" not in without.to_dict()
    counts = with_level.by_level.count
    assert counts.sum() == with_level.energised.sum() and counts.max() - counts.min() <= 0.05 * counts.max()
    assert with_level.by_level.mean[-1] > 0.3 and "by_level" in with_level.to_dict()
    assert len(residual_rate_figure(without).axes) == 2 and len(residual_rate_figure(with_level).axes) == 3
    assert adequacy.size_ratio == pytest.approx(np.sqrt(with_level.tests["level"].structure_variance) / 0.5, rel=0.1)


def test_residual_profile_locates_an_error_at_the_troughs():
    time, current = paper_current(100.0)
    rng = np.random.default_rng(7)
    rev = find_reversals(current)
    residual = 0.5 * rng.standard_normal(time.size)
    for k in rev.troughs[1:]:  # an error bump of 3 um right after each trough (not the first)
        residual[k : k + 50] += 3.0 * np.exp(-np.arange(50) / 15.0)
    profile = residual_profile(time, current, residual, slice(0, 1001), output_range=300.0)
    # the bump lasts 0.5 s, while the current rises by ~0.12 A: all in the first 0.25 A bin
    assert profile.rising.mean[0] > 0.3 and np.all(np.abs(profile.rising.mean[2:]) < 0.2)
    assert np.all(np.abs(profile.falling.mean[profile.falling.count > 0]) < 0.2)
    early = profile.by_since_reversal.mean[0]
    assert early > 0.5  # and just after a reversal
    troughs = profile.extrema.kind < 0
    assert np.all(profile.extrema.residual[troughs][1:] > 1.0)
    assert profile.tests["low_frequency"].z > 5
    d = profile.to_dict()
    assert {"rms", "max_error_pct", "tests", "cycles", "extrema", "rising", "falling", "acf"} <= set(d)


def test_residual_profile_input_errors():
    time, current = paper_current(50.0)
    r = np.zeros(time.size)
    with pytest.raises(ValueError, match="at least 20"):
        residual_profile(time, current, r, slice(0, 10), output_range=1.0)
    with pytest.raises(ValueError, match="noise model must be given"):
        residual_profile(time, current, r, None, output_range=1.0)
    with pytest.raises(ValueError, match="non-finite"):
        residual_profile(time, current, np.full(time.size, np.nan), slice(0, 500), output_range=1.0)
    with pytest.raises(ValueError, match="samples, expected"):
        residual_profile(time, current, r[:-1], slice(0, 500), output_range=1.0)
    profile = residual_profile(
        time,
        current,
        r + np.random.default_rng(0).standard_normal(time.size),
        None,
        output_range=1.0,
        noise=ARNoise(np.zeros(0), 1.0, 1.0, 10**9),
    )
    assert profile.energised.all()
