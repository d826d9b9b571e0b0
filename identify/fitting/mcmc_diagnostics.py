"""ArviZ's convergence diagnostics of an ensemble chain, computed without importing ArviZ.

:func:`multichain_statistics` is ``arviz.stats.diagnostics._multichain_statistics`` (ArviZ
0.23, the function behind ``az.summary(kind="diagnostics")``): the Monte Carlo standard
errors of the mean and of the standard deviation, the bulk and tail effective sample sizes
and the rank-normalised split-R-hat of one parameter's ``(chain, draw)`` array (Vehtari et
al. 2021), with the same operations in the same order, so the figures are ArviZ's to the
last bits: the variances ArviZ takes from its numba kernel (a running sum and sum of
squares, ``stats_variance_1d``) are taken from the same loop here, the quantiles from the
same type-7 formula (``scipy.stats.mstats.mquantiles``), the ranks and normal scores from
the same scipy functions, the autocovariances from the same numpy FFTs.

Why: importing ArviZ costs 2-6 s on the team machine and ``az.summary`` another 0.2-1 s per
call (xarray's machinery around the same arithmetic), paid inside ``study``'s sampling
phase at every convergence check that passes tau; this module costs milliseconds.
``tests/test_ecosystem.py`` compares the figures with ``az.rhat``, ``az.ess``, ``az.mcse``
and ``az.summary`` (relative 1e-12).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import stats
from scipy.fft import next_fast_len

__all__ = ["multichain_statistics"]


@njit(cache=True)
def _variance(data, ddof):
    """ArviZ's ``stats_variance_1d``: one pass of sums (this order of operations)."""
    a_a, b_b = 0.0, 0.0
    for i in data:
        a_a = a_a + i
        b_b = b_b + i * i
    var = b_b / (len(data)) - ((a_a / (len(data))) ** 2)
    var = var * (len(data) / (len(data) - ddof))
    return var


@njit(cache=True)
def _row_variances(data, ddof):
    """ArviZ's ``stats_variance_2d`` along axis 1."""
    out = np.zeros(data.shape[0])
    for i in range(data.shape[0]):
        out[i] = _variance(data[i], ddof)
    return out


def _split_chains(ary):
    half = ary.shape[1] // 2
    return np.vstack((ary[:, :half], ary[:, -half:]))


def _z_scale(ary):
    rank = stats.rankdata(ary, method="average", nan_policy="omit")
    rank = (rank - 3 / 8) / (rank.size - 2 * (3 / 8) + 1)  # Blom's back-transformation
    return stats.norm.ppf(rank).reshape(ary.shape)


def _quantiles(ary, probabilities):
    """ArviZ's quantile (R's type 7, through ``scipy.stats.mstats.mquantiles``)."""
    x = np.sort(ary, axis=None)
    n = len(x)
    p = np.asarray(probabilities, dtype=float)
    aleph = n * p + (1.0 + p * (1.0 - 1.0 - 1.0))
    k = np.floor(aleph.clip(1, n - 1)).astype(int)
    gamma = (aleph - k).clip(0, 1)
    return (1.0 - gamma) * x[(k - 1).tolist()] + gamma * x[k.tolist()]


def _autocov(ary):
    n = ary.shape[1]
    m = next_fast_len(2 * n)
    ary = ary - ary.mean(1, keepdims=True)
    spectrum = np.fft.rfft(ary, n=m, axis=1)
    spectrum *= np.conjugate(spectrum)
    cov = np.fft.irfft(spectrum, n=m, axis=1)[:, :n]
    cov /= n
    return cov


def _rhat(ary):
    ary = np.asarray(ary, dtype=float)
    if np.isnan(ary).any():
        return np.nan
    num_samples = ary.shape[1]
    chain_mean = np.mean(ary, axis=1)
    chain_var = _row_variances(ary, 1)
    between_chain_variance = num_samples * _variance(chain_mean, 1)
    within_chain_variance = np.mean(chain_var)
    return np.sqrt((between_chain_variance / within_chain_variance + num_samples - 1) / (num_samples))


