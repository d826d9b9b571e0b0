"""The uncertainty report of a finished study: one self-contained HTML page plus PNGs.

:func:`write_report` reads a results folder written by ``study`` (layout in
docs/CONTRACTS.md: ``data.npz``, ``chain.h5``, ``fit.json``, ``summary.json``,
``manifest.json``) and writes ``DIR/report.html`` (figures embedded as base64 PNG,
tables as HTML, no external files, opens in any browser without a server) and every
figure as ``DIR/<name>.png``. It never refits: model curves come from posterior draws
pushed through the forward model in one vectorised :meth:`model.Model.evaluate` call.

What the page shows
-------------------
* **At a glance**: whether the residual is at the noise level, the max error as % of
  the displacement range and where it is worst, whether the chain converged, and the
  least well determined parameters.
* **Measurement vs model** (the paper's Figs. 5-8): input vs time; displacement vs
  time with the 95 % credible band of the model and the 95 % predictive band (model
  plus noise; the AR(1) noise's marginal sd is sigma, so the predictive band is the
  pointwise 2.5/97.5 % quantile of the mixture of N(model draw, sigma^2)), with a zoom
  on the worst region; model error vs time with the ±2 sigma noise band; hysteresis
  loops with the credible band drawn along each branch (the record is split at the
  input reversals; each branch's band is a polygon over its own current samples).
* **Fit quality**: residual RMS vs sigma, reduced chi-square, max error %, per-cycle
  errors (cycles split at the input's minima) and a highlighted warning when the
  residual is far above the noise (RMS > :data:`RMS_RATIO_LIMIT` sigma or reduced
  chi-square > :data:`REDUCED_CHI2_LIMIT`).
* **Parameters**: Table 1, least squares with standard error, posterior median and
  95 % interval, tau, ESS, pinned marker; corner plot, walker traces, autocorrelation
  time vs chain length; identifiability findings.
* **Diagnosis** (hook): when ``DIR/diagnosis.json`` exists (keys ``status``,
  ``missing``, ``ranking`` = list of ``{effect, rms_after, ...}``) its verdict and
  ranking table are shown, with every ``DIR/diagnosis/*.png`` embedded.
* **Provenance**: ``manifest.json`` (data file and sha256, seed, settings, versions,
  commit, times) and the convergence status stated plainly.

Numbers shown in tables carry ``data-key`` attributes (e.g. ``fit.rms``,
``parameters.alpha.median``) and are printed with 6 significant digits, so a test can
parse them back and compare with ``summary.json``.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import tempfile
import time as _time
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np
from scipy.special import ndtr, ndtri

import model

from . import plots

__all__ = [
    "write_report",
    "load_results",
    "read_chain",
    "posterior_draws",
    "model_bands",
    "input_reversals",
    "branches",
    "cycle_errors",
    "autocorrelation_curve",
    "zoom_samples",
    "loop_zoom_box",
    "StudyResults",
    "ChainSample",
    "ModelBands",
    "Branch",
    "CycleError",
    "ResultsError",
    "FIGURES",
    "RMS_RATIO_LIMIT",
    "REDUCED_CHI2_LIMIT",
    "DIAGNOSIS_FILE",
    "DIAGNOSIS_FIGURES",
]

#: Residual RMS above this multiple of the noise sigma is "far above the noise".
RMS_RATIO_LIMIT = 1.2
#: Reduced chi-square above this is "far above the noise".
REDUCED_CHI2_LIMIT = 1.5
#: Written by the diagnosis (issue 6) into the results folder; optional.
DIAGNOSIS_FILE = "diagnosis.json"
#: Folder (inside the results folder) whose ``*.png`` the diagnosis section embeds.
DIAGNOSIS_FIGURES = "diagnosis"
#: At most this many stored chain rows are read (the chain is thinned to fit).
MAX_CHAIN_ROWS = 4000
#: At most this many steps per walker are drawn in the trace plots.
MAX_TRACE_ROWS = 800
#: At most this many samples go into the corner plot.
MAX_CORNER_SAMPLES = 6000
#: An input reversal counts once the input has moved back by this fraction of its range.
REVERSAL_TOLERANCE = 0.01
#: The zoom window is wide enough for the output to move this many predictive half-widths.
ZOOM_BAND_MULTIPLE = 15.0
#: Significant digits of the numbers in the tables.
DIGITS = 6

#: figure file stem -> alt text (also the figure's caption heading), in page order.
FIGURES = {
    "fig5_input": "Input vs time (paper Fig. 5)",
    "fig6_displacement": "Displacement vs time: measurement, posterior median model, 95% credible and predictive bands (paper Fig. 6)",
    "fig6_zoom": "Displacement vs time, zoom on the worst region",
    "fig7_error": "Model error vs time with the 2-sigma noise band (paper Fig. 7)",
    "fig8_loops": "Hysteresis loops: displacement vs current with the 95% credible band along each branch (paper Fig. 8)",
    "corner": "Corner plot of the posterior of the varying parameters",
    "traces": "Walker traces with the burn-in marked",
    "autocorrelation": "Integrated autocorrelation time vs chain length with the N/50 line",
}


class ResultsError(ValueError):
    """A results folder that cannot be reported on; the message names the file and the problem."""


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StudyResults:
    """The contents of a results folder, as the report needs them.

    Attributes
    ----------
    directory : Path
    time, current, displacement : ndarray, shape (T,)
        The record exactly as fitted: s, ``input_unit``, ``output_unit``.
    input_name, input_unit, output_name, output_unit : str
    fit, summary, manifest : dict
        ``fit.json``, ``summary.json``, ``manifest.json``.
    diagnosis : dict or None
        ``diagnosis.json`` when present.
    model : model.Model
        Rebuilt from ``summary["model"]``.
    theta_lsq : ndarray, shape (P,)
        Least-squares vector (``fit.json``), :attr:`model.Model.names` order; pinned
        parameters hold their normalisation value.
    vary : ndarray of bool, shape (P,)
        False for parameters pinned by the normalisation.
    noise_sigma : float
        Sensor noise sd, ``output_unit``.
    energised : ndarray of bool, shape (T,)
        Samples after the quiet segment (the first ``summary["noise"]["n_quiet"]``).
    """

    directory: Path
    time: np.ndarray
    current: np.ndarray
    displacement: np.ndarray
    input_name: str
    input_unit: str
    output_name: str
    output_unit: str
    fit: dict
    summary: dict
    manifest: dict
    diagnosis: dict | None
    model: model.Model
    theta_lsq: np.ndarray
    vary: np.ndarray
    noise_sigma: float
    energised: np.ndarray


def _read_json(path: Path, required=True):
    if not path.exists():
        if required:
            raise ResultsError(f"{path}: missing (a results folder is written by `python -m identify study`)")
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ResultsError(f"{path}: not valid JSON ({exc})") from None


def _require(mapping, keys, where):
    missing = [k for k in keys if k not in mapping]
    if missing:
        raise ResultsError(f"{where}: missing key(s) {missing} required by docs/CONTRACTS.md")


def load_results(result_dir) -> StudyResults:
    """Read and check a results folder (everything except the chain).

    Parameters
    ----------
    result_dir : str or Path

    Raises
    ------
    ResultsError
        A missing file or key, arrays of different lengths, or parameter names that do
        not match the model in ``summary.json``.
    """
    directory = Path(result_dir)
    if not directory.is_dir():
        raise ResultsError(f"{directory}: not a directory")
    summary = _read_json(directory / "summary.json")
    fit = _read_json(directory / "fit.json")
    manifest = _read_json(directory / "manifest.json", required=False) or {}
    diagnosis = _read_json(directory / DIAGNOSIS_FILE, required=False)
    _require(summary, ["model", "units", "noise", "fit", "identifiability", "posterior", "parameters"], directory / "summary.json")
    _require(fit, ["names", "theta", "vary"], directory / "fit.json")

    data_path = directory / "data.npz"
    if not data_path.exists():
        raise ResultsError(f"{data_path}: missing (a results folder is written by `python -m identify study`)")
    with np.load(data_path, allow_pickle=False) as data:
        _require(data, ["time", "current", "displacement"], data_path)
        arrays = {k: np.asarray(data[k], dtype=float) for k in ("time", "current", "displacement")}
        text = {k: str(data[k][()]) for k in data.files if data[k].ndim == 0 and data[k].dtype.kind == "U"}
    shapes = {k: v.shape for k, v in arrays.items()}
    if len(set(shapes.values())) != 1 or arrays["time"].ndim != 1:
        raise ResultsError(f"{data_path}: time, current and displacement must be 1-D of one length, got {shapes}")
    for k, v in arrays.items():
        if not np.isfinite(v).all():
            raise ResultsError(f"{data_path}: {k} has a non-finite value at sample {int(np.argmin(np.isfinite(v)))}")

    fitted_model = model.Model.from_dict(summary["model"])
    names = tuple(fit["names"])
    if names != fitted_model.names:
        raise ResultsError(
            f"{directory / 'fit.json'}: parameter names {list(names)} do not match the model "
            f"{fitted_model!r} of summary.json ({list(fitted_model.names)})"
        )
    theta_lsq = np.asarray(fit["theta"], dtype=float)
    vary = np.asarray(fit["vary"], dtype=bool)
    if theta_lsq.shape != (len(names),) or vary.shape != (len(names),):
        raise ResultsError(f"{directory / 'fit.json'}: theta and vary must have {len(names)} entries")

    units = summary["units"]
    n_quiet = int(summary["noise"].get("n_quiet") or 0)
    energised = np.arange(arrays["time"].size) >= n_quiet
    if not energised.any():
        raise ResultsError(f"{directory / 'summary.json'}: n_quiet = {n_quiet} leaves no energised samples")
    noise_sigma = float(summary["noise"]["sigma"])
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise ResultsError(f"{directory / 'summary.json'}: noise sigma must be finite and >= 0, got {noise_sigma}")
    return StudyResults(
        directory=directory,
        time=arrays["time"],
        current=arrays["current"],
        displacement=arrays["displacement"],
        input_name=text.get("input_name", "current"),
        input_unit=str(units.get("input", text.get("input_unit", "A"))),
        output_name=text.get("output_name", "displacement"),
        output_unit=str(units.get("output", text.get("output_unit", "um"))),
        fit=fit,
        summary=summary,
        manifest=manifest,
        diagnosis=diagnosis,
        model=fitted_model,
        theta_lsq=theta_lsq,
        vary=vary,
        noise_sigma=noise_sigma,
        energised=energised,
    )


@dataclass(frozen=True, eq=False)
class ChainSample:
    """The stored chain, thinned to at most :data:`MAX_CHAIN_ROWS` rows.

    Attributes
    ----------
    chain : ndarray, shape (S, W, D)
        ``S`` stored rows of ``W`` walkers; ``D`` = number of sampled parameters.
    log_prob : ndarray, shape (S, W)
    steps : ndarray of int, shape (S,)
        Sampler step number (1-based) of each row.
    thin : int
        Rows kept: every ``thin``-th step.
    n_steps : int
        Steps in the file.
    discard : int
        Burn-in steps (``summary["posterior"]["discard"]``).
    columns : ndarray of int, shape (D,)
        Column of the full parameter vector each sampled parameter fills.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    steps: np.ndarray
    thin: int
    n_steps: int
    discard: int
    columns: np.ndarray

    @property
    def kept(self) -> np.ndarray:
        """Boolean ``(S,)``: rows after the burn-in."""
        return self.steps > self.discard


