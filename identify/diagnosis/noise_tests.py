r"""Is a residual noise? The noise reference of the quiet start and the three tests.

The noise reference is the record's quiet (unenergised) segment: an
AR(p) model (:class:`ARNoise`, order by AIC, ``p <= 5``) fitted to it after removing a
straight line (so a slowly drifting sensor shows up as *structure* in the residual,
not as noise). Three tests compare the residual with it:

``variance``
    :math:`R = \overline{r^2} / \hat\sigma^2`, a ratio of two variance estimates: under
    the null :math:`R` over its expectation is :math:`F(n_{\mathrm{eff}}, n_{q,\mathrm{eff}})`,
    the first for the residual's own sampling error, the second for the error of the
    quiet segment's :math:`\hat\sigma^2`. ``n_eff`` is the number of samples divided by
    the noise's variance inflation :math:`\sum_k \rho_k^2` (for AR(1):
    :math:`(1+\rho^2)/(1-\rho^2)`).
``ljung_box``
    Ljung-Box :math:`Q = n(n+2)\sum_{k=1}^m \hat\rho_k^2/(n-k)` on the residual
    *whitened* by the quiet segment's AR filter; :math:`\chi^2_m` under the null, plus
    the error of that filter (:func:`ljung_box`: a scaled :math:`\chi^2_p` term; the
    p-value is that of the sum).
``low_frequency``
    Block means of length ``L`` (default 0.2 s): under the null each has the variance
    :math:`V_L = L^{-2}\sum_{|k|<L}(L-|k|)\gamma_k` of the AR noise, so
    :math:`S = \sum_b \bar r_b^2 / \hat V_L \sim \chi^2_B\, V_L / \hat V_L`. The
    reference :math:`\hat V_L` is estimated from the quiet segment, and at low frequency
    its error is not only that of :math:`\hat\sigma^2`: it rests on the fitted AR
    coefficients too (:meth:`ARNoise.block_mean_variance_relative_sd`, about 10 % for
    1000 quiet samples of AR(1) noise with :math:`\phi = 0.35`, against 7.6 % of
    :math:`\chi^2_B/B` for 350 blocks). With :math:`\ln(\hat V_L / V_L)` normal (delta
    method), the p-value is that of the mixture,
    :math:`P(S > s) = E_\epsilon[\bar F_{\chi^2_B}(s e^\epsilon)]` (Gauss-Hermite).
    ``mean_b \bar r_b^2 - V_L`` estimates the mean square of the slowly varying part of
    the residual (:attr:`StatTest.structure_variance`), which is what a missing physical effect
    leaves: every effect of the library acts on the time scale of the drive (seconds),
    not of the sensor noise (samples).

Each test returns a one-sided p-value and its normal deviate ``z`` (0 mean, unit sd and a
normal tail under the null; beyond the double range of the p-value, an approximate deviate
above 38); the verdict thresholds live in :mod:`identify.diagnosis.adequacy`. Calibration
on pure noise: ``benchmarks/noise_test_calibration.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import special, stats
from scipy.signal import lfilter

from ..data.reversals import as_1d

__all__ = [
    "autocorrelation",
    "ARNoise",
    "fit_ar_noise",
    "StatTest",
    "ljung_box",
    "variance_ratio_test",
    "low_frequency_test",
    "level_test",
]


def autocorrelation(x, max_lag) -> np.ndarray:
    """Sample autocorrelation ``rho_0 .. rho_max_lag`` (mean removed, biased estimator).

    Parameters
    ----------
    x : array_like, shape (n,)
    max_lag : int
        ``0 <= max_lag < n``.

    Returns
    -------
    ndarray, shape (max_lag + 1,)
        ``rho_0 = 1``; all zeros after lag 0 for a constant ``x``.
    """
    xv = as_1d("x", x)
    max_lag = int(max_lag)
    if not (0 <= max_lag < xv.size):
        raise ValueError(f"max_lag must satisfy 0 <= max_lag < {xv.size}, got {max_lag}")
    y = xv - xv.mean()
    n = y.size
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(y, size)
    acov = np.fft.irfft(spectrum * np.conj(spectrum), size)[: max_lag + 1] / n
    if acov[0] <= 0:
        out = np.zeros(max_lag + 1)
        out[0] = 1.0
        return out
    return acov / acov[0]


@dataclass(frozen=True)
class ARNoise:
    r"""Stationary AR(p) noise :math:`e_k = \sum_i \phi_i e_{k-i} + \sigma_\epsilon \epsilon_k`.

    Attributes
    ----------
    coefficients : ndarray, shape (p,)
        :math:`\phi_1 .. \phi_p` (empty for white noise).
    innovation_sigma : float
        :math:`\sigma_\epsilon` [output units].
    sigma : float
        Marginal standard deviation of the noise [output units].
    n_samples : int
        Samples the model was fitted on.
    """

    coefficients: np.ndarray
    innovation_sigma: float
    sigma: float
    n_samples: int

    @property
    def order(self) -> int:
        return int(self.coefficients.size)

    def autocovariance(self, max_lag) -> np.ndarray:
        """Theoretical autocovariance :math:`\\gamma_0..\\gamma_{max\\_lag}`, shape (max_lag+1,) [units^2]."""
        max_lag = int(max_lag)
        if self.order == 0:
            out = np.zeros(max_lag + 1)
            out[0] = self.sigma**2
            return out
        # impulse response psi_j (MA(inf) weights), truncated where negligible
        n_psi = max(4 * max_lag, 2000)
        impulse = np.zeros(n_psi)
        impulse[0] = 1.0
        psi = lfilter([1.0], np.concatenate(([1.0], -self.coefficients)), impulse)
        gamma = np.array([np.dot(psi[: n_psi - k], psi[k:]) for k in range(max_lag + 1)])
        gamma *= self.innovation_sigma**2
        return gamma

    def autocorrelation(self, max_lag) -> np.ndarray:
        """Theoretical autocorrelation, shape (max_lag + 1,)."""
        g = self.autocovariance(max_lag)
        return g / g[0]

    def variance_inflation(self) -> float:
        """:math:`\\sum_k \\rho_k^2` over all lags: the sample-variance inflation (1 for white)."""
        rho = self.autocorrelation(400)
        return float(1.0 + 2.0 * np.sum(rho[1:] ** 2))

    @cached_property
    def positive_long_run_variance(self) -> float:
        r""":math:`\gamma_0 (1 + 2 \sum_{k \ge 1} \max(\rho_k, 0))` over 400 lags [units^2]: a
        bound on ``n`` times the variance of the mean of any ``n`` noise samples (computed once)."""
        rho = self.autocorrelation(400)
        return float(self.sigma**2 * (1.0 + 2.0 * np.sum(np.maximum(rho[1:], 0.0))))

    @cached_property
    def long_run_relative_sd(self) -> float:
        """:meth:`block_mean_variance_relative_sd` of blocks of 400 samples (computed once)."""
        return self.block_mean_variance_relative_sd(400)

    def block_mean_variance(self, block_length) -> float:
        """Variance of the mean of ``block_length`` consecutive noise samples [units^2]."""
        n = int(block_length)
        if n < 1:
            raise ValueError(f"block_length must be >= 1, got {block_length}")
        g = self.autocovariance(n - 1)
        k = np.arange(1, n)
        return float((n * g[0] + 2.0 * np.sum((n - k) * g[1:])) / n**2)

    def block_mean_variance_relative_sd(self, block_length) -> float:
        r"""Relative sampling sd of :meth:`block_mean_variance` as estimated from the quiet segment.

        The long-run variance of the noise rests on the fitted AR coefficients as well
        as on the noise level: a quiet segment of ``n`` samples leaves each coefficient
        uncertain by about ``n^{-1/2}``, and the block-mean variance's sensitivity to
        them grows with the noise's correlation (for AR(1),
        :math:`\partial \ln V_L / \partial \phi \approx 2 / (1 - \phi)`). By the delta
        method, with the Yule-Walker estimates' asymptotic covariance
        :math:`\mathrm{cov}(\hat\phi) = \sigma_\epsilon^2 \Gamma_p^{-1} / n` and
        :math:`\mathrm{var}(\ln \hat\sigma_\epsilon^2) = 2 / n` (independent of :math:`\hat\phi`):

        .. math:: \mathrm{var}(\ln \hat V_L) \approx g^\top \mathrm{cov}(\hat\phi)\, g + 2 / n,
                  \qquad g = \partial \ln V_L / \partial \phi .

        The error of the order choice (AIC) is not included.

        Parameters
        ----------
        block_length : int
            Samples per block ``L >= 1``.

        Returns
        -------
        float
            ``sqrt(var(ln V_L))``: for white noise fitted as white, ``sqrt(2 / n)``.
        """
        n = float(self.n_samples)
        variance = 2.0 / n
        p = self.order
        if p:
            gamma = self.autocovariance(p)
            toeplitz = gamma[np.abs(np.subtract.outer(np.arange(p), np.arange(p)))]
            cov_phi = self.innovation_sigma**2 * np.linalg.inv(toeplitz) / n
            grad = np.empty(p)
            step = 1e-6
            for i in range(p):
                values = []
                for sign in (1.0, -1.0):
                    phi = self.coefficients.copy()
                    phi[i] += sign * step
                    shifted = ARNoise(phi, self.innovation_sigma, self.sigma, self.n_samples)
                    values.append(np.log(shifted.block_mean_variance(block_length)))
                grad[i] = (values[0] - values[1]) / (2.0 * step)
            variance += float(grad @ cov_phi @ grad)
        return float(np.sqrt(variance))

    def whiten(self, x) -> np.ndarray:
        """Innovations of ``x`` under this model, divided by :math:`\\sigma_\\epsilon` (unit variance under the null).

        The first ``p`` samples are dropped (no past to condition on).

        Returns
        -------
        ndarray, shape (n - p,)
        """
        xv = as_1d("x", x)
        p = self.order
        if xv.size <= p + 1:
            raise ValueError(f"need more than {p + 1} samples to whiten with an AR({p}) model")
        e = xv[p:].copy()
        for i in range(p):
            e -= self.coefficients[i] * xv[p - 1 - i : xv.size - 1 - i]
        return e / self.innovation_sigma

    def to_dict(self) -> dict:
        return {
            "order": self.order,
            "coefficients": [float(c) for c in self.coefficients],
            "innovation_sigma": float(self.innovation_sigma),
            "sigma": float(self.sigma),
            "n_samples": int(self.n_samples),
        }


def fit_ar_noise(quiet, max_order=5, detrend=True) -> ARNoise:
    """AR(p) noise model of a quiet segment by Yule-Walker, order by AIC.

    Parameters
    ----------
    quiet : array_like, shape (n,)
        Output samples of the unenergised segment (or any segment of pure noise),
        ``n >= 20``.
    max_order : int, default 5
    detrend : bool, default True
        Remove a least-squares straight line first (a drifting sensor is structure to
        be diagnosed, not noise).

    Returns
    -------
    ARNoise
    """
    q = as_1d("quiet", quiet)
    if q.size < 20:
        raise ValueError(f"the quiet segment has {q.size} samples; at least 20 are needed for a noise model")
    if detrend:
        k = np.arange(q.size, dtype=float)
        slope, intercept = np.polyfit(k, q, 1)
        q = q - (slope * k + intercept)
    else:
        q = q - q.mean()
    n = q.size
    var0 = float(np.mean(q**2))
    if var0 <= 0:
        raise ValueError("the quiet segment is constant: its noise level is zero, nothing to compare with")
    max_order = int(min(max_order, n // 10))
    rho = autocorrelation(q, max(max_order, 1))
    best = (n * np.log(var0), np.zeros(0), var0)  # AIC of white noise
    for p in range(1, max_order + 1):
        toeplitz = rho[np.abs(np.subtract.outer(np.arange(p), np.arange(p)))]
        try:
            phi = np.linalg.solve(toeplitz, rho[1 : p + 1])
        except np.linalg.LinAlgError:
            break
        innov = var0 * (1.0 - np.dot(phi, rho[1 : p + 1]))
        if innov <= 0:
            break
        aic = n * np.log(innov) + 2 * p
        if aic < best[0] - 1e-12:
            best = (aic, phi, innov)
    _, phi, innov = best
    return ARNoise(np.asarray(phi, dtype=float), float(np.sqrt(innov)), float(np.sqrt(var0)), int(n))


# -- tests --------------------------------------------------------------------------------


@dataclass(frozen=True)
class StatTest:
    """One test of "the residual is noise like the quiet segment's".

    Attributes
    ----------
    name : str
        ``"variance"``, ``"ljung_box"`` or ``"low_frequency"``.
    statistic : float
        The raw statistic (see the module docstring).
    null_mean, null_sd : float
        Its mean and sd under the null (the sd to first order in the reference's error).
    z : float
        The standardised excess: the normal deviate of ``p_value`` (one-sided: large =
        structure), not ``(statistic - null_mean) / null_sd``, whose null is skewed.
    p_value : float
        One-sided p-value of the statistic under the null.
    structure_variance : float
        Estimated mean square of the non-noise part [output units^2] (``variance``
        and ``low_frequency`` tests; NaN-free: 0 where it does not apply).
    details : dict
        Test-specific numbers (lags, block length, ...).
    """

    name: str
    statistic: float
    null_mean: float
    null_sd: float
    z: float
    p_value: float
    structure_variance: float = 0.0
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "statistic": float(self.statistic),
            "null_mean": float(self.null_mean),
            "null_sd": float(self.null_sd),
            "z": float(self.z),
            "p_value": float(self.p_value),
            "structure_variance": float(self.structure_variance),
            "details": self.details,
        }


_LEGENDRE_NODES, _LEGENDRE_WEIGHTS = np.polynomial.legendre.leggauss(256)


def _log_sf_chi2_sum(q: float, m: int, scale: float, dof: int) -> float:
    """``log P(chi2_m + scale * chi2_dof > q)`` (see :func:`ljung_box`, Notes)."""
    if scale == 0.0:
        return float(stats.chi2.logsf(q, m))
    top = q / scale
    if top <= 0.0:
        return 0.0
    # y = u^2 takes the chi2_1 density's y^(-1/2) out of the integrand
    half = 0.5 * np.sqrt(top)
    u = half * (_LEGENDRE_NODES + 1.0)
    y = u * u
    log_terms = (
        stats.chi2.logpdf(y, dof)
        + np.log(2.0 * u)
        + stats.chi2.logsf(q - scale * y, m)
        + np.log(half * _LEGENDRE_WEIGHTS)
    )
    return float(min(np.logaddexp(special.logsumexp(log_terms), stats.chi2.logsf(top, dof)), 0.0))


def _z_of(log_p: float, beyond: float) -> float:
    """Normal deviate of a one-sided p-value given by its log; ``beyond`` where the tail
    underflowed (p below ~1e-308: an approximate deviate, far above any threshold)."""
    if np.isfinite(log_p):
        return float(-special.ndtri_exp(min(log_p, 0.0)))
    return float(max(beyond, 38.0))


_HERMITE_NODES, _HERMITE_WEIGHTS = np.polynomial.hermite_e.hermegauss(64)


def _log_sf_chi2_lognormal(s: float, dof: int, log_sd: float) -> float:
    """``log P(chi2_dof * exp(-eps) > s)``, ``eps ~ N(0, log_sd^2)`` (see :func:`low_frequency_test`)."""
    if s <= 0.0:
        return 0.0
    if log_sd == 0.0:
        return float(stats.chi2.logsf(s, dof))
    eps = log_sd * _HERMITE_NODES
    terms = stats.chi2.logsf(s * np.exp(eps), dof) + np.log(_HERMITE_WEIGHTS / np.sqrt(2.0 * np.pi))
    return float(min(special.logsumexp(terms), 0.0))


def ljung_box(whitened, n_lags=40, filter_error=0.0, filter_dof=1) -> StatTest:
    r"""Ljung-Box portmanteau test of whiteness.

    Parameters
    ----------
    whitened : array_like, shape (n,)
        A series that is white under the null (e.g. :meth:`ARNoise.whiten` of the residual).
    n_lags : int, default 40
        Lags ``m`` summed; clipped to ``n // 4``.
    filter_error : float, default 0
        Expected extra ``Q`` from an *estimated* whitening filter: a filter fitted on
        ``n_q`` samples misses the true one by ``~ n_q^{-1/2}`` per coefficient, which
        leaves autocorrelations of that size and adds about ``n / n_q`` per
        coefficient to ``Q`` (``(n / n_q) max(p, 1)`` for an AR(p) filter).
    filter_dof : int, default 1
        Degrees of freedom of that extra term, ``max(p, 1)``: it is distributed as
        :math:`(c / d)\,\chi^2_d` (for AR(1) exactly :math:`(n / n_q)\chi^2_1`, since the
        coefficient's error :math:`\delta\phi` leaves :math:`\delta\rho_k = -\delta\phi\,\phi^{k-1}`).

    Notes
    -----
    The null of ``Q`` is :math:`\chi^2_m + (c/d)\chi^2_d`, mean ``m + c``, variance
    ``2 m + 2 c^2 / d``. With a short quiet segment ``c/d`` is large (7 for a 70 s record
    and a 10 s quiet start) and the second term's exponential tail, far heavier than
    :math:`\chi^2_m`'s, sets the false alarms: a normal z of ``Q`` passes 5 in about
    0.5 % of pure-noise records, and a scaled :math:`\chi^2` of the same mean and
    variance is still too light. The p-value is that of the sum itself,
    :math:`P = \int_0^{Q d/c} f_{\chi^2_d}(y)\, \bar F_{\chi^2_m}(Q - c y / d)\, dy +
    \bar F_{\chi^2_d}(Q d / c)` (Gauss-Legendre in :math:`u = \sqrt y`, in logs, so a
    p-value far below 1e-300 keeps its size), and ``z`` is its normal deviate,
    :math:`\Phi^{-1}(1 - P)`.
    """
    w = as_1d("whitened", whitened)
    n = w.size
    m = int(min(n_lags, n // 4))
    if m < 1:
        raise ValueError(f"ljung_box needs at least 4 samples per lag, got {n} samples")
    if not (np.isfinite(filter_error) and filter_error >= 0):
        raise ValueError(f"filter_error must be a finite number >= 0, got {filter_error!r}")
    if isinstance(filter_dof, bool) or not isinstance(filter_dof, (int, np.integer)) or filter_dof < 1:
        raise ValueError(f"filter_dof must be an integer >= 1, got {filter_dof!r}")
    d = int(filter_dof)
    rho = autocorrelation(w, m)[1:]
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, m + 1))))
    c = float(filter_error)
    null_mean = m + c
    null_variance = 2.0 * m + 2.0 * c * c / d
    log_p = _log_sf_chi2_sum(q, m, c / d, d)
    z = _z_of(log_p, (q - null_mean) / np.sqrt(null_variance))
    p_value = float(np.exp(log_p))
    return StatTest(
        "ljung_box",
        q,
        float(null_mean),
        float(np.sqrt(null_variance)),
        float(z),
        p_value,
        0.0,
        {"n_lags": m, "n": int(n), "lag1": float(rho[0]), "filter_error": c, "filter_dof": d},
    )


def variance_ratio_test(residual, noise: ARNoise, n_fitted=0) -> StatTest:
    """Residual mean square against the quiet segment's noise variance.

    Parameters
    ----------
    residual : array_like, shape (n,)
    noise : ARNoise
        Fitted on the quiet segment (``noise.n_samples`` sets the error of its variance).
    n_fitted : int, default 0
        Parameters fitted to the residual's data (their absorption lowers the expected
        mean square by the factor ``1 - n_fitted / n``).
    """
    r = as_1d("residual", residual)
    n = r.size
    inflation = noise.variance_inflation()
    expected = 1.0 - min(n_fitted, n - 1) / n
    ratio = float(np.mean(r**2) / noise.sigma**2)
    # a ratio of two variance estimates, each a chi-square over its effective samples:
    # (R / expected) ~ F(n / inflation, n_q / inflation) under the null
    dof_residual, dof_quiet = n / inflation, noise.n_samples / inflation
    sd = float(np.sqrt(2.0 / dof_residual + 2.0 / dof_quiet))
    log_p = float(stats.f.logsf(ratio / expected, dof_residual, dof_quiet))
    z = _z_of(log_p, np.log(max(ratio, 1e-300) / expected) / sd)
    return StatTest(
        "variance",
        ratio,
        expected,
        expected * sd,  # the sd of the ratio itself, to first order
        z,
        float(np.exp(log_p)),
        float(max(ratio - expected, 0.0) * noise.sigma**2),
        {"n": int(n), "rms": float(np.sqrt(np.mean(r**2))), "noise_sigma": float(noise.sigma)},
    )


def low_frequency_test(residual, noise: ARNoise, block_length) -> StatTest:
    """Block-mean test for slowly varying structure (see the module docstring).

    Parameters
    ----------
    residual : array_like, shape (n,)
    noise : ARNoise
    block_length : int
        Samples per block ``L >= 1``; the last partial block is dropped.
    """
    r = as_1d("residual", residual)
    L = int(block_length)
    if L < 1:
        raise ValueError(f"block_length must be >= 1, got {block_length}")
    n_blocks = r.size // L
    if n_blocks < 4:
        raise ValueError(f"{r.size} samples make only {n_blocks} blocks of {L}; at least 4 are needed")
    means = r[: n_blocks * L].reshape(n_blocks, L).mean(axis=1)
    block_var = noise.block_mean_variance(L)
    statistic = float(np.sum(means**2) / block_var)
    # the reference V_L is itself estimated from the quiet segment (its level and its
    # correlation): S = chi^2_B (V_L / V_L-hat) under the null, with ln(V_L-hat / V_L) ~
    # N(0, rel^2); its tail is that mixture's, P(S > s) = E[chi2_B.sf(s exp(eps))]
    rel_sd_reference = noise.block_mean_variance_relative_sd(L)
    log_sd = float(np.sqrt(2.0 / n_blocks + rel_sd_reference**2))  # sd of ln(S / B), to first order
    log_p = _log_sf_chi2_lognormal(statistic, n_blocks, rel_sd_reference)
    z = _z_of(log_p, np.log(max(statistic, 1e-300) / n_blocks) / log_sd)
    structure = float(max(np.mean(means**2) - block_var, 0.0))
    return StatTest(
        "low_frequency",
        statistic,
        float(n_blocks),
        n_blocks * log_sd,
        z,
        float(np.exp(log_p)),
        structure,
        {
            "block_length": L,
            "n_blocks": int(n_blocks),
            "block_noise_variance": block_var,
            "reference_relative_sd": float(rel_sd_reference),
        },
    )


# -- the whole profile --------------------------------------------------------------------


#: Finest scale of :func:`level_test`: the record's samples split into ``2**LEVEL_SCALES``
#: output levels. Finer than that, a level interval holds only a few passes of the drive
#: through it, and the test becomes one of time, which the low-frequency test is.
LEVEL_SCALES = 6

#: Fewest samples in a level interval of :func:`level_test` (the normal approximation of its mean).
LEVEL_MIN_SAMPLES = 32


def _largest_level_mean(x, r, long_run, scales, min_samples):
    """``(best, n_intervals)``: the level interval of largest ``|z|`` over the scales of
    :func:`level_test` (its ``z``, scale, index, mean, level range and the scale's mean square
    in excess of the noise), and how many intervals were tested."""
    n = r.size
    order = np.argsort(x, kind="stable")
    cumulative = np.concatenate(([0.0], np.cumsum(r[order])))
    best = {"z": 0.0, "intervals": 0, "structure": 0.0, "interval": -1, "mean": 0.0, "lo": np.nan, "hi": np.nan}
    n_intervals = 0
    for j in range(1, scales + 1):
        count = 2**j
        if n // count < min_samples:
            break
        edges = np.linspace(0, n, count + 1).round().astype(np.int64)
        size = np.diff(edges)
        means = (cumulative[edges[1:]] - cumulative[edges[:-1]]) / size
        z = means / np.sqrt(long_run / size)
        n_intervals += count
        b = int(np.argmax(np.abs(z)))
        if abs(z[b]) > abs(best["z"]):
            best = {
                "z": float(z[b]),
                "intervals": count,
                "structure": float(max(np.sum(size * means**2 - long_run) / n, 0.0)),
                "interval": b,
                "mean": float(means[b]),
                "lo": float(x[order[edges[b]]]),
                "hi": float(x[order[edges[b + 1] - 1]]),
            }
    return best, n_intervals


def _log_p_largest_of(statistic, n_intervals, rel_sd_reference):
    """log P(the largest of ``n_intervals`` ``|z|`` exceeds ``statistic``): each interval's
    two-sided tail mixed over the reference variance's error, ``P(|Z| > s exp(eps / 2))`` with
    ``eps ~ N(0, rel^2)``, then Sidak over the intervals (Bonferroni's bound where one tail is tiny)."""
    eps = rel_sd_reference * _HERMITE_NODES
    tails = np.log(2.0) + special.log_ndtr(-statistic * np.exp(0.5 * eps))
    log_p_one = min(float(special.logsumexp(tails + np.log(_HERMITE_WEIGHTS / np.sqrt(2.0 * np.pi)))), 0.0)
    if log_p_one < -30.0:
        return log_p_one + float(np.log(n_intervals))
    return float(np.log(-np.expm1(n_intervals * np.log1p(-np.exp(log_p_one)))))


def level_test(level, residual, noise: ARNoise, scales=LEVEL_SCALES, min_samples=LEVEL_MIN_SAMPLES) -> StatTest:
    r"""Does the residual have a mean that depends on the output level?

    An adequate model leaves no mean in the residual at any level of its own output; physics
    that acts by level (an end stop, a saturating sensor, a stiffening spring) leaves one over
    a narrow range of levels, which the tests in time dilute over the whole record. The
    samples are sorted by the model's output ``level`` and split into ``2, 4, ..,
    2**scales`` intervals of equal count (every interval at least ``min_samples``); each
    interval's mean residual is standardised by its noise standard deviation, bounded above
    by that of consecutive samples, :math:`\bar r_b \sim N(0, \le \gamma_0 (1 + 2
    \sum_{k \ge 1} \max(\rho_k, 0)) / n_b)`. The statistic is the largest ``|z_b|``; its
    p-value is Sidak's over every interval, each interval's two-sided tail mixed over
    the reference's error as in :func:`low_frequency_test`. The bound and the correction for
    intervals that overlap make the test conservative; a fitted model absorbs part of any such
    mean, which does the same.

    Parameters
    ----------
    level : array_like, shape (n,)
        The model's output at the residual's samples [output units].
    residual : array_like, shape (n,)
    noise : ARNoise
    scales : int, default :data:`LEVEL_SCALES`
    min_samples : int, default :data:`LEVEL_MIN_SAMPLES`

    Returns
    -------
    StatTest
        ``structure_variance``: the mean square over all samples of the interval means in
        excess of their noise, at the scale of the largest ``|z_b|``. ``details``: that scale
        (intervals), the interval and its level range, its mean and ``z``.
    """
    r = as_1d("residual", residual)
    x = as_1d("level", level, r.size)
    long_run = noise.positive_long_run_variance
    best, n_intervals = _largest_level_mean(x, r, long_run, int(scales), int(min_samples))
    statistic = abs(best["z"])
    if n_intervals == 0:
        return StatTest("level", 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, {"intervals": 0, "n_tested": 0})
    rel_sd_reference = noise.long_run_relative_sd
    log_p = _log_p_largest_of(statistic, n_intervals, rel_sd_reference)
    return StatTest(
        "level",
        statistic,
        0.0,
        1.0,
        _z_of(log_p, statistic),
        float(np.exp(log_p)),
        best["structure"],
        {
            "intervals": int(best["intervals"]),
            "n_tested": int(n_intervals),
            "interval": int(best["interval"]),
            "level_range": [best["lo"], best["hi"]],
            "mean": best["mean"],
            "interval_z": best["z"],
            "reference_relative_sd": float(rel_sd_reference),
        },
    )
