"""Build a small but real results folder, exactly per docs/CONTRACTS.md, for the report tests.

The report (:mod:`identify.report`) only reads a folder written by ``study``. So that its
tests do not depend on the study code, :func:`build_results_folder` writes one itself,
the honest way and in a couple of seconds:

1. simulate the paper's input (eqs. 14-17) at a low sampling rate, push Table 1 through
   the GPI (:class:`model.Model`), add Gaussian sensor noise of known ``noise_sigma``
   and, optionally, a hidden ripple the model cannot represent (a misfit);
2. estimate the noise from the unenergised start (samples before the current first
   leaves zero): sigma and lag-1 autocorrelation;
3. identifiability: eigen-analysis of the Fisher information of all 19 GPI parameters
   (relative scaling) at Table 1; the exact scaling degeneracy (rho, alpha, tau, a0,
   a3, b0, b3) shows up as the smallest eigenvalue, and is fixed by pinning ``rho``;
4. least squares (:func:`scipy.optimize.least_squares`) of the 18 free parameters from
   Table 1, with the Jacobian-based covariance and standard errors;
5. a short real emcee run (vectorised log-posterior, flat prior within bounds, white
   Gaussian likelihood over the energised part) into ``chain.h5`` with
   :class:`emcee.backends.HDFBackend`, group ``"mcmc"``, holding the free parameters
   only (in :attr:`model.Model.names` order, pinned ones left out);
6. ``fit.json``, ``summary.json`` and ``manifest.json`` with the contract's keys.

The chain is far too short to converge, so ``summary["posterior"]["converged"]`` is
False: that is what the report must then say.
"""

from __future__ import annotations

import hashlib
import json
import platform
import time as _time
from dataclasses import asdict, dataclass
from pathlib import Path

import emcee
import numpy as np
import scipy
from scipy.optimize import least_squares

import model

__all__ = ["FixtureSettings", "build_results_folder", "PINNED_PARAMETER"]

#: The parameter pinned by the fixture's normalisation (fixes the exact scaling degeneracy).
PINNED_PARAMETER = "rho"


@dataclass(frozen=True)
class FixtureSettings:
    """What the fixture simulates and how long it samples.

    Parameters
    ----------
    sampling_rate : float, default 10.0
        Hz; 70 s give 1401 samples.
    noise_sigma : float, default 0.5
        Sensor noise standard deviation [um].
    hidden_ripple : float, default 0.0
        Amplitude [um] of a 0.37 Hz sinusoid added to the energised part of the data
        but not to the model; > 0 makes a misfit (residual RMS above the noise) that the
        GPI cannot absorb.
    n_walkers : int, default 40
    n_steps : int, default 240
    discard : int, default 80
        Burn-in steps left out of the posterior summaries.
    seed : int, default 1
    """

    sampling_rate: float = 20.0
    noise_sigma: float = 0.5
    hidden_ripple: float = 0.0
    n_walkers: int = 40
    n_steps: int = 240
    discard: int = 80
    seed: int = 1


def _write_json(path: Path, payload: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, allow_nan=True))
    tmp.replace(path)


def _combination(eigenvector, names, n_terms=7):
    """``{name: weight}`` of the largest components of a unit eigenvector (sign: largest positive)."""
    order = np.argsort(-np.abs(eigenvector))[:n_terms]
    sign = np.sign(eigenvector[order[0]]) or 1.0
    return {names[i]: round(float(sign * eigenvector[i]), 4) for i in order if abs(eigenvector[i]) > 0.05}