def read_chain(results: StudyResults, max_rows: int = MAX_CHAIN_ROWS) -> ChainSample:
    """Read ``chain.h5`` (emcee HDFBackend, group ``"mcmc"``), thinned to ``max_rows`` rows.

    The chain holds either every parameter (``D = P``) or only the varying ones
    (``D`` = number of ``vary``), in :attr:`model.Model.names` order.

    Raises
    ------
    ResultsError
        Missing or empty chain, or a width matching neither convention.
    """
    path = results.directory / "chain.h5"
    if not path.exists():
        raise ResultsError(f"{path}: missing (the posterior chain written by `study`)")
    backend = emcee.backends.HDFBackend(str(path), name="mcmc", read_only=True)
    try:
        n_steps = int(backend.iteration)
    except (KeyError, OSError) as exc:
        raise ResultsError(f"{path}: no emcee chain in group 'mcmc' ({exc})") from None
    if n_steps < 1:
        raise ResultsError(f"{path}: the chain has no steps yet")
    thin = max(1, math.ceil(n_steps / max_rows))
    chain = backend.get_chain(thin=thin)
    log_prob = backend.get_log_prob(thin=thin)
    width = chain.shape[2]
    if width == results.vary.size:
        columns = np.arange(width)
    elif width == int(results.vary.sum()):
        columns = np.flatnonzero(results.vary)
    else:
        raise ResultsError(
            f"{path}: chain has {width} parameters, but the model has {results.vary.size} "
            f"({int(results.vary.sum())} varying)"
        )
    steps = np.arange(1, chain.shape[0] + 1) * thin
    discard = int(results.summary["posterior"].get("discard") or 0)
    return ChainSample(chain, log_prob, steps, thin, n_steps, discard, columns)


