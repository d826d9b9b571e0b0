"""Convergence of an emcee chain: autocorrelation times, the stopping rule, R-hat and ESS.

* :func:`integrated_tau` (and :func:`autocorrelation_times`, NaN for no estimate): emcee's
  integrated autocorrelation time per parameter, one inverse FFT per parameter.
* :func:`tau_convergence`: the tau rule at the end of a chain (long enough, stable since
  the previous check); :func:`check_anchor` and :func:`check_due`: which checks can pass and
  are made (the rule of :mod:`identify.fitting.posterior`'s docstring, "Sampling").
* :func:`burn_in`: the discarded steps and the thinning of the reported draws.
* :func:`chain_diagnostics` and :func:`diagnostics_verdict`: ArviZ's split-R-hat, ESS and
  MCSE per parameter (computed without importing ArviZ) and the rule :data:`RHAT_MAX`,
  :data:`ESS_BULK_MIN` on them; :func:`import_arviz` imports ArviZ for those who need it.

The sampler that applies them is :func:`identify.fitting.posterior.sample_posterior`.
"""

from __future__ import annotations

import math
import sys
import warnings

import numpy as np
import scipy.fft

from .mcmc_diagnostics import multichain_statistics

__all__ = [
    "RHAT_MAX",
    "ESS_BULK_MIN",
    "DIAGNOSTICS",
    "import_arviz",
    "chain_diagnostics",
    "burn_in",
    "diagnostics_verdict",
    "finite_or_none",
    "integrated_tau",
    "autocorrelation_times",
    "tau_convergence",
    "check_anchor",
    "check_due",
]


#: The convergence verdict's thresholds beside tau (docs/method.md, "Convergence"): every
#: parameter's rank-normalised split-R-hat below :data:`RHAT_MAX` and bulk effective sample
#: size at least :data:`ESS_BULK_MIN` (Vehtari et al. 2021). Their 1.01 presumes independent
#: chains; emcee's walkers move together and are not (the emcee author's caution, dfm/emcee
#: #279), and split-R-hat of ~70 correlated walkers with ~35 autocorrelation times each
#: scatters above 1.01 at convergence: the bundled record's seed-0 chain had passed the tau
#: rule at 68.7 tau with R-hat 1.018 and was still refused at the 60000-step cap. 1.05 is
#: the threshold commonly used for dependent or few-draw chains.
RHAT_MAX = 1.05
ESS_BULK_MIN = 400.0

#: Names of the per-parameter diagnostics (:func:`chain_diagnostics`), as in summary.json.
DIAGNOSTICS = ("rhat", "ess_bulk", "ess_tail", "mcse_mean", "mcse_sd")


def import_arviz():
    """The ``arviz`` module, imported without its FutureWarning about the coming refactor.

    ArviZ 0.2x writes a once-a-day stamp file (``daily_warning`` in its user cache) when it
    is imported, through a temporary file of a fixed name. Two processes that import it for
    the first time that day race for it, and the loser's import raises FileNotFoundError
    (seen on 2026-12-02: the two test workers' first run of the day; a batch's parallel
    studies would meet it the same way). By then the winner has written the stamp, so the
    import is tried once more, from a clean slate of ``arviz`` modules.
    """
    with warnings.catch_warnings():  # arviz 0.2x announces its refactor on import
        warnings.simplefilter("ignore", FutureWarning)
        try:
            # deferred: imported under the warning filter and retried on the stamp-file race above
            import arviz
        except FileNotFoundError:
            for name in [m for m in sys.modules if m == "arviz" or m.startswith("arviz.")]:
                del sys.modules[name]
            # deferred: the retry of the import above, from a clean slate of arviz modules
            import arviz

    return arviz


