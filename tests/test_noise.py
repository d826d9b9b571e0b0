"""Noise model: quiet-segment detection, sigma and AR(1) estimates, the significance rule,
the no-quiet-segment error and its fallbacks, whitening and the exact AR(1) likelihood."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import multivariate_normal

from identify.fitting.noise import (
    MIN_QUIET_SAMPLES,
    NoiseModel,
    NoQuietSegmentError,
    energised_mask,
    estimate_noise,
    log_likelihood,
    quiet_segment,
    whiten,
)
from identify.data.records import Record


def ar1_noise(rng, n, sigma, rho):
    """Stationary AR(1) with marginal std ``sigma`` (white for rho = 0)."""
    innovations = rng.standard_normal(n)
    innovations[1:] *= math.sqrt(1.0 - rho * rho)
    return sigma * lfilter([1.0], [1.0, -rho], innovations)


def make_record(noise, n_quiet, n_on=400, fs=100.0, drift=0.0, rest=-0.5):
    """A record whose first ``n_quiet`` samples carry zero current."""
    n = n_quiet + n_on
    time = np.arange(n) / fs
    current = np.where(np.arange(n) < n_quiet, 0.0, 1.0 + np.sin(np.arange(n) / 20.0))
    displacement = rest + drift * time + noise[:n]
    return Record(time, current, displacement, source="synthetic", sha256="")


def test_quiet_segment_is_detected_from_the_current_not_a_fixed_duration():
    # 137 quiet samples at 50 Hz = 2.74 s, nothing like the paper's 10 s.
    rng = np.random.default_rng(0)
    rec = make_record(0.2 * rng.standard_normal(600), n_quiet=137, fs=50.0)
    assert quiet_segment(rec.current) == slice(0, 137)
    noise = estimate_noise(rec)
    assert noise.quiet == slice(0, 137) and noise.n_quiet == 137
    mask = energised_mask(rec, noise)
    assert not mask[:137].any() and mask[137:].all()


def test_white_noise_sigma_with_a_drift_removed():
    rng = np.random.default_rng(1)
    sigma = 0.3
    # A drift of 2 um over the 20 s quiet segment would inflate an undetrended std 3x.
    rec = make_record(ar1_noise(rng, 2400, sigma, 0.0), n_quiet=2000, drift=0.1)
    noise = estimate_noise(rec)
    assert noise.kind == "white" and noise.rho == 0.0 and noise.source == "quiet_segment"
    # standard error of sigma_hat is sigma / sqrt(2 n) = 1.6 %; allow 5 %
    assert noise.sigma == pytest.approx(sigma, rel=0.05)


def test_ar1_noise_is_detected_and_estimated():
    rng = np.random.default_rng(2)
    rec = make_record(ar1_noise(rng, 2400, 0.5, 0.6), n_quiet=2000)
    noise = estimate_noise(rec)
    assert noise.kind == "ar1"
    # standard error of rho_hat is sqrt((1 - rho^2) / n) = 0.018; allow 0.06
    assert noise.rho == pytest.approx(0.6, abs=0.06)
    assert noise.sigma == pytest.approx(0.5, rel=0.1)


def test_white_noise_is_called_ar1_at_about_the_significance_level():
    """The rule rejects white noise at the two-sided 1 % level: over 400 white series the
    false-alarm count is binomial(400, 0.01), mean 4; 12 or more has probability < 0.1 %."""
    rng = np.random.default_rng(3)
    false_alarms = 0
    for _ in range(400):
        rec = make_record(rng.standard_normal(700), n_quiet=300)
        false_alarms += estimate_noise(rec).kind == "ar1"
    assert false_alarms < 12
    # and a modest correlation is found almost always at n = 300 (z = 0.3 sqrt(300) = 5.2)
    hits = sum(estimate_noise(make_record(ar1_noise(rng, 700, 1.0, 0.3), n_quiet=300)).kind == "ar1" for _ in range(50))
    assert hits >= 48


def test_no_quiet_segment_raises_naming_both_fallbacks():
    rng = np.random.default_rng(4)
    rec = make_record(rng.standard_normal(500), n_quiet=0)
    with pytest.raises(NoQuietSegmentError) as info:
        estimate_noise(rec)
    message = str(info.value)
    assert "no unenergised start" in message
    assert "--noise-sigma VALUE" in message and "--noise-sigma free" in message


def test_too_short_quiet_segment_raises_with_its_length():
    rng = np.random.default_rng(5)
    rec = make_record(rng.standard_normal(500), n_quiet=30)
    with pytest.raises(NoQuietSegmentError, match=rf"only 30 samples \(at least {MIN_QUIET_SAMPLES} needed\)"):
        estimate_noise(rec)


def test_constant_quiet_segment_is_refused_not_sigma_zero():
    rec = make_record(np.zeros(500), n_quiet=100)
    with pytest.raises(NoQuietSegmentError, match="zero spread"):
        estimate_noise(rec)


def test_fallbacks_user_sigma_and_free():
    rng = np.random.default_rng(6)
    rec = make_record(rng.standard_normal(500), n_quiet=0)
    user = estimate_noise(rec, noise_sigma=0.7)
    assert (user.sigma, user.kind, user.source, user.quiet) == (0.7, "white", "user", None)
    assert estimate_noise(rec, noise_sigma="0.7").sigma == 0.7  # CLI text
    free = estimate_noise(rec, noise_sigma="free")
    assert free.source == "free" and free.is_free and math.isnan(free.sigma)
    assert free.with_sigma(0.4).sigma == 0.4
    for bad in (-1.0, 0.0, "abc", float("nan")):
        with pytest.raises(ValueError, match="noise_sigma"):
            estimate_noise(rec, noise_sigma=bad)


def test_noise_model_validates_and_round_trips():
    with pytest.raises(ValueError, match="sigma"):
        NoiseModel(sigma=0.0)
    with pytest.raises(ValueError, match="rho"):
        NoiseModel(sigma=1.0, rho=1.0, kind="ar1")
    with pytest.raises(ValueError, match="white noise has rho = 0"):
        NoiseModel(sigma=1.0, rho=0.2, kind="white")
    noise = NoiseModel(sigma=0.5, rho=0.3, kind="ar1", source="quiet_segment", quiet=slice(0, 100), n_quiet=100)
    assert NoiseModel.from_dict(noise.to_dict()) == noise


def test_whitening_makes_ar1_noise_white():
    rng = np.random.default_rng(7)
    e = ar1_noise(rng, 20000, 0.5, 0.7)
    w = whiten(e, NoiseModel(sigma=0.5, rho=0.7, kind="ar1"))
    assert np.std(w) == pytest.approx(1.0, abs=0.02)  # se 0.005
    lag1 = float(w[1:] @ w[:-1] / (w @ w))
    assert abs(lag1) < 0.03  # se 0.007


@pytest.mark.parametrize("rho", [0.0, 0.45, -0.3])
def test_log_likelihood_equals_the_multivariate_normal_density(rho):
    """Reference: scipy's multivariate normal with the AR(1) covariance sigma^2 rho^|i-j|,
    which includes the exact first-sample term (tolerance: float round-off)."""
    rng = np.random.default_rng(8)
    n, sigma = 40, 0.8
    e = ar1_noise(rng, n, sigma, rho)
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    reference = multivariate_normal(np.zeros(n), sigma**2 * rho**lags).logpdf(e)
    kind = "white" if rho == 0 else "ar1"
    assert log_likelihood(e, NoiseModel(sigma=sigma, rho=rho, kind=kind)) == pytest.approx(reference, rel=1e-10)
    # batched rows with per-row sigma
    rows = np.vstack([e, 2 * e])
    batch = log_likelihood(rows, NoiseModel(sigma=sigma, rho=rho, kind=kind), sigma=np.array([sigma, 2 * sigma]))
    assert batch[0] == pytest.approx(reference, rel=1e-10)
    assert batch[1] == pytest.approx(reference - n * math.log(2.0), rel=1e-10)


def test_whiten_refuses_a_free_sigma_without_a_value():
    with pytest.raises(ValueError, match="sigma"):
        whiten(np.ones(5), NoiseModel(sigma=float("nan"), source="free"))


@pytest.mark.parametrize("rho", [0.0, 0.6])
def test_fused_row_likelihood_equals_the_reference_formula(rho):
    """log_likelihood_of_rows (the sampler's one-pass kernel) equals log_likelihood on the
    selected rows to rounding (relative 1e-12), white and AR(1), with a per-row sigma too."""
    from identify.fitting.noise import log_likelihood_of_rows

    rng = np.random.default_rng(4)
    data = rng.standard_normal(501)
    model_rows = data + 0.3 * rng.standard_normal((5, 501))
    rows = np.array([4, 0, 2])
    noise = NoiseModel(sigma=0.3, rho=rho, kind="ar1" if rho else "white", source="user", quiet=None, n_quiet=0)
    expected = log_likelihood(data[None, :] - model_rows[rows], noise)
    assert np.allclose(log_likelihood_of_rows(data, model_rows, rows, noise), expected, rtol=1e-12, atol=0)
    sigma = np.array([0.2, 0.3, 0.5])
    expected = log_likelihood(data[None, :] - model_rows[rows], noise, sigma)
    assert np.allclose(log_likelihood_of_rows(data, model_rows, rows, noise, sigma), expected, rtol=1e-12, atol=0)
    with pytest.raises(ValueError, match="sigma"):
        log_likelihood_of_rows(data, model_rows, rows, noise, np.array([0.2, -1.0, 0.3]))


@pytest.mark.parametrize("rho", [0.0, 0.6])
def test_whiten_rows_is_whiten_bit_for_bit(rho):
    """The least squares' fused whitening: the values of whiten(data - rows), and which rows are finite."""
    from identify.fitting.noise import whiten_rows

    rng = np.random.default_rng(2)
    data = rng.normal(size=500)
    rows = data + rng.normal(scale=0.1, size=(5, 500))
    rows[2, 17], rows[3, 0], rows[4, 499] = np.nan, np.inf, -np.inf
    noise = NoiseModel(sigma=0.07, rho=rho, kind="ar1" if rho else "white", source="user")
    w, finite = whiten_rows(data, rows, noise, 0.07)
    np.testing.assert_array_equal(w, whiten(data[None, :] - rows, noise, 0.07))
    np.testing.assert_array_equal(finite, np.isfinite(w).all(axis=1))
    assert finite.tolist() == [True, True, False, False, False]


def test_log_likelihood_of_rows_in_lockstep_equals_each_row_alone():
    """Rows are summed four at a time in lockstep: each row's value is the one it has alone."""
    from identify.fitting.noise import log_likelihood_of_rows

    rng = np.random.default_rng(6)
    data = rng.normal(size=300)
    rows = data + rng.normal(scale=0.1, size=(11, 300))
    noise = NoiseModel(sigma=0.1, rho=0.4, kind="ar1", source="user")
    together = log_likelihood_of_rows(data, rows, np.arange(11), noise)
    alone = [log_likelihood_of_rows(data, rows[k : k + 1], np.arange(1), noise)[0] for k in range(11)]
    np.testing.assert_array_equal(together, alone)