def posterior_draws(results: StudyResults, chain: ChainSample, n_draws: int, rng: np.random.Generator) -> np.ndarray:
    """Full parameter vectors drawn from the post-burn-in chain without replacement.

    Returns
    -------
    ndarray, shape (min(n_draws, available), P)
        Pinned parameters take their least-squares (normalisation) value.
    """
    kept = chain.kept
    samples = chain.chain[kept].reshape(-1, chain.chain.shape[2])
    finite = np.isfinite(chain.log_prob[kept].reshape(-1))
    samples = samples[finite]
    if samples.shape[0] == 0:
        raise ResultsError(
            f"{results.directory / 'chain.h5'}: no finite samples after the burn-in of {chain.discard} steps "
            f"(the chain has {chain.n_steps})"
        )
    chosen = rng.choice(samples.shape[0], size=min(int(n_draws), samples.shape[0]), replace=False)
    theta = np.repeat(results.theta_lsq[None, :], chosen.size, axis=0)
    theta[:, chain.columns] = samples[chosen]
    return theta


# --------------------------------------------------------------------------------------
# bands, reversals, cycles
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ModelBands:
    """Pointwise posterior summaries of the model curve, all shape ``(T,)``, output units.

    Attributes
    ----------
    median : pointwise median of the model draws
    credible_lo, credible_hi : 95 % credible band of the model
    predictive_lo, predictive_hi : 95 % predictive band (model plus N(0, sigma^2) noise)
    lsq : the least-squares model curve
    n_draws : int
        Draws used (inside the model's domain).
    n_outside : int
        Draws dropped because the model rejected them (operator bounds cross).
    """

    median: np.ndarray
    credible_lo: np.ndarray
    credible_hi: np.ndarray
    predictive_lo: np.ndarray
    predictive_hi: np.ndarray
    lsq: np.ndarray
    n_draws: int
    n_outside: int


def _mixture_quantile(centres, sigma, probability, tolerance=1e-3, block=4096):
    """Quantile of the equal-weight mixture of N(centres[i, t], sigma^2), for every t.

    Bisection on the mixture CDF inside the exact bracket
    ``[min_i c_i + sigma z_p, max_i c_i + sigma z_p]`` (every component's CDF is below
    ``p`` at the left end and above it at the right end), to ``tolerance * sigma``;
    in blocks of ``block`` samples to bound memory. ``centres`` has shape (D, T);
    returns shape (T,).
    """
    n_samples = centres.shape[1]
    result = np.empty(n_samples)
    offset = sigma * ndtri(probability)
    for start in range(0, n_samples, block):
        c = centres[:, start : start + block]
        low = c.min(axis=0) + offset
        high = c.max(axis=0) + offset
        while (high - low).max() > tolerance * sigma:
            middle = 0.5 * (low + high)
            below = ndtr((middle[None, :] - c) / sigma).mean(axis=0) < probability
            low = np.where(below, middle, low)
            high = np.where(below, high, middle)
        result[start : start + block] = 0.5 * (low + high)
    return result