def _ess(ary):
    """ArviZ's ``_ess`` (Geyer's initial positive and monotone sequences) of a 2-D array."""
    ary = np.asarray(ary, dtype=float)
    if np.isnan(ary).any():
        return np.nan
    if (np.max(ary) - np.min(ary)) < np.finfo(float).resolution:
        return ary.size
    n_chain, n_draw = ary.shape
    acov = _autocov(ary)
    chain_mean = ary.mean(axis=1)
    mean_var = np.mean(acov[:, 0]) * n_draw / (n_draw - 1.0)
    var_plus = mean_var * (n_draw - 1.0) / n_draw
    if n_chain > 1:
        var_plus += _variance(chain_mean, 1)
    rho_hat_t = np.zeros(n_draw)
    rho_hat_even = 1.0
    rho_hat_t[0] = rho_hat_even
    rho_hat_odd = 1.0 - (mean_var - np.mean(acov[:, 1])) / var_plus
    rho_hat_t[1] = rho_hat_odd
    t = 1
    while t < (n_draw - 3) and (rho_hat_even + rho_hat_odd) > 0.0:
        rho_hat_even = 1.0 - (mean_var - np.mean(acov[:, t + 1])) / var_plus
        rho_hat_odd = 1.0 - (mean_var - np.mean(acov[:, t + 2])) / var_plus
        if (rho_hat_even + rho_hat_odd) >= 0:
            rho_hat_t[t + 1] = rho_hat_even
            rho_hat_t[t + 2] = rho_hat_odd
        t += 2
    max_t = t - 2
    if rho_hat_even > 0:
        rho_hat_t[max_t + 1] = rho_hat_even
    t = 1
    while t <= max_t - 2:
        if (rho_hat_t[t + 1] + rho_hat_t[t + 2]) > (rho_hat_t[t - 1] + rho_hat_t[t]):
            rho_hat_t[t + 1] = (rho_hat_t[t - 1] + rho_hat_t[t]) / 2.0
            rho_hat_t[t + 2] = rho_hat_t[t + 1]
        t += 2
    ess = n_chain * n_draw
    tau_hat = -1.0 + 2.0 * np.sum(rho_hat_t[: max_t + 1]) + np.sum(rho_hat_t[max_t + 1 : max_t + 2])
    tau_hat = max(tau_hat, 1 / np.log10(ess))
    ess = ess / tau_hat
    if np.isnan(rho_hat_t).any():
        ess = np.nan
    return ess


def multichain_statistics(ary) -> tuple[float, float, float, float, float]:
    """``(mcse_mean, mcse_sd, ess_bulk, ess_tail, r_hat)`` of one parameter's ``(chain, draw)``
    array, as ``az.summary(kind="diagnostics")`` gives them (NaN where ArviZ gives none:
    fewer than 4 draws, a NaN value; R-hat also needs 2 chains)."""
    ary = np.ascontiguousarray(np.atleast_2d(ary), dtype=float)  # C order: ArviZ's sums in its order
    if np.isnan(ary).any() or ary.shape[1] < 4:
        return np.nan, np.nan, np.nan, np.nan, np.nan
    z_split = _z_scale(_split_chains(ary))
    quantile05, quantile95 = _quantiles(ary, [0.05, 0.95])
    ess_tail_value = min(_ess(_split_chains(ary <= quantile05)), _ess(_split_chains(ary <= quantile95)))
    if ary.shape[0] < 2:
        rhat_value = np.nan
    else:
        rhat_bulk = _rhat(z_split)
        ary_folded = np.abs(ary - np.median(ary))
        rhat_tail = _rhat(_z_scale(_split_chains(ary_folded)))
        rhat_value = max(rhat_bulk, rhat_tail)
    ess_mean_value = _ess(_split_chains(ary))
    sims_c2 = (ary - ary.mean()) ** 2
    sims_c2_sum = sims_c2.sum()
    var = sims_c2_sum / (sims_c2.size - 1)
    mcse_mean_value = np.sqrt(var / ess_mean_value)
    ess_bulk_value = _ess(z_split)
    evar = sims_c2_sum / sims_c2.size
    ess_mean_sims = _ess(_split_chains(sims_c2))
    varvar = ((sims_c2**2).mean() - evar**2) / ess_mean_sims
    varsd = varvar / evar / 4
    mcse_sd_value = np.sqrt(varsd)
    return mcse_mean_value, mcse_sd_value, ess_bulk_value, ess_tail_value, rhat_value
