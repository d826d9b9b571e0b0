r"""Use an identified model: predict another record (validation), and compensate the hysteresis.

Two workflows on a finished study (a results folder written by ``python -m identify
study``), neither of which refits anything:

:func:`predict`
    The study's posterior draws and its least-squares vector applied to another record of
    the same rig: bands, validation RMS and max error beside the training figures, the
    "where it fails" profile of the validation residual and the diagnosis' verdict on it.
:func:`compensate`
    The inverse of the identified model (:func:`model.inverse.invert`): the drive current
    that makes the model follow a desired displacement trajectory, for the posterior
    median and for posterior draws, and the tracking error the posterior predicts for it.

Both return result objects (:class:`Prediction`, :class:`Compensation`) whose ``to_dict``
is the JSON the commands write; :func:`write_prediction` and :func:`write_compensation`
write a result's whole output folder at once (built in a temporary folder beside it and
renamed into place, so an interrupted or failed run leaves nothing half-written). Every
input problem raises :class:`UseError` with one line naming the file and what is wrong.

Layers: this module uses the model (:mod:`model`, :mod:`model.inverse`), the identification
results (:mod:`identify.output.results`, :mod:`identify.fitting.noise`, :mod:`identify.diagnosis.residuals`,
:mod:`identify.diagnosis.diagnose`) and, for writing, :mod:`identify.output.use_report`; the command-line
shells :mod:`identify.cli.predict` and :mod:`identify.cli.compensate` call it.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time as _time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from model import Model
from model.inverse import DEFAULT_CURRENT_RANGE, STATUS_BRANCH, STATUS_EXACT, STATUS_NAMES, STATUS_SATURATED, invert

from ..data.records import Record, RecordError, load_record
from ..fitting.noise import MIN_QUIET_SAMPLES, NoiseModel, energised_mask, estimate_noise, quiet_segment
from ..output import results
from ..output.report import ModelBands

__all__ = [
    "UseError",
    "Study",
    "Target",
    "Bands",
    "Prediction",
    "Compensation",
    "load_study",
    "load_record_for_study",
    "check_units",
    "default_current_range",
    "reachable_range",
    "load_target",
    "predict",
    "compensate",
    "write_prediction",
    "write_compensation",
    "bands_of",
    "VERDICTS",
    "PREDICTION_FILE",
    "COMPENSATION_FILE",
    "COMPENSATION_CSV",
    "COMPENSATION_BANDS_CSV",
    "REACH_TOLERANCE",
]

#: ``verdict`` values of a prediction: ``adequate`` (the validation residual is the sensor's
#: noise), the diagnosis' ``missing_effect``, ``tied`` and ``unexplained``, ``parameters_differ`` (the
#: residual is not noise, but the diagnosis, refitting its baseline on the record, finds the
#: model adequate there: no effect is missing, the study's parameters do not carry over),
#: and ``not_adequate`` (not noise; the candidate search was not run).
VERDICTS = ("adequate", "missing_effect", "tied", "unexplained", "parameters_differ", "not_adequate")
PREDICTION_FILE = "prediction.json"
COMPENSATION_FILE = "compensation.json"
COMPENSATION_CSV = "compensation.csv"
COMPENSATION_BANDS_CSV = "compensation_bands.csv"
#: A target sample the median model misses at a current limit by more than this fraction of
#: the target's range (at least the inverse's tolerance) is unreachable.
REACH_TOLERANCE = 1e-6
#: Fewest samples in a prediction window.
MIN_WINDOW_SAMPLES = 20


class UseError(ValueError):
    """A study folder, record or target that cannot be used; the message names it and the problem."""


# --------------------------------------------------------------------------------------
# the study
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Study:
    """A finished study, as the workflows need it (read by :func:`load_study`).

    Attributes
    ----------
    path : Path
    record : Record
        The training record (``data.npz``).
    fit : identify.fitting.lsq.FitResult
        The least-squares fit (``fit.json``); ``fit.model`` is the study's model.
    summary, manifest : dict
    samples : ndarray, shape (S, P)
        Every posterior sample after the burn-in (thinned as in ``summary.json``) as a
        full parameter vector (pinned parameters at their least-squares value).
    sample_sigma : ndarray, shape (S,), or None
        Each sample's noise sigma when the study sampled it (``--noise-sigma free``).
    median : ndarray, shape (P,)
        The posterior median parameter vector (``summary.json``'s per-parameter medians).
    """

    path: Path
    record: Record
    fit: object
    summary: dict
    manifest: dict
    samples: np.ndarray
    sample_sigma: np.ndarray | None
    median: np.ndarray

    @property
    def model(self) -> Model:
        return self.fit.model

    @property
    def converged(self) -> bool:
        return bool(self.summary["posterior"].get("converged"))

    @property
    def noise(self) -> NoiseModel:
        return self.fit.noise

    @property
    def units(self) -> dict:
        return {"input": self.record.input_unit, "output": self.record.output_unit}

    def draws(self, n_draws: int, rng: np.random.Generator):
        """``min(n_draws, S)`` samples without replacement: ``(theta (N, P), sigma (N,) or None)``."""
        n = min(int(n_draws), self.samples.shape[0])
        chosen = rng.choice(self.samples.shape[0], size=n, replace=False)
        sigma = None if self.sample_sigma is None else self.sample_sigma[chosen]
        return self.samples[chosen], sigma


def load_study(directory) -> Study:
    """Read a finished study folder; :class:`UseError` when it is not one.

    Finished means: ``data.npz``, ``fit.json``, ``summary.json`` with a posterior block
    (written when sampling ends, converged or at the step cap) and ``chain.h5``. A
    ``fit --out`` folder (no posterior) and a study still sampling or interrupted before
    the end are refused with what to run.
    """
    path = Path(directory)
    if not path.is_dir():
        raise UseError(f"{path}: no such study folder")
    for role in ("data", "fit"):
        if not (path / results.FILES[role]).exists():
            raise UseError(
                f"{path}: {results.FILES[role]} is missing: not a results folder of `python -m identify study`"
            )
    summary_path = path / results.FILES["summary"]
    if not summary_path.exists():
        raise UseError(
            f"{path}: not a finished study: summary.json is missing (a `fit --out` folder has no posterior; "
            f"run `python -m identify study DATA --out {path}`)"
        )
    try:
        study = results.load_results(path)
    except (OSError, KeyError, ValueError) as exc:
        raise UseError(f"{path}: cannot read the study folder ({exc})") from None
    if study.summary.get("posterior") is None:
        raise UseError(
            f"{path}: not a finished study: sampling has not finished (no posterior in summary.json); rerun the same "
            "`study` command to resume it"
        )
    if not study.chain_path.exists():
        raise UseError(f"{study.chain_path}: the posterior chain is missing")
    try:
        flat, names = study.posterior_samples()
    except (OSError, KeyError, ValueError) as exc:
        raise UseError(f"{study.chain_path}: cannot read the posterior chain ({exc})") from None
    if flat.shape[0] == 0:
        raise UseError(f"{study.chain_path}: no posterior samples after the burn-in")
    fit = study.fit
    columns = np.flatnonzero(fit.vary)
    if flat.shape[1] < columns.size:
        raise UseError(
            f"{study.chain_path}: the chain has {flat.shape[1]} coordinates for {columns.size} free parameters"
        )
    samples = np.repeat(fit.theta[None, :], flat.shape[0], axis=0)
    samples[:, columns] = flat[:, : columns.size]
    sample_sigma = np.exp(flat[:, -1]) if names and names[-1] == "noise_log_sigma" else None
    median = fit.theta.copy()
    for i, entry in enumerate(study.summary["parameters"]):
        if entry.get("median") is not None:
            median[i] = float(entry["median"])
    return Study(path, study.record, fit, study.summary, study.manifest, samples, sample_sigma, median)


def load_record_for_study(path, study: Study, **columns) -> Record:
    """Load a record with the study's columns and units unless given (``time_column``, ``input_column``, ...).

    Raises
    ------
    UseError
        The file cannot be read or lacks the columns (the message lists those present),
        or units differ from the study's.
    """
    settings = study.manifest.get("settings", {})
    options = {
        "time_column": settings.get("time_column", "time"),
        "input_column": study.record.input_name,
        "output_column": study.record.output_name,
        "input_unit": study.record.input_unit,
        "output_unit": study.record.output_unit,
    }
    options.update({k: v for k, v in columns.items() if v is not None})
    if str(options["time_column"]).lower() == "none":
        options["time_column"] = None
    try:
        record = load_record(path, min_samples=MIN_WINDOW_SAMPLES, **options)
    except RecordError as exc:
        raise UseError(
            f"{exc} (the study {study.path} was identified on columns "
            f"{study.record.input_name} [{study.record.input_unit}] -> {study.record.output_name} "
            f"[{study.record.output_unit}])"
        ) from None
    check_units(record, study)
    return record


def check_units(record: Record, study: Study) -> None:
    """:class:`UseError` when the record's input or output unit is not the study's."""
    for what, mine, theirs in (
        ("input", record.input_unit, study.record.input_unit),
        ("output", record.output_unit, study.record.output_unit),
    ):
        if mine != theirs:
            raise UseError(
                f"{record.source}: its {what} is in {mine!r} but the study {study.path} was identified with the "
                f"{what} in "
                f"{theirs!r}; convert the record (the model's parameters are in the study's units)"
            )


# --------------------------------------------------------------------------------------
# bands
# --------------------------------------------------------------------------------------
#: Pointwise summaries of model curves (median, credible and predictive bands, the
#: least-squares curve, draws used and dropped): the report's type, one definition.
Bands = ModelBands


def bands_of(
    model: Model, draws, lsq_theta, time, drive, sigma, *, level=0.95, what="the record", curves_out=None
) -> Bands:
    """Push the draws and the least-squares vector through ``model`` in one call and summarise.

    Parameters
    ----------
    draws : ndarray, shape (N, P)
    lsq_theta : ndarray, shape (P,)
    time, drive : ndarray, shape (T,)
    sigma : float or ndarray of shape (N,)
        Noise sd of the predictive band (per draw when the study sampled it).
    curves_out : list, optional
        Gets the draws' curves inside the domain, shape (N_inside, T), appended.
    """
    from ..output.bands import mixture_quantile

    batch = np.vstack([draws, np.asarray(lsq_theta)[None, :]])
    curves, valid = model.evaluate(batch, time, drive)
    if not valid[-1]:
        raise UseError(
            f"the study's least-squares model is outside its domain on {what} (operator bounds cross or a "
            "non-finite output): the drive leaves the range the model was identified on"
        )
    inside = valid[:-1]
    if not inside.any():
        raise UseError(f"every posterior draw is outside the model's domain on {what}")
    model_curves = curves[:-1][inside]
    if curves_out is not None:
        curves_out.append(model_curves)
    tail = 0.5 * (1.0 - level)
    lo, median, hi = np.quantile(model_curves, [tail, 0.5, 1.0 - tail], axis=0)
    sigmas = np.broadcast_to(np.asarray(sigma, dtype=float), (draws.shape[0],))[inside]
    predictive_lo = mixture_quantile(model_curves, sigmas, tail)
    predictive_hi = mixture_quantile(model_curves, sigmas, 1.0 - tail)
    return Bands(median, lo, hi, predictive_lo, predictive_hi, curves[-1], int(inside.sum()), int((~inside).sum()))


def _errors(measured, curve, mask, output_range):
    error = measured - curve
    e = error[mask]
    worst = int(np.flatnonzero(mask)[np.argmax(np.abs(e))])
    return {
        "rms": float(np.sqrt(np.mean(e**2))),
        "max_abs_error": float(np.abs(e).max()),
        "max_error_pct": float(100.0 * np.abs(e).max() / output_range),
        "worst": worst,
    }


# --------------------------------------------------------------------------------------
# predict
# --------------------------------------------------------------------------------------
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

    The steps: the common preamble (:func:`_prepared`), the notes (:func:`_prediction_notes`),
    the bands on the record (:func:`_validation`), the training figures with the same draws
    (:func:`_training_figures`), the noise test of the validation residual
    (:func:`_residual_check`) and, when it is not noise, the diagnosis
    (:func:`_diagnose_window`).

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
    say, seconds = _say(progress), {}
    clock = _time.perf_counter()

    def check(record, study):
        check_units(record, study)
        if diagnosis not in ("auto", "adequacy"):
            raise ValueError(f"diagnosis must be 'auto' or 'adequacy', got {diagnosis!r}")

    study, record, rng = _prepared(study, record, Record, load_record_for_study, n_draws, rng, check)
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


def _say(progress):
    """``progress``, or a function that says nothing."""
    return progress or (lambda message: None)


def _prepared(study, item, item_type, load_item, n_draws, rng, check=None):
    """The preamble :func:`predict` and :func:`compensate` share: ``(study, item, rng)``.

    A path of a study is loaded (:func:`load_study`), a path of the item (the record, the
    target) read with ``load_item(item, study)``; ``check(item, study)`` runs next, then
    ``n_draws`` is checked and the generator defaults to ``default_rng(0)``.
    """
    if not isinstance(study, Study):
        study = load_study(study)
    if not isinstance(item, item_type):
        item = load_item(item, study)
    if check is not None:
        check(item, study)
    if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 2:
        raise ValueError(f"n_draws must be an integer >= 2, got {n_draws!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    return study, item, rng


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
    post = _errors(measured, bands.median, energised, output_range)
    lsq = _errors(measured, bands.lsq, energised, output_range)
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
    train_post = _errors(train.displacement, train_bands.median, train_energised, train_range)
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
    from ..diagnosis import assess_adequacy
    from ..diagnosis.residuals import ARNoise, fit_ar_noise, residual_profile

    residual_lsq = v.measured - v.bands.lsq
    quiet_w = None
    if start == 0 and quiet.stop >= 20:
        quiet_w = quiet
        noise_ref = fit_ar_noise(residual_lsq[: quiet.stop])
    else:
        noise_ref = ARNoise(np.zeros(0), float(noise.sigma), float(noise.sigma), 10**9)
    profile = residual_profile(
        v.time, v.current, residual_lsq, quiet_w, output_range=float(np.ptp(v.measured)), noise=noise_ref
    )
    return profile, assess_adequacy(profile)


def _diagnose_window(
    study: Study, record: Record, v: _Validation, noise: NoiseModel, start: int, window, n_starts, rng, notes, say
):
    """``(diagnosis, verdict, missing)``: which effect the window reveals, the study's
    least-squares vector as the baseline; ``parameters_differ`` when a refitted baseline is
    adequate there."""
    from ..diagnosis import diagnose

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
    from ..fitting.lsq import WhitenedResiduals

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


# --------------------------------------------------------------------------------------
# compensate
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Target:
    """A desired output trajectory: ``time`` [s] and ``displacement`` [output unit], shape (T,)."""

    time: np.ndarray
    displacement: np.ndarray
    source: str = "target"

    def __post_init__(self):
        t = np.array(self.time, dtype=float)
        y = np.array(self.displacement, dtype=float)
        if t.ndim != 1 or t.shape != y.shape or t.size < 2:
            raise UseError(f"{self.source}: time and displacement must be 1-D of equal length >= 2")
        if not (np.isfinite(t).all() and np.isfinite(y).all()):
            raise UseError(f"{self.source}: time and displacement must be finite")
        if not (np.diff(t) > 0).all():
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise UseError(f"{self.source}: time must strictly increase (sample {k + 1}: {t[k + 1]!r} after {t[k]!r})")
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "displacement", y)


def load_target(path, *, time_column: str = "time", output_column: str = "displacement") -> Target:
    """Read a target CSV (header ``time,displacement`` by default; other columns ignored).

    Raises
    ------
    UseError
        Unreadable file, missing columns (those present are listed), a non-numeric or
        non-finite cell (with its line), fewer than 2 rows, times not strictly increasing.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise UseError(f"{path}: no such target file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UseError(f"{path}: cannot read the target file ({exc})") from None
    lines = [
        (n, line)
        for n, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise UseError(f"{path}: empty; expected a header '{time_column},{output_column}' and one row per sample")
    header_line, header_text = lines[0]
    header = [h.strip() for h in header_text.split(",")]
    missing = [c for c in (time_column, output_column) if c not in header]
    if missing:
        raise UseError(
            f"{path}, line {header_line}: missing column(s) {', '.join(map(repr, missing))}; columns present: "
            f"{', '.join(map(repr, header))} (a target is CSV '{time_column},{output_column}', in s and the study's "
            "output unit)"
        )
    jt, jy = header.index(time_column), header.index(output_column)
    t, y = [], []
    for number, line in lines[1:]:
        cells = line.split(",")
        if len(cells) != len(header):
            raise UseError(f"{path}, line {number}: {len(cells)} cells, but the header has {len(header)} columns")
        try:
            tv, yv = float(cells[jt]), float(cells[jy])
        except ValueError:
            raise UseError(f"{path}, line {number}: not a number ({line.strip()[:60]!r})") from None
        if not (math.isfinite(tv) and math.isfinite(yv)):
            raise UseError(f"{path}, line {number}: not a finite number ({line.strip()[:60]!r})")
        t.append(tv)
        y.append(yv)
    if len(t) < 2:
        raise UseError(f"{path}: {len(t)} data row(s); a target needs at least 2")
    return Target(np.array(t), np.array(y), source=str(path))


@dataclass(frozen=True, eq=False)
class Compensation:
    """The feedforward current for a target and what the posterior predicts of it (see :func:`compensate`).

    Attributes
    ----------
    study : Study
    target : Target
    current : ndarray, shape (T,)
        The feedforward drive of the posterior-median model [input unit].
    status : ndarray of int8, shape (T,)
        :data:`model.inverse.STATUS_NAMES` per sample, for the median model.
    model_output : ndarray, shape (T,)
        The median model's output on ``current`` (the target where status is exact).
    current_lo, current_hi, current_median : ndarray, shape (T,)
        95 % band and median of the drives computed for each posterior draw (each draw's
        own exact inverse): how well the identification pins the feedforward down.
    error_median, error_lo, error_hi : ndarray, shape (T,)
        Predicted tracking error of ``current``, model minus target, over the posterior
        draws driven by it: pointwise median and 95 % credible band [output unit].
    predictive_lo, predictive_hi : ndarray, shape (T,)
        95 % band of the *measured* tracking error (the draws plus sensor noise).
    lsq_error : ndarray, shape (T,)
        Tracking error the least-squares vector predicts for ``current``.
    summary : dict
        The figures of ``compensation.json`` (tracking error RMS and max with their 95 %
        intervals over the draws, in output units and % of the target's range, inverse
        statistics, counts).
    current_range : (float, float)
    notes : list of str
    seconds : dict
    """

    study: Study
    target: Target
    current: np.ndarray
    status: np.ndarray
    model_output: np.ndarray
    current_lo: np.ndarray
    current_hi: np.ndarray
    current_median: np.ndarray
    error_median: np.ndarray
    error_lo: np.ndarray
    error_hi: np.ndarray
    predictive_lo: np.ndarray
    predictive_hi: np.ndarray
    lsq_error: np.ndarray
    summary: dict
    current_range: tuple
    notes: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        study = self.study
        out = dict(self.summary)
        out.update(
            {
                "current_range": list(self.current_range),
                "study": {
                    "path": str(study.path),
                    "model": study.model.to_dict(),
                    "converged": study.converged,
                    "units": study.units,
                    "data": study.manifest.get("data", {}),
                },
                "target": {
                    "file": self.target.source,
                    "n_samples": int(self.target.time.size),
                    "min": float(self.target.displacement.min()),
                    "max": float(self.target.displacement.max()),
                },
                "notes": list(self.notes),
                "seconds": dict(self.seconds),
            }
        )
        return results.jsonable(out)


def _interval(values) -> dict:
    lo, med, hi = np.quantile(np.asarray(values, dtype=float), [0.025, 0.5, 0.975])
    return {"median": float(med), "lo95": float(lo), "hi95": float(hi)}


def _compensation_theta(model: Model, theta):
    """Parameter vectors with ``sensor_drift`` switched off (a sensor property, not the transducer's)."""
    theta = np.array(theta, dtype=float, copy=True)
    if "sensor_drift" in model.effect_names:
        theta[..., model.effect_slice("sensor_drift")] = 0.0
    return theta


def reachable_range(model: Model, theta, time, current_range) -> tuple[float, float]:
    """Lowest and highest output of ``model`` over a sweep of the current ``lo -> hi -> lo`` on ``time``.

    The static reach of the drive limits: with increasing envelopes and Omega the output at
    the upper limit after a rise is the highest the model gives (the rise wipes the memory)
    and the lowest lies at the lower limit (the rest, or the end of the fall). The sweep
    runs on the target's own time base, so time-dependent effects (heating) act as over
    the target. A target beyond this range is unreachable; a target inside it that still
    saturates a limit somewhere (a lag that cannot cross a dead zone at once, a transducer
    that has heated) is reported, not refused.
    """
    lo, hi = current_range
    n = len(time)
    peak = n // 2
    sweep = np.concatenate([np.linspace(lo, hi, peak + 1), np.linspace(hi, lo, n - peak)[1:]])
    y, valid = model.evaluate(theta, time, sweep)
    if not valid[0]:
        raise UseError(
            f"the posterior-median model is outside its domain (operator bounds cross, or a non-finite output) for a "
            f"current between {lo:g} and {hi:g}: it is not defined that far beyond what it was identified on; narrow "
            "--current-range"
        )
    return float(y[0].min()), float(y[0].max())


def default_current_range(study: Study) -> tuple[float, float]:
    """The rig's 0-5 A for a study in A (:data:`model.inverse.DEFAULT_CURRENT_RANGE`), else the training drive's
    range."""
    if study.record.input_unit == "A":
        return DEFAULT_CURRENT_RANGE
    return float(np.min(study.record.current)), float(np.max(study.record.current))


def compensate(
    study,
    target,
    *,
    current_range=None,
    n_draws: int = 200,
    rng: np.random.Generator | None = None,
    progress=None,
) -> Compensation:
    """The drive current that makes the identified model follow ``target`` (the inverse; no refit).

    The steps: the common preamble (:func:`_prepared`), the notes
    (:func:`_compensation_notes`), the median's inverse (:func:`_invert_median`), the draws'
    inverses and tracking (:func:`_tracking`) and the summary (:func:`_compensation_summary`).

    Method (details in :mod:`model.inverse`): the posterior-median parameter vector is
    inverted exactly, sample by sample, within ``current_range``; that current is the
    feedforward (``compensation.csv``). Each of ``n_draws`` posterior draws is inverted too
    (one parallel call), giving the band of the feedforward current; and the draws are
    driven with the median's current, giving the predicted tracking error and its 95 %
    band (credible: the transducer's true displacement; predictive: as a sensor with the
    study's noise would measure it). ``sensor_drift`` is left out (it moves the sensor's
    reading, not the transducer); ``thermal`` starts cold and ``training`` virgin at the
    target's first sample, as in the identified model.

    Parameters
    ----------
    study : Study or path
    target : Target or path
        Desired displacement [output unit] at increasing times [s].
    current_range : (float, float), optional
        Limits of the drive; default the rig's 0-5 A (:func:`default_current_range`).
    n_draws : int, default 200
    rng : numpy.random.Generator, optional
        Chooses the draws; default ``default_rng(0)``.
    progress : callable(str), optional

    Returns
    -------
    Compensation

    Raises
    ------
    UseError
        Not a finished study; a target beyond the displacement the median model reaches
        within the current limits (:func:`reachable_range`; the message gives the range,
        the first such sample, what it asks and how many samples); an effect the inverse
        does not know.
    """
    say, seconds = _say(progress), {}
    study, target, rng = _prepared(
        study,
        target,
        Target,
        lambda path, study: load_target(path, output_column=study.record.output_name),
        n_draws,
        rng,
    )
    lo, hi = default_current_range(study) if current_range is None else (float(x) for x in current_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise UseError(f"--current-range {lo}:{hi}: needs LO < HI")
    y_target = target.displacement
    notes = _compensation_notes(study)
    med = _invert_median(study, target, (lo, hi), seconds)
    t = _tracking(study, target, med, (lo, hi), n_draws, rng, seconds, say)
    summary = _compensation_summary(study, target, med, t)
    counts = summary["model_tracking"]["samples"]
    if counts["branch"] or counts["saturated"]:
        notes.append(
            f"the median model misses the target at {counts['branch'] + counts['saturated']} samples (Omega switch "
            "gaps "
            f"{counts['branch']}, current limit {counts['saturated']}; max {np.abs(med.error).max():.3g} "
            f"{study.record.output_unit})"
        )
    current_lo, current_median, current_hi = np.quantile(t.each.current, [0.025, 0.5, 0.975], axis=0)
    bands = t.bands
    return Compensation(
        study=study,
        target=target,
        current=med.current,
        status=med.status,
        model_output=med.output,
        current_lo=current_lo,
        current_hi=current_hi,
        current_median=current_median,
        error_median=t.error_median,
        error_lo=bands.credible_lo - y_target,
        error_hi=bands.credible_hi - y_target,
        predictive_lo=bands.predictive_lo - y_target,
        predictive_hi=bands.predictive_hi - y_target,
        lsq_error=bands.lsq - y_target,
        summary=summary,
        current_range=(lo, hi),
        notes=notes,
        seconds=seconds,
    )


def _compensation_notes(study: Study) -> list[str]:
    """The notes of a compensation known before the inverse runs: an unconverged study, and
    how each of the model's effects enters the inverse."""
    model = study.model
    notes: list[str] = []
    if not study.converged:
        notes.append("the study's posterior is NOT CONVERGED: the bands are provisional")
    if "sensor_drift" in model.effect_names:
        notes.append("sensor_drift is left out: it is the sensor's reading, not the transducer's displacement")
    if "thermal" in model.effect_names:
        notes.append("thermal starts cold at the target's first sample (as in the identified model)")
    if "training" in model.effect_names:
        notes.append("training: the compensation assumes the virgin first cycle the model identified")
    if "lag" in model.effect_names:
        notes.append(
            "lag: the current leads the drive; at an Omega switch the drive must cross a dead zone at once, "
            "which a lag cannot: the current saturates for a few samples there (flagged)"
        )
    return notes


def _invert_median(study: Study, target: Target, limits: tuple[float, float], seconds: dict):
    """The posterior median's exact inverse within ``limits``; a target beyond what the model
    reaches there (:func:`reachable_range`) is refused with the first such sample."""
    model = study.model
    lo, hi = limits
    unit, in_unit = study.record.output_unit, study.record.input_unit
    time, y_target = target.time, target.displacement
    span = float(np.ptp(y_target))
    median_theta = _compensation_theta(model, study.median)
    clock = _time.perf_counter()
    try:
        med = invert(model, median_theta, time, y_target, current_range=(lo, hi))
    except ValueError as exc:
        raise UseError(f"{study.path}: {exc}") from None
    seconds["inverse_median"] = _time.perf_counter() - clock
    tolerance = max(REACH_TOLERANCE * max(span, 1.0), med.ytol)
    y_low, y_high = reachable_range(model, median_theta, time, (lo, hi))
    beyond = ((med.current >= hi) & (y_target > y_high + tolerance)) | (
        (med.current <= lo) & (y_target < y_low - tolerance)
    )
    unreachable = (med.status == STATUS_SATURATED) & beyond
    if unreachable.any():
        k = int(np.flatnonzero(unreachable)[0])
        side = "above the highest" if y_target[k] > y_high else "below the lowest"
        raise UseError(
            f"{target.source}: the target leaves the displacement the model reaches with the current in {lo:g}..{hi:g} "
            f"{in_unit} ({y_low:.6g} to {y_high:.6g} {unit} over a sweep between the limits): at t = {time[k]:.6g} s "
            "it "
            f"asks for {y_target[k]:.6g} {unit}, {side}; the model gives {med.output[k]:.6g} {unit} there at the "
            f"{'upper' if med.current[k] >= hi else 'lower'} limit ({int(unreachable.sum())} such samples; the target "
            "spans "
            f"{y_target.min():.6g} to {y_target.max():.6g} {unit}). Shrink the target or widen --current-range"
        )
    return med


@dataclass(frozen=True, eq=False)
class _Tracking:
    """The posterior draws on the compensation: their own inverses and the median's current through them."""

    n_draws: int
    each: object
    bands: Bands
    errors: np.ndarray
    error_median: np.ndarray


def _tracking(study: Study, target: Target, med, limits, n_draws, rng, seconds: dict, say) -> _Tracking:
    """Posterior draws: their own inverses (the band of the feedforward) and the median's
    current through them (the predicted tracking error)."""
    model = study.model
    time, y_target = target.time, target.displacement
    draws, draw_sigma = study.draws(n_draws, rng)
    draws = _compensation_theta(model, draws)
    say(f"inverting {draws.shape[0]} posterior draws ({time.size} samples)")
    clock = _time.perf_counter()
    each = invert(model, draws, time, y_target, current_range=limits)
    seconds["inverse_draws"] = _time.perf_counter() - clock
    clock = _time.perf_counter()
    sigma = draw_sigma if draw_sigma is not None else study.noise.sigma
    kept: list = []
    bands = bands_of(
        model,
        draws,
        _compensation_theta(model, study.fit.theta),
        time,
        med.current,
        sigma,
        what=f"the compensation current of {target.source}",
        curves_out=kept,
    )
    errors = kept[0] - y_target[None, :]
    seconds["tracking"] = _time.perf_counter() - clock
    return _Tracking(int(draws.shape[0]), each, bands, errors, bands.median - y_target)


def _compensation_summary(study: Study, target: Target, med, t: _Tracking) -> dict:
    """``compensation.json``'s summary: tracking error over the draws, the median model's own
    tracking, the current and its band, the inverse's statistics."""
    time, y_target = target.time, target.displacement
    span = float(np.ptp(y_target))
    errors, each, bands = t.errors, t.each, t.bands
    rms_d = np.sqrt(np.mean(errors**2, axis=1))
    max_d = np.abs(errors).max(axis=1)
    self_error = med.error
    counts = {STATUS_NAMES[s]: int((med.status == s).sum()) for s in (STATUS_EXACT, STATUS_SATURATED, STATUS_BRANCH)}
    draw_counts = {
        STATUS_NAMES[s]: int((each.status == s).sum()) for s in (STATUS_EXACT, STATUS_SATURATED, STATUS_BRANCH)
    }
    pct = 100.0 / span if span > 0 else math.nan
    lsq_error = bands.lsq - y_target
    return {
        "tracking_error": {
            "what": "posterior draws driven by the median's feedforward current, model minus target; RMS and max "
            "|error| "
            "per draw, their median and 95 % interval",
            "rms": _interval(rms_d),
            "max_abs": _interval(max_d),
            "rms_pct": _interval(rms_d * pct),
            "max_abs_pct": _interval(max_d * pct),
            "pointwise_median_rms": float(np.sqrt(np.mean(t.error_median**2))),
            "lsq_rms": float(np.sqrt(np.mean(lsq_error**2))),
            "lsq_max_abs": float(np.abs(lsq_error).max()),
        },
        "model_tracking": {
            "what": "the posterior-median model on its own inverse's current (0 up to rounding where exact)",
            "rms": float(np.sqrt(np.mean(self_error**2))),
            "max_abs": float(np.abs(self_error).max()),
            "samples": counts,
        },
        "current": {
            "min": float(med.current.min()),
            "max": float(med.current.max()),
            "draws_band_half_width_median": float(
                np.median(0.5 * (np.quantile(each.current, 0.975, axis=0) - np.quantile(each.current, 0.025, axis=0)))
            ),
            "draw_samples": draw_counts,
        },
        "target_range": span,
        "noise_sigma": float(study.noise.sigma),
        "n_draws": t.n_draws,
        "n_outside": int(bands.n_outside),
        "unit": study.record.output_unit,
        "input_unit": study.record.input_unit,
        "inverse": {"ytol": med.ytol, "evaluations_per_sample": float(med.evaluations[0]) / time.size},
    }


# --------------------------------------------------------------------------------------
# writing (whole folders, atomically)
# --------------------------------------------------------------------------------------
def _replace_folder(files: dict, out, marker: str) -> Path:
    """Write ``{name: bytes}`` into a new folder and rename it to ``out``.

    An existing ``out`` is replaced only when it is empty or holds ``marker`` (an earlier
    run of the same command); anything else is refused, so no other folder is touched.
    """
    out = Path(out)
    if out.exists():
        if not out.is_dir():
            raise UseError(f"{out}: exists and is not a folder; choose another --out")
        if any(out.iterdir()) and not (out / marker).exists():
            raise UseError(f"{out}: exists and holds other files (no {marker}); choose another --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        for name, data in files.items():
            target = staging / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        staging.chmod(0o777 & ~_umask())
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            old.rmdir()
            out.rename(old)
        staging.rename(out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out


def _umask() -> int:
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_prediction(prediction: Prediction, out) -> Path:
    """Write ``OUT/prediction.json``, ``OUT/prediction.html`` and the figures (``OUT/*.png``), all at once."""
    from ..output.use_report import prediction_files

    files = prediction_files(prediction)
    return _replace_folder(files, out, PREDICTION_FILE)


def write_compensation(compensation: Compensation, out) -> Path:
    """Write ``OUT/compensation.csv`` (``time,current``), ``compensation.json``, the bands CSV, the page and figures."""
    from ..output.use_report import compensation_files

    files = compensation_files(compensation)
    return _replace_folder(files, out, COMPENSATION_FILE)
