"""Build a small but real results folder, exactly as ``study`` writes it, for the report tests.

The report (:mod:`identify.report`) only reads a folder written by ``study``. Until that
command exists, :func:`build_results_folder` runs a miniature study from the project's
own building blocks and writers, in a few seconds:

1. simulate the paper's input (eqs. 14-17) at a low sampling rate, push Table 1 through
   the GPI (:class:`model.Model`), add Gaussian sensor noise of known ``noise_sigma``
   and, optionally, a hidden ripple the model cannot represent (a misfit); write it as a
   CSV with :func:`identify.records.write_record` and load it back (so the data file
   and its sha256 are real);
2. noise from the quiet start (:func:`identify.noise.estimate_noise`), or a free sigma;
3. least squares from Table 1 with the normalisation of
   :func:`identify.identifiability.normalised_model` (one start);
4. identifiability: :func:`identify.identifiability.analyse_identifiability` of the
   central-difference Jacobian at the optimum;
5. a short real emcee run (:func:`identify.posterior.sample_posterior` with a tiny step
   cap) into ``chain.h5``;
6. ``data.npz``, ``fit.json``, ``summary.json`` and ``manifest.json`` through
   :mod:`identify.results`.

The chain is far too short to converge, so ``summary["posterior"]["converged"]`` is
False: that is what the report must then say.
"""

from __future__ import annotations

import time as _time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import model
from identify import results
from identify.identifiability import NORMALISATION, analyse_identifiability, normalised_model
from identify.lsq import WhitenedResiduals, fit_least_squares
from identify.noise import NoiseModel, estimate_noise
from identify.posterior import LogPosterior, initial_walkers, sample_posterior
from identify.records import load_record, write_record

__all__ = ["FixtureSettings", "build_results_folder"]


@dataclass(frozen=True)
class FixtureSettings:
    """What the fixture simulates and how long it samples.

    Parameters
    ----------
    sampling_rate : float, default 10.0
        Hz; 70 s give 701 samples.
    noise_sigma : float, default 0.5
        Sensor noise standard deviation [um].
    hidden_ripple : float, default 0.0
        Amplitude [um] of a 0.37 Hz sinusoid added to the energised part of the data
        but not to the model; > 0 makes a misfit (residual RMS above the noise) that the
        GPI cannot absorb.
    free_noise : bool, default False
        Sample the noise sigma as a free parameter (``noise_log_sigma``) instead of
        taking it from the quiet segment.
    n_walkers : int, default 40
    max_steps : int, default 160
        The sampler's step cap (far below convergence).
    seed : int, default 1
    """

    sampling_rate: float = 10.0
    noise_sigma: float = 0.5
    hidden_ripple: float = 0.0
    free_noise: bool = False
    n_walkers: int = 40
    max_steps: int = 160
    seed: int = 1


def build_results_folder(directory, settings: FixtureSettings = FixtureSettings()) -> Path:
    """Write a complete results folder (data.npz, chain.h5, fit.json, summary.json, manifest.json).

    Parameters
    ----------
    directory : str or Path
        Created if missing; must not hold a chain already.
    settings : FixtureSettings

    Returns
    -------
    Path
        The folder; the simulated CSV is ``directory / "record.csv"``.
    """
    started = results.now_iso()
    t0 = _time.perf_counter()
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(settings.seed)

    time, current = model.paper_current(fs=settings.sampling_rate)
    clean = model.Model()(model.TABLE1, time, current)
    ripple = np.where(current != 0.0, settings.hidden_ripple * np.sin(2 * np.pi * 0.37 * time), 0.0)
    displacement = clean + ripple + settings.noise_sigma * rng.standard_normal(time.size)
    csv_path = out / "record.csv"
    write_record(csv_path, (time, current, displacement))
    record = load_record(csv_path)

    noise = NoiseModel(sigma=float("nan"), source="free") if settings.free_noise else estimate_noise(record)
    gpi_model = normalised_model(model.Model())
    fit = fit_least_squares(record, gpi_model, noise=noise, start=model.TABLE1, n_starts=1, rng=rng)

    free = np.flatnonzero(fit.vary)
    residuals = WhitenedResiduals(record, fit.model, fit.noise)
    jacobian = residuals.central_jacobian(fit.theta[free])
    identifiability = analyse_identifiability(
        jacobian, fit.theta[free], [fit.model.names[i] for i in free], normalisation=dict(NORMALISATION)
    )

    log_posterior = LogPosterior(record, fit.model, noise if settings.free_noise else fit.noise)
    mean = fit.theta[free]
    covariance = fit.covariance[np.ix_(free, free)]
    if settings.free_noise:
        mean = np.append(mean, np.log(fit.noise.sigma))
        covariance = np.pad(covariance, ((0, 1), (0, 1)))
        covariance[-1, -1] = 0.05**2
    posterior = sample_posterior(
        log_posterior,
        lambda n_walkers, start_rng: initial_walkers(log_posterior, mean, covariance, n_walkers, start_rng),
        out / results.FILES["chain"],
        rng,
        n_walkers=settings.n_walkers,
        max_steps=settings.max_steps,
        check_every=settings.max_steps // 2,
        progress=False,
    )

    results.write_data(out, record)
    results.write_fit(out, fit)
    results.write_summary(out, results.build_summary(record, fit, identifiability, posterior))
    manifest = results.build_manifest(
        seed=settings.seed,
        record=record,
        settings={"fixture": asdict(settings), "effects": [], "n_operators": 12, "reading": "swapped"},
        started=started,
        command=["tests/report_fixture.py"],
    )
    manifest = results.finish_manifest(manifest, started=started, seconds=_time.perf_counter() - t0, status="fixture")
    results.write_json(out / results.FILES["manifest"], manifest)
    return out