def model_bands(results: StudyResults, draws: np.ndarray, *, level: float = 0.95) -> ModelBands:
    """Push the draws (and the least-squares vector) through the model in one call.

    Parameters
    ----------
    results : StudyResults
    draws : ndarray, shape (D, P)
        Full parameter vectors.
    level : float, default 0.95
        Central probability of the bands.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    batch = np.vstack([draws, results.theta_lsq[None, :]])
    curves, valid = results.model.evaluate(batch, results.time, results.current)
    if not valid[-1]:
        raise ResultsError(f"{results.directory / 'fit.json'}: the least-squares vector is outside the model's domain")
    inside = valid[:-1]
    if not inside.any():
        raise ResultsError(f"{results.directory / 'chain.h5'}: every posterior draw is outside the model's domain")
    model_curves = curves[:-1][inside]
    tail = 0.5 * (1.0 - level)
    lo, median, hi = np.quantile(model_curves, [tail, 0.5, 1.0 - tail], axis=0)
    sigma = results.noise_sigma
    if sigma > 0:
        predictive_lo = _mixture_quantile(model_curves, sigma, tail)
        predictive_hi = _mixture_quantile(model_curves, sigma, 1.0 - tail)
    else:
        predictive_lo, predictive_hi = lo, hi
    return ModelBands(median, lo, hi, predictive_lo, predictive_hi, curves[-1], int(inside.sum()), int((~inside).sum()))


def input_reversals(current, tolerance: float | None = None) -> np.ndarray:
    """Sample indices where the input turns (its local extrema), robust to small wiggles.

    A peak (trough) is recorded once the input has fallen (risen) by more than
    ``tolerance`` from it, so measurement noise on the input does not split a branch.

    Parameters
    ----------
    current : array_like, shape (T,)
    tolerance : float, optional
        In input units; default :data:`REVERSAL_TOLERANCE` times the input's range.

    Returns
    -------
    ndarray of int, increasing
        Indices of the turning samples (first sample of a flat extremum); never 0 or T-1.
    """
    current = np.asarray(current, dtype=float)
    if current.ndim != 1:
        raise ValueError(f"current must be 1-D, got shape {current.shape}")
    span = float(np.ptp(current)) if current.size else 0.0
    if tolerance is None:
        tolerance = REVERSAL_TOLERANCE * span
    if span == 0.0:
        return np.zeros(0, dtype=int)
    reversals = []
    direction = 0
    high = low = 0  # indices of the running max / min since the last reversal
    for k in range(1, current.size):
        v = current[k]
        if v > current[high]:
            high = k
        if v < current[low]:
            low = k
        if direction >= 0 and current[high] - v > tolerance:
            if direction == 0 and low < high and low > 0:
                reversals.append(low)  # it fell first, then rose, and now falls
            if direction == 1 or high > 0:
                reversals.append(high)
            direction, low = -1, k
        elif direction <= 0 and v - current[low] > tolerance:
            if direction == 0 and high < low and high > 0:
                reversals.append(high)
            if direction == -1 or low > 0:
                reversals.append(low)
            direction, high = 1, k
    return np.array(sorted(set(r for r in reversals if 0 < r < current.size - 1)), dtype=int)


@dataclass(frozen=True)
class Branch:
    """A monotone stretch of the input between two reversals (inclusive sample range)."""

    start: int
    stop: int
    rising: bool


def branches(current, reversals) -> list[Branch]:
    """Split the record at the reversals into branches sharing their end samples.

    Returns
    -------
    list of Branch
        Covering samples ``0 .. T-1``; ``rising`` when the input ends higher than it starts.
    """
    current = np.asarray(current, dtype=float)
    edges = [0] + [int(r) for r in reversals] + [current.size - 1]
    return [
        Branch(a, b, bool(current[b] >= current[a])) for a, b in zip(edges[:-1], edges[1:]) if b > a
    ]


@dataclass(frozen=True)
class CycleError:
    """Error statistics of one input cycle (between two consecutive input minima).

    Attributes
    ----------
    index : int
        1-based cycle number.
    start, stop : int
        Samples ``start <= k < stop``.
    time_start, time_end : float
        Seconds.
    input_peak : float
        Largest input in the cycle (input units).
    rms : float
        RMS of measurement minus posterior-median model (output units).
    max_abs_error : float
        Output units.
    max_error_pct : float
        ``max_abs_error`` as % of the measured displacement range (energised part).
    time_of_max : float
        Seconds.
    """

    index: int
    start: int
    stop: int
    time_start: float
    time_end: float
    input_peak: float
    rms: float
    max_abs_error: float
    max_error_pct: float
    time_of_max: float


def cycle_errors(time, current, error, energised, branch_list, displacement_range) -> list[CycleError]:
    """Per-cycle RMS and max error; cycles are split at the input's minima.

    Parameters
    ----------
    time, current, error : ndarray, shape (T,)
        Seconds, input units, output units (measurement minus model).
    energised : ndarray of bool, shape (T,)
        Only energised samples count (the first cycle starts where they start).
    branch_list : list of Branch
        From :func:`branches`; a minimum is the start of a rising branch.
    displacement_range : float
        Measured range the % refer to (> 0), output units.
    """
    if not displacement_range > 0:
        raise ValueError(f"displacement_range must be > 0, got {displacement_range}")
    first = int(np.argmax(energised))
    minima = [b.start for b in branch_list if b.rising and b.start > first]
    edges = [first] + minima + [current.size]
    cycles = []
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a < 2:
            continue
        segment = np.abs(error[a:b])
        worst = a + int(np.argmax(segment))
        cycles.append(
            CycleError(
                index=len(cycles) + 1,
                start=a,
                stop=b,
                time_start=float(time[a]),
                time_end=float(time[b - 1]),
                input_peak=float(current[a:b].max()),
                rms=float(np.sqrt(np.mean(error[a:b] ** 2))),
                max_abs_error=float(segment.max()),
                max_error_pct=float(100.0 * segment.max() / displacement_range),
                time_of_max=float(time[worst]),
            )
        )
    return cycles


def zoom_samples(curve, centre, band_half_width, *, min_half=15, max_fraction=0.05) -> slice:
    """A window of samples around ``centre`` in which ``curve`` moves about 15 band half-widths.

    Starts at ``min_half`` samples either side and grows by 30 % until the curve's
    range in the window exceeds :data:`ZOOM_BAND_MULTIPLE` times ``band_half_width``
    or the window reaches ``max_fraction`` of the record on either side.

    Parameters
    ----------
    curve : ndarray, shape (T,)
    centre : int
    band_half_width : float
        Typical half-width of the predictive band (output units).

    Returns
    -------
    slice
    """
    n_samples = curve.size
    limit = max(min_half, int(max_fraction * n_samples))
    half = min_half
    target = ZOOM_BAND_MULTIPLE * band_half_width
    while True:
        window = slice(max(0, centre - half), min(n_samples, centre + half + 1))
        if half >= limit or np.ptp(curve[window]) >= target:
            return window
        half = min(limit, int(half * 1.3) + 1)


def loop_zoom_box(current, measured, bands: ModelBands, window: slice, energised):
    """The loops' zoom box: the window's samples, widened so x and y keep the full plot's aspect.

    Returns
    -------
    ((float, float), (float, float))
        Current limits and displacement limits, padded by 10 %.
    """
    x = current[window]
    y = np.concatenate([measured[window], bands.predictive_lo[window], bands.predictive_hi[window]])
    x_range = max(float(np.ptp(current[energised])), 1e-12)
    y_range = max(float(np.ptp(measured[energised])), 1e-12)
    x_mid, y_mid = 0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())
    fraction = max(np.ptp(x) / x_range, np.ptp(y) / y_range, 1e-3)
    half_x, half_y = 0.55 * fraction * x_range, 0.55 * fraction * y_range
    return (x_mid - half_x, x_mid + half_x), (y_mid - half_y, y_mid + half_y)


def autocorrelation_curve(chain: ChainSample, n_points: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Integrated autocorrelation time estimated from growing prefixes of the post-burn-in chain.

    Uses :func:`emcee.autocorr.integrated_time` (walker-averaged autocorrelation
    function, window ``c = 5``); estimates on a chain thinned by ``t`` are multiplied by
    ``t`` (close when tau is several times ``t``).

    Returns
    -------
    chain_lengths : ndarray of int, shape (K,)
        Steps after burn-in used for each estimate.
    tau : ndarray, shape (K, D)
        Steps; NaN for a parameter that never moved.
    """
    rows = chain.chain[chain.kept]
    if rows.shape[0] < 8:
        rows = chain.chain  # too little after burn-in: show the whole chain
    n_rows = rows.shape[0]
    sizes = np.unique(np.geomspace(min(8, n_rows), n_rows, n_points).astype(int))
    tau = np.empty((sizes.size, rows.shape[2]))
    with np.errstate(invalid="ignore", divide="ignore"):
        for i, n in enumerate(sizes):
            tau[i] = chain.thin * emcee.autocorr.integrated_time(rows[:n], c=5, tol=0, quiet=True)
    return sizes * chain.thin, tau


# --------------------------------------------------------------------------------------
# HTML helpers
# --------------------------------------------------------------------------------------
def _number(value, digits=DIGITS) -> str:
    """Table text of a number: ``digits`` significant digits; "—" for None/NaN."""
    if value is None or isinstance(value, str):
        return "—" if value is None else html.escape(value)
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    if not math.isfinite(value):
        return "—"
    return f"{value:.{digits}g}"


