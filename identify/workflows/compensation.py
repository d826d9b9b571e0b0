"""Compensate the hysteresis with a finished study's model: the inverse, no refit.

:func:`compensate` inverts the identified model (:func:`model.inverse.invert`): the drive
current that makes the posterior-median model follow a desired displacement
(:class:`Target`, read by :func:`load_target`), the same for posterior draws (the band of
that feedforward current), and the tracking error the posterior predicts for it. A target
beyond what the model reaches within the current limits (:func:`reachable_range`,
:func:`default_current_range`) is refused. ``sensor_drift`` is left out of every parameter
vector inverted (:func:`without_sensor_drift`). The result is a :class:`Compensation`, whose
``to_dict`` is ``compensation.json``; :func:`write_compensation` writes its folder at once.
What it shares with prediction (the study, the bands) is in :mod:`identify.workflows.use_study`.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from model import Model
from model.inverse import DEFAULT_CURRENT_RANGE, STATUS_BRANCH, STATUS_EXACT, STATUS_NAMES, STATUS_SATURATED, invert

from ..output import results
from ..output.use_report import compensation_files
from .use_study import Bands, Study, UseError, bands_of, prepared_inputs, progress_or_silence, replace_folder

__all__ = [
    "COMPENSATION_FILE",
    "COMPENSATION_CSV",
    "COMPENSATION_BANDS_CSV",
    "REACH_TOLERANCE",
    "Target",
    "load_target",
    "Compensation",
    "without_sensor_drift",
    "reachable_range",
    "default_current_range",
    "compensate",
    "write_compensation",
]

COMPENSATION_FILE = "compensation.json"
COMPENSATION_CSV = "compensation.csv"
COMPENSATION_BANDS_CSV = "compensation_bands.csv"
#: A target sample the median model misses at a current limit by more than this fraction of
#: the target's range (at least the inverse's tolerance) is unreachable.
REACH_TOLERANCE = 1e-6


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


def without_sensor_drift(model: Model, theta):
    """Parameter vectors with ``sensor_drift`` switched off (a sensor property, not the transducer's).

    The inverse drives the transducer; the drift moves only the sensor's reading of it, so
    every vector the compensation inverts or drives has it at zero.

    Parameters
    ----------
    model : model.Model
    theta : array_like, shape (P,) or (N, P)
        Parameter vectors of ``model``.

    Returns
    -------
    ndarray
        A copy of ``theta`` with the ``sensor_drift`` parameters 0 (unchanged when the model
        has no ``sensor_drift``).
    """
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

    The steps: the common preamble (:func:`identify.workflows.use_study.prepared_inputs`), the notes
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
    say, seconds = progress_or_silence(progress), {}
    study, target, rng = prepared_inputs(
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
    median_theta = without_sensor_drift(model, study.median)
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
    draws = without_sensor_drift(model, draws)
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
        without_sensor_drift(model, study.fit.theta),
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


def write_compensation(compensation: Compensation, out) -> Path:
    """Write ``OUT/compensation.csv`` (``time,current``), ``compensation.json``, the bands CSV, the page and figures."""
    files = compensation_files(compensation)
    return replace_folder(files, out, COMPENSATION_FILE)