def chain_diagnostics(draws) -> dict[str, np.ndarray]:
    """ArviZ's convergence diagnostics per parameter of ``draws`` ``(steps, walkers, D)``.

    The walkers are ArviZ's chains (as in ``arviz.from_emcee``); ``draws`` is the chain
    after burn-in and thinning, the draws ``posterior.nc`` holds. Returns ``{name: (D,)}``
    for :data:`DIAGNOSTICS`: rank-normalised split-R-hat (``arviz.rhat``), bulk and tail
    effective sample sizes (``arviz.ess``, ``method="bulk"``/``"tail"``), and the Monte
    Carlo standard errors of the mean and of the standard deviation (``arviz.mcse``,
    ``method="mean"``/``"sd"``). NaN where ArviZ gives no value (fewer than 4 draws per
    walker). The figures are ``az.summary(kind="diagnostics")``'s, computed by
    :func:`identify.fitting.mcmc_diagnostics.multichain_statistics` with ArviZ's
    arithmetic but without importing ArviZ (2-6 s) or its xarray machinery.
    """
    draws = np.asarray(draws, dtype=float)
    n_dim = draws.shape[2]
    out = {k: np.full(n_dim, np.nan) for k in DIAGNOSTICS}
    if draws.shape[0] < 4:
        return out
    for d in range(n_dim):
        with np.errstate(invalid="ignore", divide="ignore"):  # a parameter that never moved: NaN, as ArviZ's
            stats = multichain_statistics(np.ascontiguousarray(draws[:, :, d].T))  # (chain, draw)
        mcse_mean, mcse_sd, ess_bulk, ess_tail, rhat = stats
        out["rhat"][d], out["ess_bulk"][d], out["ess_tail"][d] = rhat, ess_bulk, ess_tail
        out["mcse_mean"][d], out["mcse_sd"][d] = mcse_mean, mcse_sd
    return out


def burn_in(tau, n_steps) -> tuple[int, int]:
    """``(discard, thin)`` for a chain of ``n_steps`` with autocorrelation times ``tau``."""
    finite = np.isfinite(tau).all()
    tau_max = float(np.max(tau)) if finite else float(n_steps)
    discard = min(int(math.ceil(2 * tau_max)), n_steps - 1)
    tau_min = float(np.min(tau)) if finite else 1.0
    return discard, max(1, int(0.5 * tau_min))


def diagnostics_verdict(diag) -> tuple[bool, str]:
    """(passes, words) of the R-hat and bulk-ESS rule on :func:`chain_diagnostics` output."""
    rhat, ess = diag["rhat"], diag["ess_bulk"]
    if not (np.isfinite(rhat).all() and np.isfinite(ess).all()):
        return False, "R-hat and ESS not available (too few draws)"
    ok = bool(np.max(rhat) < RHAT_MAX and np.min(ess) >= ESS_BULK_MIN)
    words = (
        f"R-hat max {np.max(rhat):.4f} (need < {RHAT_MAX:g}), bulk ESS min {np.min(ess):.0f} (need >= {ESS_BULK_MIN:g})"
    )
    return ok, words


def finite_or_none(x):
    """``x`` as a float, or None when it is not finite (what summary.json stores)."""
    x = float(x)
    return x if math.isfinite(x) else None