def _cell(value, key=None, digits=DIGITS, tag="td", css=None) -> str:
    attributes = ""
    if key is not None:
        attributes += f' data-key="{html.escape(key)}"'
    if css:
        attributes += f' class="{css}"'
    return f"<{tag}{attributes}>{_number(value, digits)}</{tag}>"


def _table(table_id, header, rows, caption=None) -> str:
    """``rows`` are lists of ready cell HTML strings."""
    parts = [f'<table id="{table_id}">']
    if caption:
        parts.append(f"<caption>{caption}</caption>")
    parts.append("<thead><tr>" + "".join(f"<th>{h}</th>" for h in header) + "</tr></thead><tbody>")
    parts.extend("<tr>" + "".join(r) + "</tr>" for r in rows)
    parts.append("</tbody></table>")
    return "\n".join(parts)


def _text(value) -> str:
    return f"<td>{html.escape(str(value))}</td>"


def _figure_html(stem, alt, png_bytes, caption) -> str:
    encoded = base64.b64encode(png_bytes).decode("ascii")
    return (
        f'<figure id="figure-{html.escape(stem)}"><img alt="{html.escape(alt)}" '
        f'src="data:image/png;base64,{encoded}"><figcaption><b>{html.escape(alt)}.</b> {caption}</figcaption></figure>'
    )


def _combination_text(combination) -> str:
    if isinstance(combination, dict):
        terms = [f"{weight:+.3g}·{name}" for name, weight in combination.items()]
        return " ".join(terms)
    return str(combination)


def _flatten(mapping, prefix=""):
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            yield from _flatten(value, name + ".")
        else:
            if isinstance(value, (list, tuple)):
                value = ", ".join(map(str, value)) if value else "(none)"
            yield name, value


