"""A finished study as :func:`identify.workflows.use.predict` and
:func:`identify.workflows.use.compensate` use it, and what the two share.

:func:`load_study` reads a study folder into a :class:`Study` (the training record, the
least-squares fit, every posterior sample as a full parameter vector, the posterior
median); :func:`load_record_for_study` reads another record with the study's columns and
units (:func:`check_units`). :func:`bands_of` pushes posterior draws and the least-squares
vector through the model in one call into :data:`Bands`; :func:`error_figures` scores a
curve against a measurement. :func:`prepared_inputs` is the preamble of both workflows (load
what is a path, check the draws), and :func:`replace_folder` writes a result's whole output
folder at once. Every input problem raises :class:`UseError`.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model import Model

from ..data.fileio import move_folder_into_place
from ..data.records import Record, RecordError, load_record
from ..fitting.noise import NoiseModel
from ..output import results
from ..output.bands import mixture_quantile
from ..output.report import ModelBands

__all__ = [
    "UseError",
    "MIN_WINDOW_SAMPLES",
    "Study",
    "load_study",
    "load_record_for_study",
    "check_units",
    "Bands",
    "bands_of",
    "error_figures",
    "progress_or_silence",
    "prepared_inputs",
    "replace_folder",
]

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


def error_figures(measured, curve, mask, output_range) -> dict:
    """How far ``curve`` is from ``measured`` over the samples of ``mask``.

    Parameters
    ----------
    measured, curve : ndarray, shape (T,)
    mask : ndarray of bool, shape (T,)
        The samples scored (at least one).
    output_range : float
        The measured range the % is of (> 0).

    Returns
    -------
    dict
        ``rms``, ``max_abs_error`` and ``max_error_pct`` of ``measured - curve`` over
        ``mask``, and ``worst``: the index (into the whole arrays) of the largest error.
    """
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
# the preamble both workflows share
# --------------------------------------------------------------------------------------
def progress_or_silence(progress):
    """``progress``, or a function that says nothing.

    Parameters
    ----------
    progress : callable(str) or None

    Returns
    -------
    callable(str)
    """
    return progress or (lambda message: None)


def prepared_inputs(study, item, item_type, load_item, n_draws, rng, check=None):
    """The preamble :func:`identify.workflows.use.predict` and :func:`identify.workflows.use.compensate`
    share: ``(study, item, rng)``.

    A path of a study is loaded (:func:`load_study`), a path of the item (the record, the
    target) read with ``load_item(item, study)``; ``check(item, study)`` runs next, then
    ``n_draws`` is checked and the generator defaults to ``default_rng(0)``.

    Parameters
    ----------
    study : Study or path
    item : item_type or path
        The record or the target.
    item_type : type
        What ``item`` is when it is not a path.
    load_item : callable(path, Study) -> item_type
    n_draws : int
        Posterior draws the workflow will use (an integer >= 2).
    rng : numpy.random.Generator or None
    check : callable(item, Study), optional
        Raises when the item does not suit the study.

    Returns
    -------
    tuple
        ``(Study, item, numpy.random.Generator)``.

    Raises
    ------
    UseError
        From loading; ValueError for ``n_draws``.
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


# --------------------------------------------------------------------------------------
# writing (whole folders, atomically)
# --------------------------------------------------------------------------------------
def replace_folder(files: dict, out, marker: str) -> Path:
    """Write ``{name: bytes}`` into a new folder and rename it to ``out``.

    An existing ``out`` is replaced only when it is empty or holds ``marker`` (an earlier
    run of the same command); anything else is refused, so no other folder is touched.

    Parameters
    ----------
    files : dict
        ``{relative path: bytes}``.
    out : path-like
    marker : str
        The file that makes an existing ``out`` an earlier result of the same command.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    UseError
        ``out`` is a file, or a folder holding other files.
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
        move_folder_into_place(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out