def integrated_tau(chain, c=5.0) -> np.ndarray:
    """Integrated autocorrelation time per parameter of a ``(steps, walkers, D)`` chain.

    emcee's estimator (:func:`emcee.autocorr.integrated_time`: walker-averaged
    autocorrelation, Sokal's automatic window with ``c = 5``; agrees with it to 1e-12
    relative), with one real FFT per walker and parameter, one inverse FFT per parameter,
    and no error for short chains (``inf`` where there is no estimate).
    """
    n_steps, _n_walkers, n_dim = chain.shape
    if n_steps < 2:
        return np.full(n_dim, np.inf)
    # Any length >= 2 n - 1 gives the exact (non-circular) autocovariance; scipy's fast
    # length and threads make a 54000-step check ~2.7x cheaper than numpy's power of two.
    n_fft = scipy.fft.next_fast_len(2 * n_steps - 1, real=True)
    tau = np.empty(n_dim)
    for d in range(n_dim):
        x = np.ascontiguousarray(chain[:, :, d].T)  # (walkers, steps): FFTs along the contiguous axis
        x -= x.mean(axis=1, keepdims=True)
        spectrum = scipy.fft.rfft(x, n=n_fft, axis=1, workers=-1)
        # The walker average of the normalised autocorrelations, mean_w acf_w / acf_w[0],
        # is linear in the power spectra: one inverse FFT per parameter, not one per walker.
        with np.errstate(invalid="ignore", divide="ignore"):
            power = (spectrum.real**2 + spectrum.imag**2) / np.sum(x * x, axis=1)[:, None]
            f = scipy.fft.irfft(power.sum(axis=0), n=n_fft, workers=-1)[:n_steps] / x.shape[0]
        taus = 2.0 * np.cumsum(f) - 1.0
        inside = np.arange(n_steps) < c * taus
        window = int(np.argmin(inside)) if inside.any() else n_steps - 1
        tau[d] = taus[window]
    return np.where(np.isfinite(tau), tau, np.inf)  # a chain that never moved: no estimate


def autocorrelation_times(chain) -> np.ndarray:
    """Integrated autocorrelation time per parameter of a ``(steps, walkers, D)`` chain
    (:func:`integrated_tau`: emcee's estimator to 1e-12 relative, one inverse FFT per parameter); NaN
    where there is no estimate (a coordinate that never moved), as
    :func:`emcee.autocorr.integrated_time` gives it."""
    tau = integrated_tau(np.asarray(chain, dtype=float))
    return np.where(np.isfinite(tau), tau, np.nan)


def tau_convergence(chain, check_every, tau_factor, tau_rtol, cache=None):
    """(converged, tau, relative change, message) at the end of ``chain``.

    ``cache`` (dict: chain length -> tau) avoids recomputing the previous check's tau.
    """
    cache = {} if cache is None else cache
    n = chain.shape[0]
    tau = cache[n] if n in cache else integrated_tau(chain)
    cache[n] = tau
    prev_n = n - check_every
    if prev_n >= check_every:
        tau_prev = cache[prev_n] if prev_n in cache else integrated_tau(chain[:prev_n])
        with np.errstate(invalid="ignore"):
            relative = np.abs(tau - tau_prev) / tau
        change = float(np.max(relative)) if np.isfinite(relative).all() else math.inf
    else:
        change = math.inf
    long_enough = bool(np.isfinite(tau).all() and n >= tau_factor * np.max(tau))
    stable = change < tau_rtol
    msg = (
        f"{n} steps = {n / np.max(tau):.1f} x tau_max ({np.max(tau):.1f} steps; need >= {tau_factor:g}), "
        f"tau change since the previous check {change:.1%} (need < {tau_rtol:.0%})"
    )
    return long_enough and stable, tau, change, msg


def check_anchor(n, check_every) -> int:
    """The last anchor at or before step ``n``: anchors are ``check_every`` times
    ``round(2**(i/4))``, i = 0, 1, ... (500, 1000, ..., 16000, 19000, 22500, 27000, 32000,
    38000, 45500, 54000 for ``check_every = 500``): from the 16th on, each is at most 19 %
    past the previous one."""
    i = 0
    while check_every * round(2.0 ** ((i + 1) / 4)) <= n:
        i += 1
    return check_every * round(2.0 ** (i / 4))


def check_due(chain, check_every, tau_factor, cache) -> bool:
    """Whether the convergence check at the end of ``chain`` can pass: its length reaches
    ``tau_factor`` times tau_max of the prefix at the last anchor (:func:`check_anchor`; tau
    computed once per anchor through ``cache``). See :mod:`identify.fitting.posterior`, "Sampling"."""
    n = chain.shape[0]
    anchor = check_anchor(n, check_every)
    if anchor not in cache:
        cache[anchor] = integrated_tau(chain[:anchor])
    tau_max = float(np.max(cache[anchor]))
    return not (math.isfinite(tau_max) and n < tau_factor * tau_max)