def _atomic_write(path: Path, payload: bytes) -> None:
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(payload)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def _png(figure, dpi) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1250px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em} h2{border-bottom:2px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.8em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}
th{background:#f2f2f2} td:first-child,th:first-child{text-align:left}
caption{text-align:left;font-weight:bold;padding:.3em 0}
tr.worst td{background:#ffe3e0} tr.pinned td{color:#777;background:#f7f7f7}
figure{margin:1.2em 0} img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:.92em;color:#444;margin-top:.3em}
.alert{background:#fdecea;border-left:6px solid #d93025;padding:.6em 1em;margin:1em 0}
.ok{background:#e8f5e9;border-left:6px solid #2e7d32;padding:.6em 1em;margin:1em 0}
.note{background:#fff8e1;border-left:6px solid #f9a825;padding:.6em 1em;margin:1em 0}
code{background:#f4f4f4;padding:0 .2em}
"""


# --------------------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------------------
def write_report(result_dir, *, n_draws: int = 200, rng: np.random.Generator | None = None) -> Path:
    """Write ``DIR/report.html`` and every figure as ``DIR/<name>.png``.

    Parameters
    ----------
    result_dir : str or Path
        A results folder written by ``study`` (see docs/CONTRACTS.md).
    n_draws : int, default 200
        Posterior draws pushed through the model for the bands (fewer when the chain
        holds fewer samples after burn-in). 200 puts the 2.5 % quantile between the 5th
        and 6th draw: enough for a band, cheap to evaluate.
    rng : numpy.random.Generator, optional
        Chooses the draws; default ``numpy.random.default_rng(0)``, so the same folder
        gives the same page.

    Returns
    -------
    Path
        ``DIR/report.html``.

    Raises
    ------
    ResultsError
        The folder is incomplete or inconsistent (message names the file).
    ValueError
        ``n_draws < 2``.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 2:
        raise ValueError(f"n_draws must be an integer >= 2, got {n_draws!r}")
    started = _time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    results = load_results(result_dir)
    chain = read_chain(results)
    draws = posterior_draws(results, chain, n_draws, rng)
    bands = model_bands(results, draws)

    time, current, measured = results.time, results.current, results.displacement
    energised = results.energised
    error = measured - bands.median
    displacement_range = float(np.ptp(measured[energised]))
    if displacement_range <= 0:
        raise ResultsError(f"{results.directory / 'data.npz'}: the measured output is constant over the energised part")
    worst = int(np.flatnonzero(energised)[np.argmax(np.abs(error[energised]))])
    max_error_pct = 100.0 * abs(error[worst]) / displacement_range
    reversals = input_reversals(current)
    branch_list = branches(current, reversals)
    cycles = cycle_errors(time, current, error, energised, branch_list, displacement_range)
    band_half_width = 0.5 * float(np.median((bands.predictive_hi - bands.predictive_lo)[energised]))
    zoom = zoom_samples(bands.median, worst, band_half_width)
    window = (float(time[zoom.start]), float(time[zoom.stop - 1]))
    zoom_box = loop_zoom_box(current, measured, bands, zoom, energised)
    lengths, tau_curve = autocorrelation_curve(chain)

    names = results.model.names
    units = {p.name: p.unit for p in results.model.parameters}
    sampled_names = [names[i] for i in chain.columns]
    labels = [f"{n} [{plots.unit_label(units[n])}]" for n in sampled_names]
    figures = {}
    captions = {}
    out = dict(input_name=results.input_name, input_unit=results.input_unit)
    y_units = dict(output_name=results.output_name, output_unit=results.output_unit)

    figures["fig5_input"] = plots.input_figure(time, current, reversals=reversals, **out)
    captions["fig5_input"] = f"The drive as recorded; dots mark the {reversals.size} input reversals used to split the branches."
    figures["fig6_displacement"] = plots.displacement_figure(
        time, measured, bands.median, bands.credible_lo, bands.credible_hi, bands.predictive_lo, bands.predictive_hi, **y_units
    )
    captions["fig6_displacement"] = (
        f"Black: measurement. Red: pointwise median of {bands.n_draws} posterior draws pushed through the model, "
        "with its 95 % credible band (uncertainty of the model curve). Orange: 95 % predictive band, model plus "
        f"sensor noise (σ = {_number(results.noise_sigma, 4)} {plots.unit_label(results.output_unit)}); "
        "about 95 % of the measured samples should lie inside it when the model is adequate."
    )
    figures["fig6_zoom"] = plots.displacement_figure(
        time, measured, bands.median, bands.credible_lo, bands.credible_hi, bands.predictive_lo, bands.predictive_hi,
        window=window, title=f"Zoom on the worst region: {window[0]:.4g}–{window[1]:.4g} s", **y_units,
    )  # fmt: skip
    captions["fig6_zoom"] = (
        f"The samples around the largest error (t = {time[worst]:.4g} s), a window just wide enough for the output to "
        f"move {ZOOM_BAND_MULTIPLE:g} × the predictive band's half-width ({band_half_width:.3g} "
        f"{plots.unit_label(results.output_unit)}), so the bands are visible."
    )
    error_lo = measured - bands.credible_hi
    error_hi = measured - bands.credible_lo
    figures["fig7_error"] = plots.error_figure(
        time, error, error_lo, error_hi, noise_sigma=results.noise_sigma, max_error_pct=max_error_pct,
        max_error_index=worst, output_unit=results.output_unit,
        energised_from=float(time[np.argmax(energised)]) if not energised[0] else None,
    )  # fmt: skip
    captions["fig7_error"] = (
        "Measurement minus the posterior-median model. Where the error leaves the blue ±2σ band systematically, the "
        "model misses something; the paper quotes its maximum as “less than 3 %” of the maximal displacement."
    )
    figures["fig8_loops"] = plots.loops_figure(
        current, measured, bands.median, bands.credible_lo, bands.credible_hi,
        segments=[(b.start, b.stop) for b in branch_list], rising=[b.rising for b in branch_list], zoom_box=zoom_box,
        **out, **y_units,
    )  # fmt: skip
    captions["fig8_loops"] = (
        f"The record is split at the input reversals into {len(branch_list)} monotone branches (rising red, falling "
        "blue); each branch's 95 % credible band is drawn against that branch's own current samples, so rising, "
        "falling and minor loops keep their own bands. Right: the green box around the largest error, at the same "
        "aspect as the full plot, where the band and the measured samples are visible."
    )
    kept = chain.chain[chain.kept].reshape(-1, chain.chain.shape[2])
    if kept.shape[0] > MAX_CORNER_SAMPLES:
        kept = kept[rng.choice(kept.shape[0], MAX_CORNER_SAMPLES, replace=False)]
    vary_columns = [i for i, c in enumerate(chain.columns) if results.vary[c]]
    figures["corner"] = plots.corner_figure(
        kept[:, vary_columns], [labels[i] for i in vary_columns], reference=results.theta_lsq[chain.columns[vary_columns]]
    )
    captions["corner"] = (
        f"{kept.shape[0]} samples after the burn-in. Strong diagonal ridges are the near-degenerate combinations listed "
        "under identifiability."
    )
    trace_step = max(1, math.ceil(chain.chain.shape[0] / MAX_TRACE_ROWS))
    figures["traces"] = plots.trace_figure(
        chain.chain[::trace_step], chain.log_prob[::trace_step], labels, steps=chain.steps[::trace_step], discard=chain.discard
    )
    captions["traces"] = (
        "Each line is one walker. Well-mixed chains look like stationary noise after the shaded burn-in; trends or "
        "stuck walkers mean the chain is too short."
    )
    tau_max = results.summary["posterior"].get("tau_max")
    figures["autocorrelation"] = plots.autocorrelation_figure(lengths, tau_curve, sampled_names, tau_reported=tau_max)
    captions["autocorrelation"] = (
        "Estimated from growing prefixes of the chain after the burn-in (emcee's walker-averaged estimator"
        + (f", chain thinned by {chain.thin}" if chain.thin > 1 else "")
        + "). The chain is long enough when every curve has flattened and lies below the dashed N/50 line."
    )

    directory = results.directory
    png = {}
    for stem, figure in figures.items():
        png[stem] = _png(figure, dpi=80 if stem == "corner" else 100)
        _atomic_write(directory / f"{stem}.png", png[stem])
    figures.clear()

    page = _page(
        results=results,
        chain=chain,
        bands=bands,
        png=png,
        captions=captions,
        cycles=cycles,
        worst=worst,
        max_error_pct=max_error_pct,
        displacement_range=displacement_range,
        seconds=_time.perf_counter() - started,
    )
    report_path = directory / "report.html"
    _atomic_write(report_path, page.encode("utf-8"))
    return report_path


def _fit_status(summary, noise_sigma):
    fit = summary["fit"]
    ratio = fit["rms"] / noise_sigma if noise_sigma > 0 else math.inf
    chi2 = fit.get("reduced_chi2")
    misfit = ratio > RMS_RATIO_LIMIT or (chi2 is not None and chi2 > REDUCED_CHI2_LIMIT)
    return ratio, misfit


def _page(*, results, chain, bands, png, captions, cycles, worst, max_error_pct, displacement_range, seconds) -> str:
    summary, manifest = results.summary, results.manifest
    unit = plots.unit_label(results.output_unit)
    fit = summary["fit"]
    noise = summary["noise"]
    posterior = summary["posterior"]
    ratio, misfit = _fit_status(summary, results.noise_sigma)
    converged = bool(posterior.get("converged"))
    worst_cycle = next((c for c in cycles if c.start <= worst < c.stop), None)
    data_file = manifest.get("data_file") or manifest.get("data") or str(results.directory / "data.npz")
    title = f"Identification report — {Path(str(data_file)).name}"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Model: GPI with {results.model.n_operators} operators, reading <code>{html.escape(results.model.reading)}</code>, "
        f"effects: {html.escape(', '.join(results.model.effect_names) or 'none')}. "
        f"{results.time.size} samples over {results.time[-1] - results.time[0]:.4g} s. "
        f"Results folder: <code>{html.escape(str(results.directory))}</code>.</p>",
    ]

    # ---- at a glance
    parts.append('<h2 id="glance">At a glance</h2>')
    if not converged:
        parts.append(
            '<div class="alert" id="convergence-alert"><b>NOT CONVERGED.</b> The chain has '
            f"{_number(posterior.get('n_steps'))} steps, fewer than 50 × the largest autocorrelation time "
            f"(τ<sub>max</sub> = {_number(posterior.get('tau_max'), 4)} steps). The posterior intervals and bands below "
            "are provisional; rerun the study to extend the chain.</div>"
        )
    else:
        parts.append(
            f'<div class="ok" id="convergence-ok">Converged: {_number(posterior.get("n_steps"))} steps, at least 50 × '
            f"τ<sub>max</sub> = {_number(posterior.get('tau_max'), 4)} steps.</div>"
        )
    fit_sentence = (
        f"Residual RMS {_number(fit['rms'], 4)} {unit} = {ratio:.3g} × the sensor noise σ = "
        f"{_number(results.noise_sigma, 4)} {unit}; reduced χ² = {_number(fit.get('reduced_chi2'), 4)}."
    )
    if misfit:
        parts.append(
            '<div class="alert" id="misfit-alert"><b>The residual is far above the noise.</b> '
            f"{fit_sentence} The bands on this page are conditional on a model that misses something; "
            'see the <a href="#diagnosis">diagnosis section</a>.</div>'
        )
    else:
        parts.append(f'<div class="ok" id="fit-ok"><b>The residual is at the noise level.</b> {fit_sentence}</div>')
    where = f"t = {results.time[worst]:.4g} s"
    if worst_cycle is not None:
        where += f" (cycle {worst_cycle.index}, input {results.current[worst]:.3g} {html.escape(results.input_unit)})"
    relative_width = []
    for p in summary["parameters"]:
        if p.get("vary", True) and p.get("median") not in (None, 0) and p.get("lo95") is not None:
            relative_width.append(((p["hi95"] - p["lo95"]) / abs(p["median"]), p["name"]))
    relative_width.sort(reverse=True)
    parts.append(
        "<ul>"
        f"<li>Max error: <b>{max_error_pct:.3g} %</b> of the measured displacement range "
        f"({displacement_range:.4g} {unit}) for the posterior-median model, worst at {where}; least squares: "
        f"{_number(fit.get('max_error_pct'), 4)} % (the paper reports less than 3 %).</li>"
        + (
            "<li>Least well determined (widest 95 % interval relative to the median): "
            + ", ".join(f"{html.escape(n)} (±{50 * w:.3g} %)" for w, n in relative_width[:3])
            + ".</li>"
            if relative_width
            else ""
        )
        + f"<li>Bands from {bands.n_draws} posterior draws"
        + (f" ({bands.n_outside} draws outside the model's domain dropped)" if bands.n_outside else "")
        + ".</li></ul>"
    )

    # ---- measurement vs model
    parts.append('<h2 id="measurement">1. Measurement vs model</h2>')
    for stem in ("fig5_input", "fig6_displacement", "fig6_zoom", "fig7_error", "fig8_loops"):
        parts.append(_figure_html(stem, FIGURES[stem], png[stem], captions[stem]))

    # ---- fit quality
    parts.append('<h2 id="fit-quality-section">2. Fit quality</h2>')
    rows = [
        [_text(f"residual RMS, least squares [{unit}]"), _cell(fit["rms"], "fit.rms")],
        [_text(f"sensor noise σ [{unit}] ({noise.get('source', '?')}, {noise.get('kind', '?')})"), _cell(noise["sigma"], "noise.sigma")],
        [_text("lag-1 autocorrelation of the noise ρ"), _cell(noise.get("rho"), "noise.rho")],
        [_text("quiet samples used for the noise"), _cell(noise.get("n_quiet"), "noise.n_quiet")],
        [_text("RMS / σ"), _cell(ratio, "derived.rms_ratio", css="alert" if ratio > RMS_RATIO_LIMIT else None)],
        [_text("reduced χ²"), _cell(fit.get("reduced_chi2"), "fit.reduced_chi2")],
        [_text("max error, least squares [% of displacement range]"), _cell(fit.get("max_error_pct"), "fit.max_error_pct")],
        [_text("max error, posterior median [% of displacement range]"), _cell(max_error_pct, "derived.max_error_pct")],
        [_text(f"max |error|, posterior median [{unit}]"), _cell(abs(float(results.displacement[worst] - bands.median[worst])), "derived.max_abs_error")],
        [_text("time of the max error [s]"), _cell(float(results.time[worst]), "derived.time_of_max")],
        [_text("least-squares time [s]"), _cell(fit.get("seconds"), "fit.seconds")],
    ]  # fmt: skip
    parts.append(_table("fit-quality", ["quantity", "value"], rows, caption="Fit quality (energised part of the record)"))
    parts.append(
        f"<p>“Far above the noise” means RMS &gt; {RMS_RATIO_LIMIT} σ or reduced χ² &gt; {REDUCED_CHI2_LIMIT}. "
        "Least-squares numbers are from <code>summary.json</code>; the posterior-median numbers are computed here from "
        "the same draws as the bands.</p>"
    )
    worst_index = max(cycles, key=lambda c: c.max_abs_error).index if cycles else None
    rows = []
    for c in cycles:
        cells = [
            _cell(c.index, f"cycles.{c.index}.index"), _cell(c.time_start, f"cycles.{c.index}.time_start", 4),
            _cell(c.time_end, f"cycles.{c.index}.time_end", 4), _cell(c.input_peak, f"cycles.{c.index}.input_peak", 4),
            _cell(c.rms, f"cycles.{c.index}.rms", 4), _cell(c.max_abs_error, f"cycles.{c.index}.max_abs_error", 4),
            _cell(c.max_error_pct, f"cycles.{c.index}.max_error_pct", 4), _cell(c.time_of_max, f"cycles.{c.index}.time_of_max", 4),
        ]  # fmt: skip
        rows.append(cells)
    cycle_table = _table(
        "cycle-errors",
        ["cycle", "start [s]", "end [s]", f"input peak [{html.escape(results.input_unit)}]", f"RMS [{unit}]",
         f"max |error| [{unit}]", "max error [%]", "at [s]"],
        rows,
        caption="Error per input cycle (cycles split at the input's minima; posterior-median model; worst cycle highlighted)",
    )  # fmt: skip
    if worst_index is not None:
        cycle_table = cycle_table.replace(f'<tr><td data-key="cycles.{worst_index}.index">', f'<tr class="worst"><td data-key="cycles.{worst_index}.index">', 1)
    parts.append(cycle_table)

    # ---- parameters
    parts.append('<h2 id="parameters-section">3. Parameters</h2>')
    rows = []
    for p in summary["parameters"]:
        name = p["name"]
        pinned = not p.get("vary", True)
        key = f"parameters.{name}"
        row = [
            _text(name), _text(plots.unit_label(p.get("unit", ""))), _cell(p.get("table1"), f"{key}.table1"),
            _cell(p.get("lsq"), f"{key}.lsq"), _cell(p.get("lsq_stderr"), f"{key}.lsq_stderr"),
            _cell(p.get("median"), f"{key}.median"), _cell(p.get("lo95"), f"{key}.lo95"), _cell(p.get("hi95"), f"{key}.hi95"),
            _cell(p.get("tau"), f"{key}.tau", 4), _cell(p.get("ess"), f"{key}.ess", 4),
            _text("pinned by normalisation" if pinned else "varies"),
        ]  # fmt: skip
        rows.append(row)
    table = _table(
        "parameters",
        ["parameter", "unit", "Table 1", "least squares", "± std. error", "posterior median", "2.5 %", "97.5 %",
         "τ [steps]", "ESS", "status"],
        rows,
        caption="Parameters: the paper's Table 1 (— for effects), least squares, posterior median and 95 % interval",
    )  # fmt: skip
    for p in summary["parameters"]:
        if not p.get("vary", True):
            table = table.replace(f"<tr><td>{html.escape(p['name'])}</td>", f'<tr class="pinned"><td>{html.escape(p["name"])}</td>', 1)
    parts.append(table)
    rows = [
        [_text("walkers"), _cell(posterior.get("n_walkers"), "posterior.n_walkers")],
        [_text("steps"), _cell(posterior.get("n_steps"), "posterior.n_steps")],
        [_text("burn-in discarded [steps]"), _cell(posterior.get("discard"), "posterior.discard")],
        [_text("thin"), _cell(posterior.get("thin"), "posterior.thin")],
        [_text("mean acceptance fraction"), _cell(posterior.get("acceptance_fraction"), "posterior.acceptance_fraction")],
        [_text("largest autocorrelation time τ [steps]"), _cell(posterior.get("tau_max"), "posterior.tau_max")],
        [_text("converged (steps ≥ 50 τ)"), _cell(converged, "posterior.converged", css=None if converged else "alert")],
        [_text("sampling time [s]"), _cell(posterior.get("seconds"), "posterior.seconds")],
    ]
    parts.append(_table("posterior-settings", ["quantity", "value"], rows, caption="Posterior sampling (emcee)"))
    for stem in ("corner", "traces", "autocorrelation"):
        parts.append(_figure_html(stem, FIGURES[stem], png[stem], captions[stem]))

    identifiability = summary["identifiability"]
    parts.append('<h3 id="identifiability">Identifiability</h3>')
    parts.append(
        "<p>Directions of parameter space the data cannot pin down, from the eigen-analysis of the Fisher "
        "information at the least-squares optimum. Exact degeneracies leave the output unchanged and are fixed by "
        "the normalisation (the pinned parameters above); near-degenerate combinations are kept free and show up as "
        "wide, correlated intervals.</p>"
    )
    normalisation = identifiability.get("normalisation") or {}
    rows = [[_text(k), _cell(v, f"identifiability.normalisation.{k}")] for k, v in normalisation.items()]
    parts.append(_table("identifiability-normalisation", ["pinned parameter", "value"], rows, caption="Normalisation used"))
    for kind in ("exact", "near"):
        rows = []
        for i, item in enumerate(identifiability.get(kind) or []):
            if isinstance(item, dict):
                rows.append([_cell(item.get("eigenvalue"), f"identifiability.{kind}.{i}.eigenvalue"),
                             _text(_combination_text(item.get("combination", item)))])  # fmt: skip
            else:
                rows.append([_cell(None), _text(_combination_text(item))])
        if not rows:
            rows = [[_text("(none)"), _text("")]]
        caption = "Exact degeneracies" if kind == "exact" else "Near-degenerate combinations"
        parts.append(_table(f"identifiability-{kind}", ["eigenvalue", "combination (weights)"], rows, caption=caption))

    # ---- diagnosis
    parts.append('<h2 id="diagnosis">4. Diagnosis</h2>')
    parts.append(_diagnosis_html(results))

    # ---- provenance
    parts.append('<h2 id="provenance-section">5. Provenance</h2>')
    rows = [[_text("convergence"), f'<td class="{"ok" if converged else "alert"}" data-key="posterior.converged.text">'
             f'{"converged" if converged else "NOT CONVERGED"}</td>']]  # fmt: skip
    for name, value in _flatten(manifest):
        rows.append([_text(name), _text(value)])
    rows.append([_text("report: posterior draws for the bands"), _cell(bands.n_draws)])
    rows.append([_text("report: generated in [s]"), _cell(seconds, digits=3)])
    rows.append([_text("report: generated at"), _text(_time.strftime("%Y-%m-%d %H:%M:%S"))])
    parts.append(_table("provenance", ["item", "value"], rows, caption="Provenance (manifest.json)"))
    parts.append("</body></html>")
    return "\n".join(parts)


def _diagnosis_html(results: StudyResults) -> str:
    """The diagnosis hook: render ``diagnosis.json`` and embed ``diagnosis/*.png`` when present."""
    diagnosis = results.diagnosis
    figure_dir = results.directory / DIAGNOSIS_FIGURES
    pngs = sorted(figure_dir.glob("*.png")) if figure_dir.is_dir() else []
    if diagnosis is None and not pngs:
        return (
            f"<p>No diagnosis in this folder (<code>{DIAGNOSIS_FILE}</code> absent). The diagnosis tells which "
            "physical effect the model misses when the residual is above the noise.</p>"
        )
    parts = []
    if diagnosis is not None:
        status = str(diagnosis.get("status", "unknown"))
        missing = diagnosis.get("missing")
        css = "ok" if status == "adequate" else "alert"
        verdict = {
            "adequate": "the residual is consistent with the noise; nothing to add.",
            "missing_effect": f"the model misses the effect <b>{html.escape(str(missing))}</b>; add it with "
            f"<code>--effects {html.escape(str(missing))}</code>.",
            "unexplained": "structure remains in the residual that no effect of the library explains.",
        }.get(status, html.escape(str(missing or "")))
        parts.append(f'<div class="{css}" id="diagnosis-verdict">Verdict: <b>{html.escape(status)}</b>: {verdict}</div>')
        ranking = diagnosis.get("ranking") or []
        if ranking:
            columns = ["effect", "rms_after"] + sorted({k for r in ranking for k in r} - {"effect", "rms_after"})
            rows = []
            for r in ranking:
                row = []
                for col in columns:
                    value = r.get(col)
                    if isinstance(value, (int, float)) and not isinstance(value, bool):
                        row.append(_cell(value, f"diagnosis.{r.get('effect')}.{col}"))
                    else:
                        row.append(_text("—" if value is None else value))
                rows.append(row)
            parts.append(_table("diagnosis-ranking", [html.escape(c) for c in columns], rows,
                                caption="Candidate effects, best first (rms_after: residual RMS with the effect added)"))  # fmt: skip
    for path in pngs:
        alt = f"Diagnosis: {path.stem.replace('_', ' ')}"
        parts.append(_figure_html(f"diagnosis-{path.stem}", alt, path.read_bytes(), f"From <code>{DIAGNOSIS_FIGURES}/{path.name}</code>."))
    return "\n".join(parts)
