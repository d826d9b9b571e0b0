"""Noise model: quiet-segment detection, sigma and AR(1) estimates, the significance rule,
the no-quiet-segment error and its fallbacks, whitening and the exact AR(1) likelihood."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import multivariate_normal

from identify.data.records import Record
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


@pytest.mark.parametrize("uneven", [False, True])
def test_log_likelihood_of_rows_in_lockstep_equals_each_row_alone(uneven):
    """Rows are summed four at a time in lockstep, the groups on numba's threads: each row's
    value is the one it has alone, on one thread or two (an even grid and an uneven one)."""
    import numba

    from identify.fitting.noise import log_likelihood_of_rows

    rng = np.random.default_rng(6)
    data = rng.normal(size=300)
    rows = data + rng.normal(scale=0.1, size=(11, 300))
    noise = NoiseModel(sigma=0.1, rho=0.4, kind="ar1", source="user")
    correlations = 0.4 ** rng.integers(1, 4, size=299).astype(float) if uneven else None
    alone = [
        log_likelihood_of_rows(data, rows[k : k + 1], np.arange(1), noise, correlations=correlations)[0]
        for k in range(11)
    ]
    before = numba.get_num_threads()
    try:
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            together = log_likelihood_of_rows(data, rows, np.arange(11), noise, correlations=correlations)
            np.testing.assert_array_equal(together, alone)
    finally:
        numba.set_num_threads(before)


# -- uneven sampling: each step's own correlation (module docstring, "Uneven sampling") -------


def _kept(n, every, around, centres):
    """Indices 0, every, 2 every, ... with ``around`` samples on each side of ``centres`` (as
    the working copy and ``--every`` keep them) and the last one."""
    near = (np.asarray(centres)[:, None] + np.arange(-around, around + 1)[None, :]).ravel()
    return np.union1d(np.union1d(np.arange(0, n, every), near[(near >= 0) & (near < n)]), [n - 1])


def test_step_correlations_are_rho_to_the_power_of_each_step():
    noise = NoiseModel(sigma=1.0, rho=0.6, kind="ar1", dt=0.01)
    even = np.arange(50) * 0.01
    assert noise.step_correlations(even) is None  # an even grid at dt: rho everywhere
    assert noise.step_correlations(even + 1e-13 * np.sin(np.arange(50))) is None  # round-off of the time stamps
    assert NoiseModel(sigma=1.0, rho=0.6, kind="ar1").step_correlations(even[::3]) is None  # no dt: every step one dt
    assert NoiseModel(sigma=1.0, dt=0.01).step_correlations(even[::3]) is None  # white
    time = np.array([0.0, 0.01, 0.03, 0.06, 0.065, 0.165])
    np.testing.assert_allclose(noise.step_correlations(time), [0.6, 0.36, 0.216, 0.6**0.5, 0.6**10], rtol=1e-12)
    negative = NoiseModel(sigma=1.0, rho=-0.5, kind="ar1", dt=0.01)
    # whole steps: the AR(1)'s own (-0.5)^k; a fractional step keeps the sign of its nearest whole step
    np.testing.assert_allclose(negative.step_correlations(time), [-0.5, 0.25, -0.125, -(0.5**0.5), 0.5**10], rtol=1e-12)
    close = noise.step_correlations(np.array([0.0, 1e-9, 0.01]))
    assert close[0] == 0.99  # clipped as rho is


@pytest.mark.parametrize("rho", [0.7, -0.4])
def test_a_thinned_record_keeps_the_exact_ar1_likelihood(rho):
    """Reference: the multivariate normal of the kept samples of an AR(1) at the full rate,
    covariance sigma^2 rho^|i - j| over their original indices: the working copy and
    ``--every`` keep every k-th sample and the reversals at the full rate. Positive rho also
    at fractional steps: the Ornstein-Uhlenbeck covariance sigma^2 rho^(|t_i - t_j| / dt)."""
    rng = np.random.default_rng(11)
    sigma, dt, n = 0.6, 0.01, 400
    kept = _kept(n, 9, 3, [57, 200, 333])
    time = kept * dt
    lags = np.abs(np.subtract.outer(kept, kept))
    reference = multivariate_normal(np.zeros(kept.size), sigma**2 * rho**lags)
    e = reference.rvs(random_state=rng)
    noise = NoiseModel(sigma=sigma, rho=rho, kind="ar1", dt=dt)
    assert log_likelihood(e, noise, time=time) == pytest.approx(reference.logpdf(e), rel=1e-10)
    one_rho = log_likelihood(e, noise)  # every step taken as one dt: not the record's density
    assert abs(one_rho - reference.logpdf(e)) > 1.0
    if rho > 0:
        jittered = np.sort(time + rng.uniform(-0.3, 0.3, time.size) * dt)
        steps = np.abs(np.subtract.outer(jittered, jittered)) / dt
        ou = multivariate_normal(np.zeros(kept.size), sigma**2 * rho**steps)
        assert log_likelihood(e, noise, time=jittered) == pytest.approx(ou.logpdf(e), rel=1e-10)


def test_whitening_a_thinned_ar1_record_makes_it_white():
    rng = np.random.default_rng(12)
    sigma, rho, dt, n = 0.5, 0.8, 0.001, 60000
    e = ar1_noise(rng, n, sigma, rho)
    kept = _kept(n, 18, 50, np.arange(2500, n, 5000))  # the working copy of a 1 kHz record
    noise = NoiseModel(sigma=sigma, rho=rho, kind="ar1", dt=dt)
    w = whiten(e[kept], noise, time=kept * dt)
    assert np.std(w) == pytest.approx(1.0, abs=0.03)  # se 0.009
    assert abs(float(w[1:] @ w[:-1] / (w @ w))) < 0.04  # se 0.01
    blind = whiten(e[kept], NoiseModel(sigma=sigma, rho=rho**18, kind="ar1"))  # one correlation for every step
    assert float(blind[1:] @ blind[:-1] / (blind @ blind)) > 0.1


def test_the_fused_kernels_take_each_steps_correlation():
    """whiten_rows (bit for bit) and log_likelihood_of_rows (to rounding) with an uneven grid
    equal whiten and log_likelihood with it; a time of the wrong length is refused."""
    from identify.fitting.noise import log_likelihood_of_rows, whiten_rows

    rng = np.random.default_rng(13)
    kept = _kept(700, 7, 4, [100, 350, 600])
    time = kept * 0.01
    data = rng.normal(size=kept.size)
    rows = data + rng.normal(scale=0.1, size=(6, kept.size))
    rows[5, 3] = np.nan
    noise = NoiseModel(sigma=0.1, rho=0.5, kind="ar1", dt=0.01)
    w, finite = whiten_rows(data, rows, noise, 0.1, time=time)
    np.testing.assert_array_equal(w, whiten(data[None, :] - rows, noise, 0.1, time=time))
    assert finite.tolist() == [True] * 5 + [False]
    picked = np.array([4, 0, 2])
    expected = log_likelihood(data[None, :] - rows[picked], noise, time=time)
    assert np.allclose(log_likelihood_of_rows(data, rows, picked, noise, time=time), expected, rtol=1e-12, atol=0)
    even = log_likelihood_of_rows(data, rows, picked, noise)
    assert not np.allclose(even, expected, rtol=1e-6)
    with pytest.raises(ValueError, match="time has shape"):
        whiten(data, noise, time=time[:-1])


def test_the_noise_estimate_keeps_its_step_and_a_thinned_record_its_own():
    rng = np.random.default_rng(14)
    e = ar1_noise(rng, 5000, 0.4, 0.6)
    rec = make_record(e, 3000, n_on=2000, fs=1000.0)
    noise = estimate_noise(rec)
    assert noise.kind == "ar1" and noise.dt == pytest.approx(0.001, rel=1e-12)
    assert NoiseModel.from_dict(noise.to_dict()) == noise
    assert NoiseModel.from_dict({k: v for k, v in noise.to_dict().items() if k != "dt"}).dt is None  # older files
    with pytest.raises(ValueError, match="dt"):
        NoiseModel(sigma=1.0, rho=0.3, kind="ar1", dt=0.0)
    # a quiet start with one sample missing in ten: rho from the pairs one dt apart
    keep = np.flatnonzero(np.arange(5000) % 10 != 5)
    gappy = Record(rec.time[keep], rec.current[keep], rec.displacement[keep], source="gaps", sha256="")
    estimate = estimate_noise(gappy)
    assert estimate.dt == pytest.approx(0.001, rel=1e-12)
    assert estimate.rho == pytest.approx(noise.rho, abs=0.03)


def test_a_drawn_noise_has_the_models_sigma_and_correlation_on_its_grid():
    """``NoiseModel.draw``: the marginal sd and the lag-1 correlation of the model on its own
    grid, ``rho**k`` on a grid of every k-th sample, white noise for ``rho = 0`` (the same
    draws as ``sigma * standard_normal``), an uneven grid each step's own correlation."""
    sigma, rho, dt = 0.4, 0.6, 0.01
    ar1 = NoiseModel(sigma, rho, "ar1", source="user", dt=dt)
    even = np.arange(4000) * dt
    for grid, expected in ((even, rho), (even[::3], rho**3)):
        eps = ar1.draw(grid, np.random.default_rng(2), size=40)
        assert eps.shape == (40, grid.size)
        assert abs(eps.std() / sigma - 1.0) < 0.03
        lag1 = np.mean(eps[:, 1:] * eps[:, :-1]) / np.mean(eps * eps)
        assert abs(lag1 - expected) < 0.02
    white = NoiseModel(sigma, source="user", dt=dt)
    assert np.array_equal(
        white.draw(even, np.random.default_rng(3)), sigma * np.random.default_rng(3).standard_normal(even.size)
    )
    uneven = np.cumsum(np.where(np.arange(3000) % 2 == 0, dt, 2 * dt))
    eps = ar1.draw(uneven, np.random.default_rng(4), size=60)
    products = eps[:, 1:] * eps[:, :-1] / sigma**2
    assert abs(products[:, 0::2].mean() - rho**2) < 0.03  # the steps of 2 dt, from the first on
    assert abs(products[:, 1::2].mean() - rho) < 0.03