def build_results_folder(directory, settings: FixtureSettings = FixtureSettings()) -> Path:
    """Write a complete results folder (data.npz, chain.h5, fit.json, summary.json, manifest.json).

    Parameters
    ----------
    directory : str or Path
        Created if missing; existing result files in it are overwritten.
    settings : FixtureSettings

    Returns
    -------
    Path
        The folder.
    """
    started = _time.time()
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(settings.seed)

    # 1. record
    time, current = model.paper_current(fs=settings.sampling_rate)
    gpi_model = model.Model()
    truth = model.TABLE1.copy()
    clean = gpi_model(truth, time, current)
    ripple = np.where(current != 0.0, settings.hidden_ripple * np.sin(2 * np.pi * 0.37 * time), 0.0)
    displacement = clean + ripple + settings.noise_sigma * rng.standard_normal(time.size)
    data_path = out / "data.npz"
    with open(str(data_path) + ".tmp", "wb") as handle:
        np.savez(
            handle,
            time=time,
            current=current,
            displacement=displacement,
            input_name=np.array("current"),
            input_unit=np.array("A"),
            output_name=np.array("displacement"),
            output_unit=np.array("um"),
        )
    Path(str(data_path) + ".tmp").replace(data_path)
    data_sha256 = hashlib.sha256(data_path.read_bytes()).hexdigest()

    # 2. noise from the quiet start
    n_quiet = int(np.argmax(current != 0.0))
    quiet = displacement[:n_quiet] - displacement[:n_quiet].mean()
    noise_sigma = float(np.sqrt(np.mean(quiet**2)))
    noise_rho = float(np.sum(quiet[1:] * quiet[:-1]) / np.sum(quiet**2))
    noise_kind = "ar1" if abs(noise_rho) > 2.0 / np.sqrt(n_quiet) else "white"
    noise = {"sigma": noise_sigma, "rho": noise_rho, "kind": noise_kind, "source": "quiet_segment", "n_quiet": n_quiet}
    energised = np.arange(time.size) >= n_quiet

    # 3. identifiability at Table 1: relative-scale Fisher information, central differences,
    #    all 2 * 19 perturbed sets in one vectorised call.
    names = gpi_model.names
    step = 1e-6
    perturbed = np.repeat(truth[None, :], 2 * truth.size, axis=0)
    for i in range(truth.size):
        perturbed[2 * i, i] *= 1 + step
        perturbed[2 * i + 1, i] *= 1 - step
    responses, _ = gpi_model.evaluate(perturbed, time, current)
    jac_relative = ((responses[0::2] - responses[1::2]) / (2 * step))[:, energised].T / noise_sigma
    eigenvalues, eigenvectors = np.linalg.eigh(jac_relative.T @ jac_relative)
    relative = eigenvalues / eigenvalues.max()
    exact = [
        {"eigenvalue": float(eigenvalues[k]), "combination": _combination(eigenvectors[:, k], names)}
        for k in range(names.__len__())
        if relative[k] < 1e-9
    ]
    near = [
        {"eigenvalue": float(eigenvalues[k]), "combination": _combination(eigenvectors[:, k], names)}
        for k in range(len(names))
        if 1e-9 <= relative[k] < 1e-6
    ]

    # 4. least squares of the free parameters
    pinned_index = names.index(PINNED_PARAMETER)
    fit_model = model.Model(gpi_parameters=model.GPI_PARAMETERS.replace(PINNED_PARAMETER, vary=False))
    vary = fit_model.parameters.vary
    lower, upper = fit_model.parameters.lower[vary], fit_model.parameters.upper[vary]

    def full(free):
        theta = np.broadcast_to(truth, np.shape(free)[:-1] + truth.shape).copy()
        theta[..., vary] = free
        return theta

    def residuals(free):
        y, valid = fit_model.evaluate(full(free), time, current)
        if not valid[0]:
            return np.full(int(energised.sum()), 1e6)
        return (displacement - y[0])[energised] / noise_sigma

    lsq_started = _time.time()
    solution = least_squares(residuals, truth[vary], bounds=(lower, upper), x_scale="jac", method="trf")
    lsq_seconds = _time.time() - lsq_started
    theta_lsq = full(solution.x)
    jac = solution.jac
    covariance_free = np.linalg.pinv(jac.T @ jac)
    covariance = np.zeros((truth.size, truth.size))
    covariance[np.ix_(vary, vary)] = covariance_free
    stderr = np.full(truth.size, np.nan)
    stderr[vary] = np.sqrt(np.diag(covariance_free))
    residual = displacement - fit_model(theta_lsq, time, current)
    rms = float(np.sqrt(np.mean(residual[energised] ** 2)))
    measured_range = float(np.ptp(displacement[energised]))
    max_error_pct = float(100.0 * np.max(np.abs(residual[energised])) / measured_range)
    n_free = int(vary.sum())
    reduced_chi2 = float(np.sum((residual[energised] / noise_sigma) ** 2) / (energised.sum() - n_free))
    fit_payload = {
        "model": fit_model.to_dict(),
        "names": list(names),
        "theta": theta_lsq.tolist(),
        "stderr": [None if not np.isfinite(s) else float(s) for s in stderr],
        "covariance": covariance.tolist(),
        "vary": vary.tolist(),
        "rms": rms,
        "max_error_pct": max_error_pct,
        "reduced_chi2": reduced_chi2,
        "noise": noise,
        "n_starts": 1,
        "success": bool(solution.success),
        "message": str(solution.message),
        "seconds": lsq_seconds,
    }

    # 5. a short real emcee run
    def log_posterior(free_batch):
        theta = full(free_batch)
        inside = fit_model.in_bounds(theta)
        log_prob = np.full(theta.shape[0], -np.inf)
        if inside.any():
            y, valid = fit_model.evaluate(theta[inside], time, current)
            chi2 = np.sum(((displacement - y)[:, energised] / noise_sigma) ** 2, axis=1)
            log_prob[np.flatnonzero(inside)[valid]] = -0.5 * chi2[valid]
        return log_prob

    start = rng.multivariate_normal(solution.x, covariance_free, size=settings.n_walkers, method="eigh")
    bad = ~np.isfinite(log_posterior(start))
    for _ in range(100):  # redraw walkers that start outside the support
        if not bad.any():
            break
        start[bad] = rng.multivariate_normal(solution.x, covariance_free, size=int(bad.sum()), method="eigh")
        bad = ~np.isfinite(log_posterior(start))
    else:
        raise RuntimeError(f"fixture: {int(bad.sum())} walkers still start outside the support")
    chain_path = out / "chain.h5"
    if chain_path.exists():
        chain_path.unlink()
    backend = emcee.backends.HDFBackend(str(chain_path), name="mcmc")
    backend.reset(settings.n_walkers, n_free)
    sampler = emcee.EnsembleSampler(settings.n_walkers, n_free, log_posterior, vectorize=True, backend=backend)
    sampler.random_state = np.random.RandomState(settings.seed).get_state()
    mcmc_started = _time.time()
    # walkers are drawn from the LSQ covariance, so they are independent; the check trips
    # only on the parameters' very different magnitudes.
    sampler.run_mcmc(start, settings.n_steps, progress=False, skip_initial_state_check=True)
    mcmc_seconds = _time.time() - mcmc_started
    tau_free = sampler.get_autocorr_time(discard=settings.discard, tol=0, quiet=True)
    kept = sampler.get_chain(discard=settings.discard, flat=True)
    n_kept = (settings.n_steps - settings.discard) * settings.n_walkers
    ess_free = n_kept / tau_free
    lo95, median, hi95 = np.percentile(kept, [2.5, 50.0, 97.5], axis=0)
    converged = bool(settings.n_steps - settings.discard >= 50.0 * tau_free.max())

    # 6. summaries
    parameters = []
    free_index = {name: k for k, name in enumerate(np.asarray(names)[vary])}
    for i, p in enumerate(fit_model.parameters):
        k = free_index.get(p.name)
        parameters.append(
            {
                "name": p.name,
                "unit": p.unit,
                "table1": float(model.TABLE1[i]),
                "lsq": float(theta_lsq[i]),
                "lsq_stderr": None if k is None else float(stderr[i]),
                "median": float(theta_lsq[i]) if k is None else float(median[k]),
                "lo95": float(theta_lsq[i]) if k is None else float(lo95[k]),
                "hi95": float(theta_lsq[i]) if k is None else float(hi95[k]),
                "tau": None if k is None else float(tau_free[k]),
                "ess": None if k is None else float(ess_free[k]),
                "vary": k is not None,
            }
        )
    summary = {
        "model": fit_model.to_dict(),
        "units": {"input": "A", "output": "um"},
        "noise": noise,
        "fit": {"rms": rms, "max_error_pct": max_error_pct, "reduced_chi2": reduced_chi2, "seconds": lsq_seconds},
        "identifiability": {
            "normalisation": {PINNED_PARAMETER: float(truth[pinned_index])},
            "exact": exact,
            "near": near,
        },
        "posterior": {
            "converged": converged,
            "n_walkers": settings.n_walkers,
            "n_steps": settings.n_steps,
            "discard": settings.discard,
            "thin": 1,
            "acceptance_fraction": float(np.mean(sampler.acceptance_fraction)),
            "tau_max": float(tau_free.max()),
            "seconds": mcmc_seconds,
        },
        "parameters": parameters,
    }
    manifest = {
        "seed": settings.seed,
        "data_file": str(data_path),
        "data_sha256": data_sha256,
        "settings": {"fixture": asdict(settings), "effects": [], "n_operators": 12, "reading": "swapped"},
        "versions": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "emcee": emcee.__version__,
        },
        "git_commit": "fixture (tests/report_fixture.py)",
        "start_time": _time.strftime("%Y-%m-%dT%H:%M:%S", _time.localtime(started)),
        "end_time": _time.strftime("%Y-%m-%dT%H:%M:%S"),
        "seconds": _time.time() - started,
    }
    _write_json(out / "fit.json", fit_payload)
    _write_json(out / "summary.json", summary)
    _write_json(out / "manifest.json", manifest)
    return out
