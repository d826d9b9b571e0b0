"""Predict another record with a finished study's model: validation, no refit.

:func:`predict` applies the study's posterior draws and its least-squares vector to a new
record of the same rig (the model runs from the record's first sample, and an optional
window is scored): the bands, the validation RMS and max error beside the training figures
with the same draws, the "where it fails" profile of the validation residual, whether that
residual is the sensor's noise and, when it is not, the diagnosis' verdict on which effect
the record reveals (:data:`VERDICTS`). The result is a :class:`Prediction`, whose
``to_dict`` is ``prediction.json``; :func:`write_prediction` writes its folder at once.
What it shares with compensation (the study, the bands) is in
:mod:`identify.workflows.use_study`.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..data.records import Record
from ..diagnosis import assess_adequacy, diagnose
from ..diagnosis.residuals import ARNoise, fit_ar_noise, residual_profile
from ..fitting.lsq import WhitenedResiduals
from ..fitting.noise import MIN_QUIET_SAMPLES, NoiseModel, energised_mask, estimate_noise, quiet_segment
from ..output import results
from ..output.use_report import prediction_files
from .use_study import (
    MIN_WINDOW_SAMPLES,
    Bands,
    Study,
    UseError,
    bands_of,
    check_units,
    error_figures,
    load_record_for_study,
    load_study,
    prepared_inputs,
    progress_or_silence,
    replace_folder,
)

__all__ = ["VERDICTS", "PREDICTION_FILE", "Prediction", "predict", "write_prediction"]

#: ``verdict`` values of a prediction: ``adequate`` (the validation residual is the sensor's
#: noise), the diagnosis' ``missing_effect``, ``tied`` and ``unexplained``, ``parameters_differ`` (the
#: residual is not noise, but the diagnosis, refitting its baseline on the record, finds the
#: model adequate there: no effect is missing, the study's parameters do not carry over),
#: and ``not_adequate`` (not noise; the candidate search was not run).
VERDICTS = ("adequate", "missing_effect", "tied", "unexplained", "parameters_differ", "not_adequate")
PREDICTION_FILE = "prediction.json"


@dataclass(frozen=True, eq=False)
class Prediction:
    """The study's model applied to another record (see :func:`predict`). Arrays cover the window.

    Attributes
    ----------
    study : Study
    record : Record
        The whole new record.
    window : (float, float)
        Scored time span [s] (the whole record when none was given).
    start, stop : int
        The window's samples ``start <= k < stop`` of ``record``; the model was run from
        sample 0 (the memory at the window's start depends on the history before it).
    time, current, measured : ndarray, shape (n,)
    energised : ndarray of bool, shape (n,)
        Window samples after the record's unenergised start: the ones scored.
    bands : Bands
        Of the window.
    rms, max_error_pct, max_abs_error, time_of_max : float
        Of the posterior-median curve (pointwise median of the draws) over the energised
        window samples; the % is of the measured range there.
    rms_lsq, max_error_pct_lsq : float
        Of the least-squares curve.
    inside_predictive_band : float
        Fraction of the energised window samples inside the 95 % predictive band.
    noise : NoiseModel
        The sensor noise used (from the record's quiet start when it has one, else the study's).
    training : dict
        The study's figures on its own record: ``rms_lsq``, ``max_error_pct_lsq``,
        ``reduced_chi2`` (summary.json), ``rms``, ``max_error_pct``, ``inside_predictive_band``
        (posterior median, recomputed here with the same draws).
    profile : identify.diagnosis.residuals.ResidualProfile
        Where the validation residual (least squares, the diagnosis' convention) fails.
    adequacy : identify.diagnosis.Adequacy
        Is that residual the sensor noise?
    diagnosis : identify.diagnosis.Diagnosis or None
        The candidate search when the residual is not noise (``diagnosis="auto"``).
    verdict : str
        One of :data:`VERDICTS`.
    missing : str or None
        The effect the diagnosis names (``verdict == "missing_effect"``).
    notes : list of str
        What to keep in mind (extrapolation, unconverged study, per-record effects, ...).
    seconds : dict
        Wall time per phase.
    """

    study: Study
    record: Record
    window: tuple
    start: int
    stop: int
    time: np.ndarray
    current: np.ndarray
    measured: np.ndarray
    energised: np.ndarray
    bands: Bands
    rms: float
    max_error_pct: float
    max_abs_error: float
    time_of_max: float
    rms_lsq: float
    max_error_pct_lsq: float
    inside_predictive_band: float
    noise: NoiseModel
    training: dict
    profile: object
    adequacy: object
    diagnosis: object
    verdict: str
    missing: str | None
    notes: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        """Measurement minus the posterior-median curve, shape (n,)."""
        return self.measured - self.bands.median

    @property
    def noise_sigma(self) -> float:
        return float(self.noise.sigma)

    def to_dict(self) -> dict:
        """``prediction.json``: the headline keys first, then the details."""
        study = self.study
        out = {
            "rms": self.rms,
            "max_error_pct": self.max_error_pct,
            "noise_sigma": self.noise_sigma,
            "inside_predictive_band": self.inside_predictive_band,
            "verdict": self.verdict,
            "missing": self.missing,
            "rms_lsq": self.rms_lsq,
            "max_error_pct_lsq": self.max_error_pct_lsq,
            "max_abs_error": self.max_abs_error,
            "time_of_max": self.time_of_max,
            "rms_over_sigma": self.rms / self.noise_sigma,
            "training": self.training,
            "window": {
                "start": self.window[0],
                "stop": self.window[1],
                "first_sample": self.start,
                "n_samples": self.stop - self.start,
                "n_scored": int(self.energised.sum()),
                "model_run_from_sample": 0,
            },
            "noise": self.noise.to_dict(),
            "adequacy": self.adequacy.to_dict(),
            "where": self.profile.to_dict(),
            "diagnosis": None if self.diagnosis is None else self.diagnosis.to_dict(),
            "draws": {"n_draws": self.bands.n_draws, "n_outside": self.bands.n_outside},
            "study": {
                "path": str(study.path),
                "model": study.model.to_dict(),
                "data": study.manifest.get("data", {}),
                "converged": study.converged,
                "units": study.units,
            },
            "record": {
                "file": str(self.record.source),
                "sha256": self.record.sha256,
                "n_samples": len(self.record),
                "notes": list(self.record.notes),
            },
            "notes": list(self.notes),
            "seconds": dict(self.seconds),
        }
        return results.jsonable(out)


def _window_indices(record: Record, window) -> tuple[int, int, tuple]:
    time = record.time
    if window is None:
        return 0, len(time), (float(time[0]), float(time[-1]))
    t0, t1 = (float(x) for x in window)
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1):
        raise UseError(f"--window {t0}:{t1}: needs T0 < T1 (seconds)")
    inside = np.flatnonzero((time >= t0) & (time <= t1))
    if inside.size < MIN_WINDOW_SAMPLES:
        raise UseError(
            f"{record.source}: the window {t0:g}:{t1:g} s holds {inside.size} samples (at least {MIN_WINDOW_SAMPLES} "
            "needed); "
            f"the record spans {time[0]:g} to {time[-1]:g} s"
        )
    return int(inside[0]), int(inside[-1]) + 1, (t0, t1)


def _noise_for(record: Record, study: Study) -> NoiseModel:
    """The new record's own quiet-start noise when it has one, else the study's sigma (as a known sigma)."""
    quiet = quiet_segment(record.current)
    if quiet.stop >= MIN_QUIET_SAMPLES:
        try:
            return estimate_noise(record)
        except ValueError:
            pass
    return NoiseModel(sigma=float(study.noise.sigma), rho=0.0, kind="white", source="user")


def predict(
    study,
    record,
    *,
    window=None,
    n_draws: int = 200,
    rng: np.random.Generator | None = None,
    diagnosis: str = "auto",
    n_starts: int = 6,
    progress=None,
) -> Prediction:
    """Apply a finished study's posterior and least-squares fit to another record (no refit).

    The steps: the common preamble (:func:`identify.workflows.use_study.prepared_inputs`),
    the notes (:func:`_prediction_notes`), the bands on the record (:func:`_validation`),
    the training figures with the same draws (:func:`_training_figures`), the noise test of
    the validation residual (:func:`_residual_check`) and, when it is not noise, the
    diagnosis (:func:`_diagnose_window`).

    Parameters
    ----------
    study : Study or path
        A finished study (:func:`load_study`).
    record : Record or path, or a list of them
        The new record, in the study's units (a path is read with the study's columns); a list
        validates each record on its own and returns a list of :class:`Prediction`.
    window : (float, float), optional
        Score only ``T0 <= t <= T1`` [s]; the model still runs from the record's first
        sample, so the operators' memory at ``T0`` carries the history (fit on the first
        part of a record, predict the rest with ``window=(split, end)``).
    n_draws : int, default 200
        Posterior draws pushed through the model (one vectorised call).
    rng : numpy.random.Generator, optional
        Chooses the draws (and seeds a diagnosis); default ``default_rng(0)``.
    diagnosis : {"auto", "adequacy"}, default "auto"
        The validation residual (of the least-squares vector) is always profiled and tested
        against the noise (:func:`identify.diagnosis.assess_adequacy`: is the misfit
        noise?). ``"auto"`` then, when it is not noise, runs the candidate search
        (:func:`identify.diagnosis.diagnose` on the window, the study's least-squares vector
        as its baseline: which effect does the new record reveal?); ``"adequacy"`` stops at
        the test (verdict ``not_adequate``). The diagnosis runs the model on the window
        alone (from the model's initial state at ``T0``) and may refit its baseline there;
        when that refit makes the model adequate the verdict is ``parameters_differ``.
    n_starts : int, default 6
        Least-squares starts of a diagnosis that must refit its baseline.
    progress : callable(str), optional

    Returns
    -------
    Prediction

    Raises
    ------
    UseError
        Not a finished study, a record in other units, an empty window, a model outside
        its domain on this record.
    """
    if isinstance(record, (list, tuple)):  # several validation records: each on its own
        study = study if isinstance(study, Study) else load_study(study)
        rng = np.random.default_rng(0) if rng is None else rng
        options = dict(window=window, n_draws=n_draws, diagnosis=diagnosis, n_starts=n_starts, progress=progress)
        return [predict(study, one, rng=rng, **options) for one in record]
    say, seconds = progress_or_silence(progress), {}
    clock = _time.perf_counter()

    def check(record, study):
        check_units(record, study)
        if diagnosis not in ("auto", "adequacy"):
            raise ValueError(f"diagnosis must be 'auto' or 'adequacy', got {diagnosis!r}")

    study, record, rng = prepared_inputs(study, record, Record, load_record_for_study, n_draws, rng, check)
    start, stop, window = _window_indices(record, window)
    quiet = quiet_segment(record.current)
    energised_all = np.ones(len(record), dtype=bool)
    energised_all[quiet] = False
    energised = energised_all[start:stop]
    if not energised.any():
        raise UseError(
            f"{record.source}: the window {window[0]:g}:{window[1]:g} s holds no energised sample (the drive is zero)"
        )
    noise = _noise_for(record, study)
    notes = _prediction_notes(study, record, noise, start, stop)
    v = _validation(study, record, noise, start, stop, energised, n_draws, rng, notes, say)
    seconds["bands"] = _time.perf_counter() - clock
    clock = _time.perf_counter()
    training = _training_figures(study, v.draws, v.draw_sigma)
    seconds["training"] = _time.perf_counter() - clock
    clock = _time.perf_counter()
    profile, adequacy = _residual_check(v, noise, quiet, start)
    seconds["profile"] = _time.perf_counter() - clock
    found = None
    if adequacy.adequate:
        verdict, missing = "adequate", None
    elif diagnosis == "adequacy":
        verdict, missing = "not_adequate", None
    else:
        clock = _time.perf_counter()
        found, verdict, missing = _diagnose_window(study, record, v, noise, start, window, n_starts, rng, notes, say)
        seconds["diagnosis"] = _time.perf_counter() - clock
    time, post, lsq = v.time, v.post, v.lsq
    return Prediction(
        study=study,
        record=record,
        window=window,
        start=start,
        stop=stop,
        time=time,
        current=v.current,
        measured=v.measured,
        energised=energised,
        bands=v.bands,
        rms=post["rms"],
        max_error_pct=post["max_error_pct"],
        max_abs_error=post["max_abs_error"],
        time_of_max=float(time[post["worst"]]),
        rms_lsq=lsq["rms"],
        max_error_pct_lsq=lsq["max_error_pct"],
        inside_predictive_band=float(v.inside[energised].mean()),
        noise=noise,
        training=training,
        profile=profile,
        adequacy=adequacy,
        diagnosis=found,
        verdict=verdict,
        missing=missing,
        notes=notes,
        seconds=seconds,
    )


def _prediction_notes(study: Study, record: Record, noise: NoiseModel, start: int, stop: int) -> list[str]:
    """The notes of a prediction known before the model runs: an unconverged study, a drive
    beyond the training range, a window after the start, per-record effects, the study's noise."""
    notes: list[str] = []
    if not study.converged:
        message = str(study.summary["posterior"].get("message") or "").removeprefix("NOT CONVERGED:").strip()
        notes.append(f"the study's posterior is NOT CONVERGED ({message}); the bands are provisional")
    lo_train, hi_train = float(np.min(study.record.current)), float(np.max(study.record.current))
    lo_new, hi_new = float(np.min(record.current[:stop])), float(np.max(record.current[:stop]))
    if lo_new < lo_train - 1e-9 * (hi_train - lo_train) or hi_new > hi_train + 1e-9 * (hi_train - lo_train):
        notes.append(
            f"the record's drive ({lo_new:.4g} to {hi_new:.4g} {record.input_unit}) leaves the training range "
            f"({lo_train:.4g} to {hi_train:.4g}): the model extrapolates there"
        )
    if start > 0:
        notes.append(
            f"the model runs from the record's first sample (t = {record.time[0]:g} s); only the window is scored"
        )
    for name, text in (
        (
            "sensor_drift",
            "sensor_drift is per record (normalised time): the study's drift is applied to this record's span",
        ),
        ("thermal", "thermal starts cold (no heating before the record's first sample)"),
        ("training", "training starts from the virgin state at the record's first sample"),
    ):
        if name in study.model.effect_names:
            notes.append(text)
    if noise.source == "user":
        notes.append(
            f"no quiet start of {MIN_QUIET_SAMPLES}+ samples in this record: the study's noise sigma "
            f"{noise.sigma:.4g} {record.output_unit} is used"
        )
    return notes


@dataclass(frozen=True, eq=False)
class _Validation:
    """The model on the new record: the draws, the bands and errors on the scored window."""

    draws: np.ndarray
    draw_sigma: float | None
    bands: Bands
    time: np.ndarray
    current: np.ndarray
    measured: np.ndarray
    output_range: float
    post: dict
    lsq: dict
    inside: np.ndarray


def _validation(
    study: Study, record: Record, noise: NoiseModel, start: int, stop: int, energised, n_draws, rng, notes, say
) -> _Validation:
    """Posterior draws and the least-squares vector through the model from the record's first
    sample (history included), scored on the window ``start:stop``."""
    draws, draw_sigma = study.draws(n_draws, rng)
    sigma = draw_sigma if draw_sigma is not None else noise.sigma
    say(f"pushing {draws.shape[0]} posterior draws through the model ({stop} samples)")
    full = bands_of(
        study.model, draws, study.fit.theta, record.time[:stop], record.current[:stop], sigma, what=str(record.source)
    )
    cut = slice(start, stop)
    bands = Bands(
        *(
            getattr(full, f)[cut]
            for f in ("median", "credible_lo", "credible_hi", "predictive_lo", "predictive_hi", "lsq")
        ),
        full.n_draws,
        full.n_outside,
    )
    if full.n_outside:
        notes.append(
            f"{full.n_outside} of {draws.shape[0]} draws are outside the model's domain on this record and were dropped"
        )
    time, current, measured = record.time[cut], record.current[cut], record.displacement[cut]
    output_range = float(np.ptp(measured[energised]))
    if not output_range > 0:
        raise UseError(f"{record.source}: the measured output is constant over the scored window")
    post = error_figures(measured, bands.median, energised, output_range)
    lsq = error_figures(measured, bands.lsq, energised, output_range)
    inside = (measured >= bands.predictive_lo) & (measured <= bands.predictive_hi)
    return _Validation(draws, draw_sigma, bands, time, current, measured, output_range, post, lsq, inside)


def _training_figures(study: Study, draws, draw_sigma) -> dict:
    """The training record's figures with the same draws, beside the validation's."""
    train = study.record
    train_energised = energised_mask(train, study.noise)  # as the study and its report count them
    train_bands = bands_of(
        study.model,
        draws,
        study.fit.theta,
        train.time,
        train.current,
        draw_sigma if draw_sigma is not None else study.noise.sigma,
        what="the training record",
    )
    train_range = float(np.ptp(train.displacement[train_energised]))
    train_post = error_figures(train.displacement, train_bands.median, train_energised, train_range)
    train_inside = (train.displacement >= train_bands.predictive_lo) & (train.displacement <= train_bands.predictive_hi)
    fit_summary = study.summary["fit"]
    return {
        "rms_lsq": fit_summary.get("rms"),
        "max_error_pct_lsq": fit_summary.get("max_error_pct"),
        "reduced_chi2": fit_summary.get("reduced_chi2"),
        "rms": train_post["rms"],
        "max_error_pct": train_post["max_error_pct"],
        "inside_predictive_band": float(train_inside[train_energised].mean()),
        "noise_sigma": float(study.noise.sigma),
        "n_samples": len(train),
        "n_scored": int(train_energised.sum()),  # energised samples, counted as the validation's n_scored
        "n_draws": int(np.asarray(draws).shape[0]),
        "file": study.manifest.get("data", {}).get("file"),
    }


def _residual_check(v: _Validation, noise: NoiseModel, quiet: slice, start: int):
    """``(profile, adequacy)`` of the least-squares residual on the window: where it fails,
    and is it noise (as the diagnosis: the quiet start's AR noise, else white noise of sigma)."""
    residual_lsq = v.measured - v.bands.lsq
    quiet_w = None
    if start == 0 and quiet.stop >= 20:
        quiet_w = quiet
        noise_ref = fit_ar_noise(residual_lsq[: quiet.stop])
    else:
        noise_ref = ARNoise(np.zeros(0), float(noise.sigma), float(noise.sigma), 10**9)
    profile = residual_profile(
        v.time,
        v.current,
        residual_lsq,
        quiet_w,
        output_range=float(np.ptp(v.measured)),
        noise=noise_ref,
        level=v.bands.lsq,
    )
    return profile, assess_adequacy(profile)


def _diagnose_window(
    study: Study, record: Record, v: _Validation, noise: NoiseModel, start: int, window, n_starts, rng, notes, say
):
    """``(diagnosis, verdict, missing)``: which effect the window reveals, the study's
    least-squares vector as the baseline; ``parameters_differ`` when a refitted baseline is
    adequate there."""
    time, current, measured = v.time, v.current, v.measured
    window_record = replace(
        record,
        time=time,
        current=current,
        displacement=measured,
        notes=(*record.notes, f"window {window[0]:g}:{window[1]:g} s"),
    )
    diag_noise = (
        noise
        if (noise.quiet is not None and start == 0)
        else NoiseModel(sigma=float(noise.sigma), rho=0.0, kind="white", source="user")
    )
    own = study.model(study.fit.theta, time, current)  # the diagnosis runs the model on the window alone
    baseline = _baseline_fit(study.fit, window_record, own, diag_noise)
    say("the validation residual is not noise: diagnosing which effect the record reveals")
    try:
        found = diagnose(window_record, study.model, fit=baseline, n_starts=n_starts, rng=rng, progress=say)
    except ValueError as exc:
        raise UseError(f"{record.source}: the diagnosis cannot run on this window ({exc})") from None
    verdict, missing = found.status, found.missing
    if verdict == "adequate" and not np.array_equal(found.fit.theta, study.fit.theta):
        verdict = "parameters_differ"
        notes.append(
            f"the diagnosis refitted the model's parameters on this window and found it adequate there (RMS "
            f"{found.rms:.4g} {record.output_unit}): no effect is missing, but the study's parameters do not carry over"
        )
    return found, verdict, missing


def _baseline_fit(fit, record: Record, model_output, noise: NoiseModel):
    """The study's least-squares fit re-expressed on another record (same theta, its residual)."""
    residual = np.asarray(record.displacement) - model_output
    energised = np.ones(len(record), dtype=bool)
    energised[quiet_segment(record.current)] = False
    output_range = float(np.ptp(np.asarray(record.displacement)[energised]))
    whitened = WhitenedResiduals(record, fit.model, noise)
    w = whitened(fit.theta[whitened.free])
    dof = max(len(record) - int(fit.vary.sum()), 1)
    return replace(
        fit,
        residual=residual,
        noise=noise,
        rms=float(np.sqrt(np.mean(residual[energised] ** 2))),
        max_error_pct=float(100.0 * np.abs(residual[energised]).max() / output_range),
        reduced_chi2=float(w @ w) / dof,
        n_starts=0,
        message="the study's least-squares vector (not refitted)",
        seconds=0.0,
    )


def write_prediction(prediction: Prediction, out) -> Path:
    """Write ``OUT/prediction.json``, ``OUT/prediction.html`` and the figures (``OUT/*.png``), all at once."""
    files = prediction_files(prediction)
    return replace_folder(files, out, PREDICTION_FILE)
