"""The uncertainty report of a finished study: one self-contained HTML page plus PNGs.

:func:`write_report` reads a results folder written by ``study`` (layout in
docs/CONTRACTS.md, read through :func:`identify.output.results.load_results`: ``data.npz``,
``chain.h5``, ``fit.json``, ``summary.json``, ``manifest.json``) and writes
``DIR/report.html`` (figures embedded as base64 PNG, tables as HTML, no external files:
it opens in any browser without a server) and every figure as ``DIR/<name>.png``
(names in :data:`FIGURES`). It never refits: model curves come from posterior draws
pushed through the forward model in ONE vectorised :meth:`model.Model.evaluate` call.

What the page shows
-------------------
* **At a glance**: convergence (a red box when not converged), whether the residual is
  at the noise level (a red box when it is far above it), the max error as % of the
  displacement range and where it is worst, the least well determined parameters.
* **1. Measurement vs model** (the paper's Figs. 5-8): input vs time; displacement vs
  time with the 95 % credible band of the model and the 95 % predictive band (model
  plus noise; the AR(1) noise's marginal sd is sigma, so the predictive band is the
  pointwise 2.5/97.5 % quantile of the mixture of N(model draw, sigma^2)), and a zoom
  on the worst region; model error vs time with the ±2 sigma noise band; hysteresis
  loops with the credible band drawn along each branch (the record is split at the
  input reversals, :func:`identify.data.reversals.find_reversals`; each branch's band is a polygon over its
  own current samples, never a sorted current grid).
* **2. Fit quality**: residual RMS vs sigma, reduced chi-square, max error %, the share
  of samples inside the predictive band, per-cycle errors (cycles split at the input's
  minima) and a highlighted warning when the residual is far above the noise (RMS >
  :data:`RMS_RATIO_LIMIT` sigma or reduced chi-square > :data:`REDUCED_CHI2_LIMIT`).
* **3. Parameters**: Table 1, least squares with standard error, posterior median and
  95 % interval, tau, ESS, pinned marker; corner plot, walker traces, autocorrelation
  time vs chain length; identifiability findings.
* **4. Diagnosis** (a small hook for issue 6): when ``DIR/diagnosis.json`` exists
  (keys ``status``, ``missing``, ``ranking`` = list of ``{effect, rms_after, ...}``)
  its verdict and ranking table are shown, and every ``DIR/diagnosis/*.png`` is
  embedded (sorted by name; the file stem becomes the alt text).
* **5. Provenance**: ``manifest.json`` (data file and sha256, seed, settings, versions,
  git commit, run times) and the convergence status stated plainly.

Numbers in tables carry ``data-key`` attributes (``fit.rms``,
``parameters.alpha.median``, ...) and are printed with :data:`DIGITS` significant
digits, so a test can parse them back and compare them with ``summary.json``.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.fileio import atomic_write_bytes
from ..data.reversals import Reversals, find_reversals
from ..fitting.noise import energised_mask
from ..fitting.posterior import BENCH_COVERAGE, ChainBackend, autocorrelation_times
from . import plots, results
from .bands import mixture_quantile
from .diagnosis_files import COMPARISON_FILE, DIAGNOSIS_FIGURES, DIAGNOSIS_FILE, next_step
from .page import (
    embedded_figure,
    escape,
    html_page,
    html_table,
    number_cell,
    number_text,
    plain_text,
    png_bytes,
    text_cell,
)

__all__ = [
    "write_report",
    "load_report_data",
    "read_chain",
    "posterior_draws",
    "model_bands",
    "branches",
    "cycle_errors",
    "zoom_samples",
    "loop_zoom_box",
    "autocorrelation_curve",
    "ReportData",
    "ChainSample",
    "PosteriorDraws",
    "ModelBands",
    "Branch",
    "CycleError",
    "ResultsError",
    "FIGURES",
    "RMS_RATIO_LIMIT",
    "REDUCED_CHI2_LIMIT",
    "DIAGNOSIS_FILE",
    "DIAGNOSIS_FIGURES",
    "NOISE_COORDINATE",
    "residual_above_noise",
    "Comparison",
    "load_comparison",
    "comparison_figure",
    "COMPARISON_FIGURE",
]

#: Residual RMS above this multiple of the noise sigma is "far above the noise".
RMS_RATIO_LIMIT = 1.2
#: Reduced chi-square above this is "far above the noise".
REDUCED_CHI2_LIMIT = 1.5
#: Name of the sampled log noise sigma (last chain column when the noise is free).
NOISE_COORDINATE = "noise_log_sigma"
#: At most this many stored chain rows are read (the chain is thinned to fit).
MAX_CHAIN_ROWS = 4000
#: At most this many rows per walker are drawn in the trace plots.
MAX_TRACE_ROWS = 800
#: At most this many samples go into the corner plot.
MAX_CORNER_SAMPLES = 6000
#: The zoom window is wide enough for the output to move this many predictive half-widths.
ZOOM_BAND_MULTIPLE = 15.0
#: PNG resolution [dots per inch]; the corner plot is larger in inches, so lower.
DPI = {"default": 100, "corner": 80}

#: figure file stem -> alt text (also the caption's heading), in page order.
FIGURES = {
    "fig5_input": "Input vs time (paper Fig. 5)",
    "fig6_displacement": "Displacement vs time: measurement, posterior median model, 95% credible and predictive "
    "bands (paper Fig. 6)",
    "fig6_zoom": "Displacement vs time, zoom on the worst region",
    "fig7_error": "Model error vs time with the 2-sigma noise band (paper Fig. 7)",
    "fig8_loops": "Hysteresis loops: displacement vs current with the 95% credible band along each branch (paper Fig. "
    "8)",
    "corner": "Corner plot of the posterior of the varying parameters",
    "traces": "Walker traces with the burn-in marked",
    "autocorrelation": "Integrated autocorrelation time vs chain length with the N/50 line",
}


#: The comparison's figure (written only when the study is compared with an earlier one).
COMPARISON_FIGURE = {"comparison": "Before and after: the earlier study's model and this one's"}


class ResultsError(ValueError):
    """A results folder that cannot be reported on; the message names the file and the problem."""


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ReportData:
    """A results folder as the report needs it (read by :func:`load_report_data`).

    Attributes
    ----------
    directory : Path
    study : identify.output.results.StudyResults
        ``record`` (``data.npz``), ``fit`` (:class:`identify.fitting.lsq.FitResult`),
        ``summary``, ``manifest``.
    diagnosis : dict or None
        ``diagnosis.json`` when present.
    energised : ndarray of bool, shape (T,)
        Samples after the quiet segment (:func:`identify.fitting.noise.energised_mask`).
    noise_sigma : float
        Sensor noise sd [output unit] (``summary["noise"]["sigma"]``).
    """

    directory: Path
    study: results.StudyResults
    diagnosis: dict | None
    energised: np.ndarray
    noise_sigma: float

    @property
    def record(self):
        return self.study.record

    @property
    def fit(self):
        return self.study.fit

    @property
    def model(self):
        return self.study.fit.model

    @property
    def summary(self) -> dict:
        return self.study.summary

    @property
    def manifest(self) -> dict:
        return self.study.manifest

    @property
    def noise_is_free(self) -> bool:
        return self.summary["noise"].get("source") == "free"


def load_report_data(result_dir) -> ReportData:
    """Read and check a results folder (everything except the chain).

    Raises
    ------
    ResultsError
        A missing or unreadable file, a summary without a posterior (sampling not
        finished), or a record whose output is constant.
    """
    directory = Path(result_dir)
    try:
        study = results.load_results(directory)
    except (OSError, KeyError, ValueError) as exc:
        raise ResultsError(f"{directory}: cannot read the results folder ({exc})") from exc
    summary = study.summary
    for key in ("model", "units", "noise", "fit", "parameters"):
        if key not in summary:
            raise ResultsError(f"{directory / results.FILES['summary']}: missing key {key!r} (docs/CONTRACTS.md)")
    if summary.get("posterior") is None:
        raise ResultsError(
            f"{directory / results.FILES['summary']}: no posterior yet (the study has not finished sampling; "
            "rerun the same study command to resume it)"
        )
    diagnosis_path = directory / DIAGNOSIS_FILE
    diagnosis = results.read_json(diagnosis_path) if diagnosis_path.exists() else None
    record = study.record
    energised = energised_mask(record, study.fit.noise)
    if not np.ptp(np.asarray(record.displacement)[energised]) > 0:
        raise ResultsError(f"{directory / results.FILES['data']}: the output is constant over the energised part")
    noise_sigma = summary["noise"].get("sigma")
    if noise_sigma is None or not (math.isfinite(noise_sigma) and noise_sigma > 0):
        raise ResultsError(
            f"{directory / results.FILES['summary']}: noise sigma must be finite and > 0, got {noise_sigma}"
        )
    return ReportData(directory, study, diagnosis, energised, float(noise_sigma))


@dataclass(frozen=True, eq=False)
class ChainSample:
    """The stored chain, thinned to at most :data:`MAX_CHAIN_ROWS` rows.

    Attributes
    ----------
    chain : ndarray, shape (S, W, D)
        ``S`` stored rows of ``W`` walkers; ``D`` sampled coordinates.
    log_prob : ndarray, shape (S, W)
    steps : ndarray of int, shape (S,)
        Sampler step number (1-based) of each row.
    thin : int
        Every ``thin``-th step was read.
    n_steps : int
        Steps in the file.
    discard : int
        Burn-in steps (``summary["posterior"]["discard"]``).
    names : tuple of str, length D
        The sampled coordinates: the free model parameters, then
        :data:`NOISE_COORDINATE` when the noise sigma is free.
    columns : ndarray of int, shape (D_model,)
        Column of the full parameter vector each of the first ``D_model`` coordinates fills.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    steps: np.ndarray
    thin: int
    n_steps: int
    discard: int
    names: tuple
    columns: np.ndarray

    @property
    def kept(self) -> np.ndarray:
        """Boolean ``(S,)``: rows after the burn-in."""
        return self.steps > self.discard

    @property
    def has_noise(self) -> bool:
        return bool(self.names) and self.names[-1] == NOISE_COORDINATE


def read_chain(data: ReportData, max_rows: int = MAX_CHAIN_ROWS) -> ChainSample:
    """Read ``chain.h5`` (emcee HDFBackend, group ``"mcmc"``), thinned to ``max_rows`` rows.

    Raises
    ------
    ResultsError
        Missing or empty chain, or a width that does not match the free parameters.
    """
    path = data.directory / results.FILES["chain"]
    if not path.exists():
        raise ResultsError(f"{path}: missing (the posterior chain written by `study`)")
    backend = ChainBackend(
        str(path), name="mcmc", read_only=True
    )  # takes no file lock: a running study is not disturbed
    try:
        n_steps = int(backend.iteration)
    except (KeyError, OSError) as exc:
        raise ResultsError(f"{path}: no emcee chain in group 'mcmc' ({exc})") from None
    if n_steps < 1:
        raise ResultsError(f"{path}: the chain has no steps yet")
    columns = np.flatnonzero(data.fit.vary)
    names = tuple(data.model.names[i] for i in columns) + ((NOISE_COORDINATE,) if data.noise_is_free else ())
    thin = max(1, math.ceil(n_steps / max_rows))
    chain = backend.get_chain(thin=thin)
    if chain.shape[2] != len(names):
        raise ResultsError(
            f"{path}: the chain has {chain.shape[2]} coordinates, expected {len(names)} ({', '.join(names)})"
        )
    log_prob = backend.get_log_prob(thin=thin)
    steps = np.arange(1, chain.shape[0] + 1) * thin
    discard = int(data.summary["posterior"].get("discard") or 0)
    if discard >= n_steps:
        raise ResultsError(f"{path}: the burn-in ({discard} steps) covers the whole chain ({n_steps} steps)")
    return ChainSample(chain, log_prob, steps, thin, n_steps, discard, names, columns)


@dataclass(frozen=True, eq=False)
class PosteriorDraws:
    """Posterior draws as full model vectors.

    Attributes
    ----------
    theta : ndarray, shape (N, P)
        Pinned parameters hold their least-squares (normalisation) value.
    noise_sigma : ndarray, shape (N,), or None
        Each draw's sigma when the noise is free, else None (the fixed sigma applies).
    """

    theta: np.ndarray
    noise_sigma: np.ndarray | None


def posterior_draws(data: ReportData, chain: ChainSample, n_draws: int, rng: np.random.Generator) -> PosteriorDraws:
    """Draw ``min(n_draws, available)`` post-burn-in samples without replacement."""
    kept = chain.kept
    samples = chain.chain[kept].reshape(-1, chain.chain.shape[2])
    samples = samples[np.isfinite(chain.log_prob[kept].reshape(-1))]
    if samples.shape[0] == 0:
        raise ResultsError(f"{data.directory / results.FILES['chain']}: no finite samples after the burn-in")
    chosen = samples[rng.choice(samples.shape[0], size=min(int(n_draws), samples.shape[0]), replace=False)]
    theta = np.repeat(data.fit.theta[None, :], chosen.shape[0], axis=0)
    theta[:, chain.columns] = chosen[:, : chain.columns.size]
    sigma = np.exp(chosen[:, -1]) if chain.has_noise else None
    return PosteriorDraws(theta, sigma)


# --------------------------------------------------------------------------------------
# bands, reversals, cycles, zooms, autocorrelation
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ModelBands:
    """Pointwise posterior summaries of the model curve, all shape ``(T,)``, output unit.

    Attributes
    ----------
    median : pointwise median of the model draws
    credible_lo, credible_hi : 95 % credible band of the model
    predictive_lo, predictive_hi : 95 % predictive band (model plus N(0, sigma^2) noise)
    lsq : the least-squares model curve
    n_draws : int
        Draws used (with a finite model output).
    n_outside : int
        Draws dropped because their model output is not finite.
    """

    median: np.ndarray
    credible_lo: np.ndarray
    credible_hi: np.ndarray
    predictive_lo: np.ndarray
    predictive_hi: np.ndarray
    lsq: np.ndarray
    n_draws: int
    n_outside: int


def model_bands(data: ReportData, draws: PosteriorDraws, *, level: float = 0.95) -> ModelBands:
    """Push the draws and the least-squares vector through the model in one call.

    Parameters
    ----------
    data : ReportData
    draws : PosteriorDraws
        ``theta`` of shape (D, P).
    level : float, default 0.95
        Central probability of the bands.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    record = data.record
    batch = np.vstack([draws.theta, data.fit.theta[None, :]])
    curves, valid = data.model.evaluate(batch, record.time, record.current)
    if not valid[-1]:
        raise ResultsError(
            f"{data.directory / results.FILES['fit']}: the least-squares vector gives a non-finite model output"
        )
    inside = valid[:-1]
    if not inside.any():
        raise ResultsError(
            f"{data.directory / results.FILES['chain']}: every posterior draw gives a non-finite model output"
        )
    model_curves = curves[:-1][inside]
    tail = 0.5 * (1.0 - level)
    lo, median, hi = np.quantile(model_curves, [tail, 0.5, 1.0 - tail], axis=0)
    sigmas = (
        draws.noise_sigma[inside] if draws.noise_sigma is not None else np.full(model_curves.shape[0], data.noise_sigma)
    )
    predictive_lo = mixture_quantile(model_curves, sigmas, tail)
    predictive_hi = mixture_quantile(model_curves, sigmas, 1.0 - tail)
    return ModelBands(median, lo, hi, predictive_lo, predictive_hi, curves[-1], int(inside.sum()), int((~inside).sum()))


@dataclass(frozen=True)
class Branch:
    """A monotone stretch of the input between two reversals (inclusive sample range)."""

    start: int
    stop: int
    rising: bool


def branches(n_samples: int, reversals: Reversals) -> list[Branch]:
    """Split the record at the reversals into branches sharing their end samples.

    A branch ending at a peak rises, one ending at a trough falls (a flat quiet start before
    the first rise counts as falling); the last branch turns away from the last reversal.

    Returns
    -------
    list of Branch
        Covering samples ``0 .. n_samples-1``, rising and falling in turn.
    """
    edges = [0] + [int(r) for r in reversals.index] + [int(n_samples) - 1]
    ends_rising = [bool(k > 0) for k in reversals.kind] + [bool(reversals.kind[-1] < 0) if len(reversals) else True]
    return [Branch(a, b, rising) for a, b, rising in zip(edges[:-1], edges[1:], ends_rising) if b > a]


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
        Largest input in the cycle (input unit).
    rms : float
        RMS of measurement minus posterior-median model (output unit).
    max_abs_error : float
        Output unit.
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
        Seconds, input unit, output unit (measurement minus model).
    energised : ndarray of bool, shape (T,)
        Only energised samples count (the first cycle starts where they start).
    branch_list : list of Branch
        From :func:`branches`; a minimum is the start of a rising branch.
    displacement_range : float
        Measured range the % refer to (> 0), output unit.
    """
    if not displacement_range > 0:
        raise ValueError(f"displacement_range must be > 0, got {displacement_range}")
    first = int(np.argmax(energised))
    minima = [b.start for b in branch_list if b.rising and b.start > first]
    edges = [first] + minima + [len(time)]
    cycles = []
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a < 2:
            continue
        magnitude = np.abs(error[a:b])
        worst = a + int(np.argmax(magnitude))
        cycles.append(
            CycleError(
                index=len(cycles) + 1,
                start=a,
                stop=b,
                time_start=float(time[a]),
                time_end=float(time[b - 1]),
                input_peak=float(np.max(current[a:b])),
                rms=float(np.sqrt(np.mean(error[a:b] ** 2))),
                max_abs_error=float(magnitude.max()),
                max_error_pct=float(100.0 * magnitude.max() / displacement_range),
                time_of_max=float(time[worst]),
            )
        )
    return cycles


def zoom_samples(curve, centre, band_half_width, *, min_half=15, max_fraction=0.05) -> slice:
    """A window of samples around ``centre`` in which ``curve`` moves a few band widths.

    Starts at ``min_half`` samples either side and grows by 30 % until the curve's
    range in the window reaches :data:`ZOOM_BAND_MULTIPLE` times ``band_half_width``
    or the half-window reaches ``max_fraction`` of the record.

    Parameters
    ----------
    curve : ndarray, shape (T,)
    centre : int
        Sample index.
    band_half_width : float
        Typical half-width of the predictive band (output unit).

    Returns
    -------
    slice
    """
    n_samples = len(curve)
    limit = max(min_half, int(max_fraction * n_samples))
    half = min_half
    target = ZOOM_BAND_MULTIPLE * band_half_width
    while True:
        window = slice(max(0, centre - half), min(n_samples, centre + half + 1))
        if half >= limit or np.ptp(curve[window]) >= target:
            return window
        half = min(limit, int(half * 1.3) + 1)


def loop_zoom_box(current, measured, bands: ModelBands, window: slice, energised):
    """The loops' zoom box: the window's samples, widened so that x and y keep the full plot's aspect.

    Returns
    -------
    ((float, float), (float, float))
        Current limits and displacement limits (10 % margin).
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

    Uses emcee's estimator (walker-averaged autocorrelation function, window ``c = 5``) as
    :func:`identify.fitting.posterior.autocorrelation_times` computes it (equal to
    :func:`emcee.autocorr.integrated_time` to 1e-12, one inverse FFT per parameter instead
    of one per walker and parameter); estimates from a chain thinned by ``t`` are multiplied
    by ``t`` (close when tau is several times ``t``).

    Returns
    -------
    chain_lengths : ndarray of int, shape (K,)
        Steps after burn-in used for each estimate.
    tau : ndarray, shape (K, D)
        Steps; NaN for a coordinate that never moved.
    """
    rows = chain.chain[chain.kept]
    if rows.shape[0] < 8:
        rows = chain.chain  # too little after burn-in: use the whole chain
    n_rows = rows.shape[0]
    sizes = np.unique(np.geomspace(min(8, n_rows), n_rows, n_points).astype(int))
    tau = np.empty((sizes.size, rows.shape[2]))
    for i, n in enumerate(sizes):
        tau[i] = chain.thin * autocorrelation_times(rows[:n])
    return sizes * chain.thin, tau


# --------------------------------------------------------------------------------------
# what the page states
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Analysis:
    """Everything computed for one page (internal)."""

    chain: ChainSample
    bands: ModelBands
    error: np.ndarray
    worst: int
    max_error_pct: float
    displacement_range: float
    inside_predictive_pct: float
    reversals: np.ndarray
    branch_list: list
    cycles: list
    band_half_width: float
    credible_half_width: float
    zoom: slice
    zoom_box: tuple
    autocorrelation: tuple


def analyse_report(data: ReportData, n_draws: int, rng: np.random.Generator) -> _Analysis:
    record = data.record
    time, current, measured = (np.asarray(a, dtype=float) for a in (record.time, record.current, record.displacement))
    energised = data.energised
    chain = read_chain(data)
    bands = model_bands(data, posterior_draws(data, chain, n_draws, rng))
    error = measured - bands.median
    displacement_range = float(np.ptp(measured[energised]))
    worst = int(np.flatnonzero(energised)[np.argmax(np.abs(error[energised]))])
    inside = (measured >= bands.predictive_lo) & (measured <= bands.predictive_hi)
    reversals = find_reversals(current)
    branch_list = branches(current.size, reversals)
    band_half_width = 0.5 * float(np.median((bands.predictive_hi - bands.predictive_lo)[energised]))
    zoom = zoom_samples(bands.median, worst, band_half_width)
    return _Analysis(
        chain=chain,
        bands=bands,
        error=error,
        worst=worst,
        max_error_pct=100.0 * abs(error[worst]) / displacement_range,
        displacement_range=displacement_range,
        inside_predictive_pct=100.0 * float(inside[energised].mean()),
        reversals=reversals.index,
        branch_list=branch_list,
        cycles=cycle_errors(time, current, error, energised, branch_list, displacement_range),
        band_half_width=band_half_width,
        credible_half_width=0.5 * float(np.median((bands.credible_hi - bands.credible_lo)[energised])),
        zoom=zoom,
        zoom_box=loop_zoom_box(current, measured, bands, zoom, energised),
        autocorrelation=autocorrelation_curve(chain),
    )


def report_figures(data: ReportData, analysis: _Analysis, rng: np.random.Generator):
    """Yield ``(stem, figure, caption)`` in page order; each figure is made only when asked for."""
    record = data.record
    time, current, measured = (np.asarray(a, dtype=float) for a in (record.time, record.current, record.displacement))
    bands, chain, worst = analysis.bands, analysis.chain, analysis.worst
    unit = plots.unit_label(record.output_unit)
    x_names = dict(input_name=record.input_name, input_unit=record.input_unit)
    y_names = dict(output_name=record.output_name, output_unit=record.output_unit)
    band_arrays = (bands.median, bands.credible_lo, bands.credible_hi, bands.predictive_lo, bands.predictive_hi)

    yield (
        "fig5_input",
        plots.input_figure(time, current, reversals=analysis.reversals, **x_names),
        (
            f"The drive as recorded; dots mark the {analysis.reversals.size} input reversals at which the record is "
            "split "
            "into branches."
        ),
    )
    yield (
        "fig6_displacement",
        plots.displacement_figure(time, measured, *band_arrays, **y_names),
        (
            f"Black: measurement. Red: pointwise median of {bands.n_draws} posterior draws pushed through the model, "
            "with "
            f"its 95 % credible band (the uncertainty of the model curve; typical half-width "
            f"{analysis.credible_half_width:.3g} {unit}). Orange: 95 % predictive band, model plus sensor noise "
            f"(typical half-width {analysis.band_half_width:.3g} {unit}); {analysis.inside_predictive_pct:.1f} % of "
            "the "
            "energised measured samples lie inside it (about 95 % when the model is adequate)."
        ),
    )
    window = (float(time[analysis.zoom.start]), float(time[analysis.zoom.stop - 1]))
    yield (
        "fig6_zoom",
        plots.displacement_figure(
            time,
            measured,
            *band_arrays,
            window=window,
            title=f"Zoom on the worst region: {window[0]:.4g}–{window[1]:.4g} s",
            **y_names,
        ),
        (
            f"The samples around the largest error (t = {time[worst]:.4g} s), in a window just wide enough for the "
            "model to "
            f"move {ZOOM_BAND_MULTIPLE:g} × the predictive band's half-width, so that the bands are visible."
        ),
    )
    energised_from = None if data.energised[0] else float(time[np.argmax(data.energised)])
    yield (
        "fig7_error",
        plots.error_figure(
            time,
            analysis.error,
            measured - bands.credible_hi,
            measured - bands.credible_lo,
            noise_sigma=data.noise_sigma,
            max_error_pct=analysis.max_error_pct,
            max_error_index=worst,
            output_unit=record.output_unit,
            energised_from=energised_from,
        ),
        (
            "Measurement minus the posterior-median model. Where the error leaves the blue ±2σ band systematically, "
            "the "
            "model misses something; the paper quotes this maximum as “less than 3 %” of the maximal displacement."
        ),
    )
    yield (
        "fig8_loops",
        plots.loops_figure(
            current,
            measured,
            bands.median,
            bands.credible_lo,
            bands.credible_hi,
            segments=[(b.start, b.stop) for b in analysis.branch_list],
            rising=[b.rising for b in analysis.branch_list],
            zoom_box=analysis.zoom_box,
            **x_names,
            **y_names,
        ),
        (
            f"The record is split at the input reversals into {len(analysis.branch_list)} monotone branches (rising "
            "red, "
            "falling blue); each branch's 95 % credible band is a polygon over that branch's own current samples, so "
            "rising, "
            "falling and minor loops keep their own bands (never a sorted current grid, which would mix branches of a "
            f"system with memory). The band is {2 * analysis.credible_half_width:.3g} {unit} wide typically, so it "
            "shows "
            "only in the zoom (right: the green box around the largest error, at the full plot's aspect)."
        ),
    )

    units = {p.name: p.unit for p in data.model.parameters}
    labels = [
        f"ln σ [ln {unit}]" if n == NOISE_COORDINATE else f"{n} [{plots.unit_label(units[n])}]" for n in chain.names
    ]
    reference = list(data.fit.theta[chain.columns])
    if chain.has_noise:
        reference.append(math.log(data.noise_sigma))
    kept = chain.chain[chain.kept].reshape(-1, chain.chain.shape[2])
    if kept.shape[0] > MAX_CORNER_SAMPLES:
        kept = kept[rng.choice(kept.shape[0], MAX_CORNER_SAMPLES, replace=False)]
    yield (
        "corner",
        plots.corner_figure(kept, labels, reference=reference),
        (
            f"{kept.shape[0]} samples after the burn-in of {chain.discard} steps. Narrow diagonal ridges are the "
            "near-degenerate combinations listed under identifiability."
        ),
    )
    step = max(1, math.ceil(chain.chain.shape[0] / MAX_TRACE_ROWS))
    yield (
        "traces",
        plots.trace_figure(
            chain.chain[::step], chain.log_prob[::step], labels, steps=chain.steps[::step], discard=chain.discard
        ),
        (
            "Each line is one walker. A well-mixed chain looks like stationary noise after the shaded burn-in; trends "
            "or "
            "stuck walkers mean the chain is too short."
        ),
    )
    lengths, tau = analysis.autocorrelation
    yield (
        "autocorrelation",
        plots.autocorrelation_figure(
            lengths, tau, list(chain.names), tau_reported=data.summary["posterior"].get("tau_max")
        ),
        (
            "Estimated from growing prefixes of the chain after the burn-in (emcee's walker-averaged estimator"
            + (f", chain read every {chain.thin} steps" if chain.thin > 1 else "")
            + "). The chain is long enough when every curve has flattened and lies below the dashed N/50 line."
        ),
    )


# --------------------------------------------------------------------------------------
# HTML
# --------------------------------------------------------------------------------------
def _combination_text(combination) -> str:
    if isinstance(combination, dict):
        return " ".join(f"{weight:+.3g}·{name}" for name, weight in combination.items())
    return str(combination)


def _flatten(value, prefix=""):
    """``(dotted name, scalar)`` pairs of nested dicts and lists (lists of scalars joined)."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _flatten(item, f"{prefix}.{key}" if prefix else str(key))
    elif isinstance(value, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in value):
        for i, item in enumerate(value, start=1):
            yield from _flatten(item, f"{prefix}[{i}]")
    elif isinstance(value, (list, tuple)):
        yield prefix, " ".join(map(str, value)) if value else "none"
    else:
        yield prefix, value


def residual_above_noise(summary: dict) -> bool:
    """Whether the least-squares residual of ``summary`` (``summary.json``) is far above the
    sensor noise (RMS > :data:`RMS_RATIO_LIMIT` sigma or reduced chi-square >
    :data:`REDUCED_CHI2_LIMIT`), the red box of "At a glance". False when sigma was identified
    from the residual itself (``noise.source == "free"``): RMS is then near sigma by construction."""
    noise = summary.get("noise") or {}
    sigma = noise.get("sigma")
    if noise.get("source") == "free" or not sigma or not math.isfinite(sigma):
        return False
    return _fit_verdict(summary, float(sigma))[1]


def _fit_verdict(summary, noise_sigma):
    """(RMS / sigma, far above the noise?) from the least-squares numbers of ``summary``."""
    fit = summary["fit"]
    ratio = float(fit["rms"]) / noise_sigma
    chi2 = fit.get("reduced_chi2")
    misfit = ratio > RMS_RATIO_LIMIT or (chi2 is not None and chi2 > REDUCED_CHI2_LIMIT)
    return ratio, misfit


def _glance_html(data: ReportData, analysis: _Analysis) -> str:
    summary, posterior, fit = data.summary, data.summary["posterior"], data.summary["fit"]
    record = data.record
    unit = escape(plots.unit_label(record.output_unit))  # page text: put into the markup below
    ratio, misfit = _fit_verdict(summary, data.noise_sigma)
    parts = ['<h2 id="glance">At a glance</h2>']
    message = str(posterior.get("message") or "")
    for prefix in ("NOT CONVERGED:", "converged:"):  # the box says it already
        if message.startswith(prefix):
            message = message[len(prefix) :].strip()
    message = plain_text(message[:1].upper() + message[1:] + ("" if message.endswith(".") or not message else "."))
    if posterior.get("converged"):
        parts.append(f'<div class="ok" id="convergence-ok"><b>Converged.</b> {message}</div>')
    else:
        parts.append(
            f'<div class="alert" id="convergence-alert"><b>NOT CONVERGED.</b> {message or "The chain is too short."} '
            "The intervals and bands below are provisional; rerun the same study command to extend the chain.</div>"
        )
    sentence = (
        f"Residual RMS {number_text(fit['rms'], 4)} {unit} = {ratio:.3g} × the sensor noise σ = "
        f"{number_text(data.noise_sigma, 4)} {unit}; reduced χ² = {number_text(fit.get('reduced_chi2'), 4)}."
    )
    if data.noise_is_free:
        parts.append(
            '<div class="note" id="fit-free-noise"><b>σ was estimated from the residual itself</b> (no quiet '
            "segment), so "
            "RMS ≈ σ by construction and cannot reveal a misfit; judge the fit by the figures and the diagnosis. "
            f"{sentence}</div>"
        )
    elif misfit:
        parts.append(
            f'<div class="alert" id="misfit-alert"><b>The residual is far above the noise.</b> {sentence} The bands on '
            'this page are conditional on a model that misses something; see the <a href="#diagnosis">diagnosis '
            "section</a>.</div>"
        )
        parts.append(_next_step_html(data))
    else:
        parts.append(f'<div class="ok" id="fit-ok"><b>The residual is at the noise level.</b> {sentence}</div>')
    worst = analysis.worst
    where = f"t = {record.time[worst]:.4g} s"
    cycle = next((c for c in analysis.cycles if c.start <= worst < c.stop), None)
    if cycle is not None:
        where += f" (cycle {cycle.index}"
    where += f", input {record.current[worst]:.3g} {escape(plots.unit_label(record.input_unit))}" + (
        ")" if cycle else ""
    )
    widths = sorted(
        (
            ((p["hi95"] - p["lo95"]) / abs(p["median"]), p["name"])
            for p in summary["parameters"]
            if p.get("vary") and p.get("median") and p.get("lo95") is not None and p.get("hi95") is not None
        ),
        reverse=True,
    )
    items = [
        f"Max error <b>{analysis.max_error_pct:.3g} %</b> of the measured displacement range "
        f"({analysis.displacement_range:.4g} {unit}) for the posterior-median model, worst at {where}; least squares: "
        f"{number_text(fit.get('max_error_pct'), 4)} % (the paper reports less than 3 %).",
        f"{analysis.inside_predictive_pct:.1f} % of the measured samples lie inside the 95 % predictive band.",
    ]
    if widths:
        items.append(
            "Least well determined (widest 95 % interval relative to the median): "
            + ", ".join(f"<code>{escape(name)}</code> (±{50 * w:.3g} %)" for w, name in widths[:3])
            + "."
        )
    items.append(
        f"Bands from {analysis.bands.n_draws} posterior draws"
        + (f" ({analysis.bands.n_outside} with a non-finite model output dropped)" if analysis.bands.n_outside else "")
        + "."
    )
    parts.append("<ul>" + "".join(f"<li>{item}</li>" for item in items) + "</ul>")
    return "\n".join(parts)


def _next_step_html(data: ReportData) -> str:
    """The diagnosis' verdict in one sentence and the exact command to run next (a box of "At a
    glance"); without a diagnosis, the commands that make one."""
    manifest_data = data.manifest.get("data") if isinstance(data.manifest.get("data"), dict) else {}
    data_file = str(manifest_data.get("file") or data.record.source)
    if data.diagnosis is None:
        command = f"python -m identify diagnose {data_file} --out {data.directory}"
        return (
            '<div class="note" id="next-step"><b>Next:</b> no diagnosis in this folder (the study ran with '
            "<code>--no-diagnose</code>, or before studies diagnosed themselves). Find which effect is missing with "
            f"<code>{escape(command)}</code>, then <code>{escape(f'python -m identify report {data.directory}')}"
            "</code>.</div>"
        )
    sentence, command = next_step(
        data.diagnosis, data_file=data_file, effects=data.model.effect_names, out_dir=data.directory
    )
    run = f'<br>Next: <code class="command">{escape(command)}</code>' if command else ""
    return f'<div class="note" id="next-step"><b>Diagnosis:</b> {escape(sentence)}{run}</div>'


#: How the noise sigma was found (``summary.json`` ``noise.source``), in words.
_NOISE_SOURCES = {
    "quiet_segment": "the record's unenergised start",
    "user": "the value given",
    "given": "the value given",
    "free": "the residual itself, sampled",
}
#: The noise model (``noise.kind``), in words.
_NOISE_KINDS = {"white": "white", "ar1": "first-order autoregressive"}
#: A diagnosis' status (``diagnosis.json`` ``status``), in words.
STATUS_LABELS = {
    "adequate": "adequate",
    "missing_effect": "an effect is missing",
    "tied": "tied",
    "unexplained": "unexplained",
}
#: The diagnosis ranking's columns (``diagnosis.json`` ``ranking`` keys) -> headers; ``{unit}``: the output unit.
_RANKING_HEADERS = {
    "effect": "effect",
    "rms_after": "RMS with it [{unit}]",
    "max_error_pct_after": "max error with it [% of range]",
    "delta_bic": "BIC gain",
    "explained_fraction": "share of the misfit explained (1: all)",
    "adequate_after": "residual is noise with it",
    "refitted": "refitted",
    "parameters": "fitted parameters",
    "note": "note",
}


def _fit_quality_html(data: ReportData, analysis: _Analysis) -> str:
    summary, fit, noise = data.summary, data.summary["fit"], data.summary["noise"]
    record = data.record
    unit = plots.unit_label(record.output_unit)
    ratio, _ = _fit_verdict(summary, data.noise_sigma)
    worst = analysis.worst
    rows = [
        [text_cell(f"residual RMS, least squares [{unit}]"), number_cell(fit["rms"], "fit.rms")],
        [
            text_cell(
                f"sensor noise σ [{unit}] (from {_NOISE_SOURCES.get(noise.get('source'), noise.get('source'))}, "
                f"{_NOISE_KINDS.get(noise.get('kind'), noise.get('kind'))})"
            ),
            number_cell(noise["sigma"], "noise.sigma"),
        ],
        [text_cell("lag-1 autocorrelation of the noise ρ"), number_cell(noise.get("rho"), "noise.rho")],
        [text_cell("quiet samples used for the noise"), number_cell(noise.get("n_quiet"), "noise.n_quiet")],
        [
            text_cell("RMS / σ"),
            number_cell(ratio, "derived.rms_ratio", css="alert" if ratio > RMS_RATIO_LIMIT else None),
        ],
        [
            text_cell("reduced χ²"),
            number_cell(
                fit.get("reduced_chi2"),
                "fit.reduced_chi2",
                css="alert" if (fit.get("reduced_chi2") or 0) > REDUCED_CHI2_LIMIT else None,
            ),
        ],
        [
            text_cell("max error, least squares [% of displacement range]"),
            number_cell(fit.get("max_error_pct"), "fit.max_error_pct"),
        ],
        [
            text_cell("max error, posterior median [% of displacement range]"),
            number_cell(analysis.max_error_pct, "derived.max_error_pct"),
        ],
        [
            text_cell(f"max |error|, posterior median [{unit}]"),
            number_cell(abs(float(analysis.error[worst])), "derived.max_abs_error"),
        ],
        [text_cell("time of the max error [s]"), number_cell(float(record.time[worst]), "derived.time_of_max")],
        [
            text_cell("measured samples inside the 95 % predictive band [%]"),
            number_cell(analysis.inside_predictive_pct, "derived.inside_predictive_pct"),
        ],
        [text_cell("least-squares time [s]"), number_cell(fit.get("seconds"), "fit.seconds")],
    ]
    parts = ['<h2 id="fit-quality-section">2. Fit quality</h2>']
    parts.append(
        html_table("fit-quality", ["quantity", "value"], rows, caption="Fit quality (energised part of the record)")
    )
    parts.append(
        f"<p>“Far above the noise” means RMS &gt; {RMS_RATIO_LIMIT} σ or reduced χ² &gt; {REDUCED_CHI2_LIMIT}. "
        "Least-squares numbers are those of <code>summary.json</code>; the posterior-median numbers are computed here "
        "from the same draws as the bands.</p>"
    )
    in_unit = plots.unit_label(record.input_unit)
    rows, classes = [], {}
    worst_cycle = max(analysis.cycles, key=lambda c: c.max_abs_error) if analysis.cycles else None
    for i, c in enumerate(analysis.cycles):
        key = f"cycles.{c.index}"
        rows.append(
            [
                number_cell(c.index, f"{key}.index"),
                number_cell(c.time_start, f"{key}.time_start", 4),
                number_cell(c.time_end, f"{key}.time_end", 4),
                number_cell(c.input_peak, f"{key}.input_peak", 4),
                number_cell(c.rms, f"{key}.rms", 4),
                number_cell(c.max_abs_error, f"{key}.max_abs_error", 4),
                number_cell(c.max_error_pct, f"{key}.max_error_pct", 4),
                number_cell(c.time_of_max, f"{key}.time_of_max", 4),
            ]
        )
        if c is worst_cycle:
            classes[i] = "worst"
    parts.append(
        html_table(
            "cycle-errors",
            [
                "cycle",
                "start [s]",
                "end [s]",
                f"input peak [{in_unit}]",
                f"RMS [{unit}]",
                f"max |error| [{unit}]",
                "max error [%]",
                "at [s]",
            ],
            rows,
            caption="Error per input cycle (split at the input's minima; posterior-median model; worst cycle "
            "highlighted)",
            row_classes=classes,
        )
    )
    return "\n".join(parts)


#: ArviZ's diagnostics shown in the parameter table (summary.json keys; identify.fitting.posterior.DIAGNOSTICS).
_DIAGNOSTIC_COLUMNS = ("rhat", "ess_bulk", "ess_tail", "mcse_mean")


def _calibration_reading(coverage: dict) -> str:
    """What the bench's measured coverage says about the intervals (calibrated or not, in words)."""
    post, lsq, nominal = coverage["posterior"], coverage["least_squares"], coverage["nominal"]
    short = [(name, value) for name, value in (("posterior", post), ("least-squares", lsq)) if value < nominal - 0.02]
    if not short:
        return "Both are calibrated there; the posterior also carries the non-Gaussian shape and the correlations."
    reading = "; ".join(
        f"a {name} 95 % interval holds the truth about {value:.0%} of the time" for name, value in short
    )
    return (
        f"That is less than nominal: {reading} (most misses in the curved block rho, tau, a0-a3; docs/benchmarks.md)."
    )


def _parameters_html(data: ReportData, analysis: _Analysis, figures_html: str) -> str:
    summary, posterior = data.summary, data.summary["posterior"]
    rows, classes = [], {}
    terms_off = {n: t for t in summary["fit"].get("terms", []) if t.get("pinned") for n in t["parameters"]}
    for i, p in enumerate(summary["parameters"]):
        status = "varies" if p.get("vary") else "pinned by normalisation"
        if p["name"] in terms_off:
            t = terms_off[p["name"]]
            status = (
                f"pinned off: {t['effect']} term '{t['term']}' not supported by the record "
                f"(chi-square {t['delta_chi2']:+.1f} <= BIC {t['penalty']:.1f})"
            )
        key = f"parameters.{p['name']}"
        rows.append(
            [
                text_cell(p["name"]),
                text_cell(plots.unit_label(p.get("unit") or "")),
                number_cell(p.get("table1"), f"{key}.table1"),
                number_cell(p.get("lsq"), f"{key}.lsq"),
                number_cell(p.get("lsq_stderr"), f"{key}.lsq_stderr"),
                number_cell(p.get("median"), f"{key}.median"),
                number_cell(p.get("lo95"), f"{key}.lo95"),
                number_cell(p.get("hi95"), f"{key}.hi95"),
                number_cell(p.get("tau"), f"{key}.tau"),
                number_cell(p.get("ess"), f"{key}.ess"),
                *[number_cell(p.get(k), f"{key}.{k}") for k in _DIAGNOSTIC_COLUMNS],
                text_cell(status),
            ]
        )
        if not p.get("vary"):
            classes[i] = "pinned"
    noise_posterior = summary["noise"].get("posterior")
    if noise_posterior:
        key = "noise.posterior"
        rows.append(
            [
                text_cell("noise σ"),
                text_cell(plots.unit_label(data.record.output_unit)),
                number_cell(None),
                number_cell(summary["noise"]["sigma"], "noise.sigma"),
                number_cell(None),
                number_cell(noise_posterior.get("median"), f"{key}.median"),
                number_cell(noise_posterior.get("lo95"), f"{key}.lo95"),
                number_cell(noise_posterior.get("hi95"), f"{key}.hi95"),
                number_cell(noise_posterior.get("tau"), f"{key}.tau"),
                number_cell(noise_posterior.get("ess"), f"{key}.ess"),
                *[number_cell(noise_posterior.get(k), f"{key}.{k}") for k in _DIAGNOSTIC_COLUMNS],
                text_cell("varies (free noise)"),
            ]
        )
    parts = ['<h2 id="parameters-section">3. Parameters</h2>']
    parts.append(
        html_table(
            "parameters",
            [
                "parameter",
                "unit",
                "Table 1",
                "least squares",
                "± std. error",
                "posterior median",
                "2.5 %",
                "97.5 %",
                "τ [steps]",
                "ESS",
                "R-hat",
                "bulk ESS",
                "tail ESS",
                "MCSE (mean)",
                "status",
            ],
            rows,
            caption="Parameters: the paper's Table 1 (— for effects), least squares, posterior median and 95 % "
            "interval; "
            "ESS = walkers x steps after burn-in / τ; R-hat, bulk and tail ESS and MCSE are ArviZ's "
            "(walkers as chains, after burn-in and thinning)",
            row_classes=classes,
        )
    )
    parts.append(_priors_html(summary.get("priors"), summary["parameters"]))
    parts.append(
        '<p class="note" id="interval-calibration">How far to trust the intervals: on the virtual bench '
        f"({BENCH_COVERAGE['n_records']} seeded records, truth known; docs/method.md) the posterior 95 % "
        f"intervals covered the truth at {BENCH_COVERAGE['posterior']:.3f} ± {BENCH_COVERAGE['posterior_se']:.3f} and "
        f"the least-squares ones (estimate ± 1.96 std. errors) at {BENCH_COVERAGE['least_squares']:.3f} ± "
        f"{BENCH_COVERAGE['least_squares_se']:.3f} (nominal {BENCH_COVERAGE['nominal']:.2f}; ± is the standard error "
        f"across records). {_calibration_reading(BENCH_COVERAGE)} Off the bench, both are conditional on the model: "
        "read them together with the fit-quality section and the diagnosis.</p>"
    )
    converged = bool(posterior.get("converged"))
    rows = [
        [text_cell("walkers"), number_cell(posterior.get("n_walkers"), "posterior.n_walkers")],
        [text_cell("steps"), number_cell(posterior.get("n_steps"), "posterior.n_steps")],
        [text_cell("burn-in discarded [steps]"), number_cell(posterior.get("discard"), "posterior.discard")],
        [text_cell("thin (summaries)"), number_cell(posterior.get("thin"), "posterior.thin")],
        [
            text_cell("mean acceptance fraction"),
            number_cell(posterior.get("acceptance_fraction"), "posterior.acceptance_fraction"),
        ],
        [
            text_cell("largest autocorrelation time τ [steps]"),
            number_cell(posterior.get("tau_max"), "posterior.tau_max"),
        ],
        [
            text_cell("steps / τ_max (need ≥ 50)"),
            number_cell(
                posterior["n_steps"] / posterior["tau_max"] if posterior.get("tau_max") else None,
                "derived.steps_per_tau",
                4,
            ),
        ],
        [text_cell("converged"), number_cell(converged, "posterior.converged", css="ok" if converged else "alert")],
        [text_cell("sampling time [s]"), number_cell(posterior.get("seconds"), "posterior.seconds")],
    ]
    parts.append(html_table("posterior-settings", ["quantity", "value"], rows, caption="Posterior sampling (emcee)"))
    parts.append(figures_html)
    parts.append(_identifiability_html(summary.get("identifiability")))
    return "\n".join(parts)


def _priors_html(priors, parameters) -> str:
    """The priors the posterior used (``summary.json`` ``priors``: defaults and a priors file's)."""
    if not priors:  # a study from before the priors were recorded
        return '<p class="note" id="priors">Priors: not recorded in summary.json (the defaults of docs/method.md).</p>'
    units = {p["name"]: p.get("unit") or "" for p in parameters}
    rows, classes = [], {}
    for i, prior in enumerate(priors):
        given = prior.get("source") != "default"
        rows.append(
            [
                text_cell(prior["name"]),
                text_cell(plots.unit_label(units.get(prior["name"], ""))),
                text_cell(prior["distribution"]),
                number_cell(prior.get("lower")),
                number_cell(prior.get("upper")),
                number_cell(prior.get("mu")),
                number_cell(prior.get("sigma")),
                text_cell(prior.get("source", "")),
            ]
        )
        if given:
            classes[i] = "given-prior"
    return html_table(
        "priors",
        ["parameter", "unit", "distribution", "lower", "upper", "μ", "σ", "source"],
        rows,
        caption="Priors of the sampled parameters: the defaults (uniform, or log-uniform for positive scale "
        "parameters spanning two decades) and those of a priors file (study --priors), on the bounds shown",
        row_classes=classes,
    )


def _identifiability_html(identifiability) -> str:
    parts = ['<h3 id="identifiability">Identifiability</h3>']
    if not identifiability:
        parts.append("<p>No identifiability analysis in <code>summary.json</code>.</p>")
        return "\n".join(parts)
    parts.append(
        "<p>Directions of parameter space the data cannot pin down, from the eigen-analysis of the Fisher information "
        "(relative parameter changes) at the least-squares optimum. Exact degeneracies leave the output unchanged and "
        "are removed by the normalisation (the pinned parameters); near-degenerate combinations stay free and show up "
        "as wide, correlated intervals. Relative std. = 1/√eigenvalue: how well the combination is known.</p>"
    )
    condition = identifiability.get("condition_number")
    if condition is not None:
        parts.append(
            f'<p>Condition number of the scaled Fisher information: <span data-key="identifiability.condition_number">'
            f"{number_text(condition)}</span>.</p>"
        )
    normalisation = identifiability.get("normalisation") or {}
    rows = [[text_cell(k), number_cell(v, f"identifiability.normalisation.{k}")] for k, v in normalisation.items()]
    parts.append(
        html_table(
            "identifiability-normalisation",
            ["pinned parameter", "value"],
            rows or [[text_cell("(none)"), text_cell("")]],
            caption="Normalisation used",
        )
    )
    for kind, caption in (("exact", "Exact degeneracies"), ("near", "Near-degenerate combinations")):
        rows = []
        for i, item in enumerate(identifiability.get(kind) or []):
            item = item if isinstance(item, dict) else {"combination": item}
            key = f"identifiability.{kind}.{i}"
            rows.append(
                [
                    number_cell(item.get("eigenvalue"), f"{key}.eigenvalue"),
                    number_cell(item.get("relative_std"), f"{key}.relative_std"),
                    text_cell(_combination_text(item.get("combination"))),
                ]
            )
        parts.append(
            html_table(
                f"identifiability-{kind}",
                ["eigenvalue", "relative std.", "combination (weights)"],
                rows or [[text_cell("(none)"), text_cell(""), text_cell("")]],
                caption=caption,
            )
        )
    return "\n".join(parts)


def _diagnosis_html(data: ReportData) -> str:
    """The diagnosis hook: ``diagnosis.json``'s verdict and ranking, and every ``diagnosis/*.png``."""
    parts = ['<h2 id="diagnosis">4. Diagnosis</h2>']
    diagnosis = data.diagnosis
    figure_dir = data.directory / DIAGNOSIS_FIGURES
    pngs = sorted(figure_dir.glob("*.png")) if figure_dir.is_dir() else []
    if diagnosis is None and not pngs:
        parts.append(
            f"<p>No diagnosis in this folder (<code>{DIAGNOSIS_FILE}</code> absent). The diagnosis "
            "(<code>python -m identify diagnose</code>) tells which physical effect the model misses when the residual "
            "is above the noise.</p>"
        )
        return "\n".join(parts)
    if diagnosis is not None:
        status = str(diagnosis.get("status", "unknown"))
        unit = plots.unit_label(data.record.output_unit)
        missing = diagnosis.get("missing")
        tied = " or ".join(f"<b><code>{escape(str(name))}</code></b>" for name in diagnosis.get("tied") or [])
        verdict = {
            "adequate": "the residual is consistent with the noise; nothing to add.",
            "missing_effect": f"the model misses the effect <b><code>{escape(str(missing))}</code></b>; add it with "
            f"<code>--effects {escape(str(missing))}</code>.",
            "tied": f"several explanations repair the model and this record does not separate them: {tied}; "
            "another record (a hold at constant current, a quiet end) or a joint diagnosis can.",
            "unexplained": "structure remains in the residual that no effect of the library explains.",
        }.get(status, "")
        css = "ok" if status == "adequate" else "alert"
        label = STATUS_LABELS.get(status, status.replace("_", " "))
        parts.append(f'<div class="{css}" id="diagnosis-verdict">Verdict: <b>{escape(label)}</b>: {verdict}</div>')
        ranking = diagnosis.get("ranking") or []
        if ranking:
            known = [k for k in _RANKING_HEADERS if any(k in r for r in ranking)]
            columns = known + sorted({k for r in ranking for k in r} - set(known))
            rows = []
            for r in ranking:
                row = []
                for column in columns:
                    value = r.get(column)
                    if isinstance(value, (int, float)) and not isinstance(value, bool):
                        row.append(number_cell(value, f"diagnosis.{r.get('effect')}.{column}"))
                    elif column == "parameters" and isinstance(value, dict):
                        row.append(_effect_parameters_cell(value))
                    else:
                        row.append(text_cell(value))
                rows.append(row)
            parts.append(
                html_table(
                    "diagnosis-ranking",
                    [_RANKING_HEADERS.get(c, c.replace("_", " ")).format(unit=unit) for c in columns],
                    rows,
                    caption="Candidate effects, best first (each added to the model and refitted; the BIC gain is "
                    "the fall in the Bayesian information criterion, which charges each added parameter)",
                )
            )
    for path in pngs:
        alt = f"Diagnosis: {path.stem.replace('_', ' ')}"  # "record1_residual_time" -> words
        parts.append(
            embedded_figure(f"diagnosis-{path.stem}", alt, path.read_bytes(), f"From {DIAGNOSIS_FIGURES}/{path.name}.")
        )
    return "\n".join(parts)


def _effect_parameters_cell(parameters: dict) -> str:
    """A ranking entry's fitted effect parameters as a readable ``name = value unit`` list.

    ``parameters`` is ``{parameter name: value}`` (``diagnosis.json``'s ranking entry); the
    unit comes from the effect library (:data:`model.EFFECTS`), blank when unknown.
    """
    from model import EFFECTS

    units = {p.name: p.unit for cls in EFFECTS.values() for p in cls.parameters}
    if not parameters:
        return text_cell("—")
    items = []
    for name, value in parameters.items():
        unit = units.get(name, "")
        text = f"<code>{escape(str(name))}</code> = {number_text(value, 4)}" + (
            f" {escape(plots.unit_label(unit))}" if unit else ""
        )
        items.append(f"<li>{text}</li>")
    return '<td class="parameters"><ul>' + "".join(items) + "</ul></td>"


def _provenance_html(data: ReportData, analysis: _Analysis, seconds: float) -> str:
    converged = bool(data.summary["posterior"].get("converged"))
    rows = [
        [
            text_cell("convergence"),
            text_cell("converged" if converged else "NOT CONVERGED", css="ok" if converged else "alert"),
        ]
    ]
    for name, value in _flatten(data.manifest):
        if name == "finished" and value is None:  # the run is closed after its report is written
            value = "at the end of this run (the report is written before the manifest is closed)"
        rows.append([text_cell(name), text_cell(value)])
    rows.append(
        [
            text_cell("record stored in the results folder"),
            text_cell(f"{results.FILES['data']} (sha256 {data.record.sha256})"),
        ]
    )
    rows.append([text_cell("report: posterior draws for the bands"), number_cell(analysis.bands.n_draws)])
    rows.append([text_cell("report: generated in [s]"), number_cell(seconds, digits=3)])
    rows.append([text_cell("report: generated at (UTC)"), text_cell(results.now_iso())])
    return '<h2 id="provenance-section">5. Provenance</h2>\n' + html_table(
        "provenance", ["item (manifest key)", "value"], rows, caption="Provenance (the results folder's manifest)"
    )


def _page(data: ReportData, analysis: _Analysis, figure_html: dict, seconds: float) -> str:
    record = data.record
    source = data.manifest.get("data", {}).get("file") if isinstance(data.manifest.get("data"), dict) else None
    title = f"Identification report — {Path(str(source or record.source)).name}"
    effects = ", ".join(data.model.effect_names) or "none"
    parts = [
        f"<p>Model: GPI with {data.model.n_operators} play operators, reading "
        f"<code>{escape(data.model.reading)}</code>, "
        f"effects: {escape(effects)}. Record: {len(record.time)} samples over "
        f"{record.time[-1] - record.time[0]:.4g} s. Results folder: "
        f"<code>{escape(str(data.directory))}</code>.</p>",
        _glance_html(data, analysis),
        figure_html.get("comparison-section", ""),
        '<h2 id="measurement">1. Measurement vs model</h2>',
        *(figure_html[s] for s in ("fig5_input", "fig6_displacement", "fig6_zoom", "fig7_error", "fig8_loops")),
        _fit_quality_html(data, analysis),
        _parameters_html(data, analysis, "\n".join(figure_html[s] for s in ("corner", "traces", "autocorrelation"))),
        _diagnosis_html(data),
        _provenance_html(data, analysis, seconds),
    ]
    return html_page(title, parts)


# --------------------------------------------------------------------------------------
# before and after: the comparison with an earlier study (study --compare)
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Comparison:
    """The least-squares error of an earlier study of the same record and of this one.

    Attributes
    ----------
    earlier : Path
        The earlier results folder.
    found : str
        How it was named (``"given (--compare)"`` or ``"found by manifest"``).
    effects_before, effects_after : tuple of str
        The effects of the two models.
    model_before, model_after : ndarray, shape (T,)
        The two least-squares model curves [output unit].
    error_before, error_after : ndarray, shape (T,)
        Measurement minus each curve [output unit].
    rms_before, rms_after : float
        RMS of the errors over the energised samples [output unit].
    max_pct_before, max_pct_after : float
        Largest absolute error as % of the measured displacement range (energised samples).
    cycles_before, cycles_after : list of CycleError
        Per-cycle errors (the same cycles).
    """

    earlier: Path
    found: str
    effects_before: tuple
    effects_after: tuple
    model_before: np.ndarray
    model_after: np.ndarray
    error_before: np.ndarray
    error_after: np.ndarray
    rms_before: float
    rms_after: float
    max_pct_before: float
    max_pct_after: float
    cycles_before: list
    cycles_after: list

    @property
    def improved_cycles(self) -> list[int]:
        """1-based numbers of the cycles whose RMS error fell."""
        return [b.index for b, a in zip(self.cycles_before, self.cycles_after) if a.rms < b.rms]


def load_comparison(data: ReportData, analysis: _Analysis) -> Comparison | str | None:
    """The :class:`Comparison` named by ``DIR/comparison.json``; None without that file; a
    sentence (plain text) when the earlier folder cannot be compared (gone, another record)."""
    path = data.directory / COMPARISON_FILE
    if not path.exists():
        return None
    named = results.read_json(path)
    earlier = Path(str(named.get("earlier")))
    try:
        before = results.load_results(earlier)
    except (OSError, KeyError, ValueError) as exc:
        return f"The earlier study {earlier} named in {COMPARISON_FILE} cannot be read ({exc})."
    if before.record.sha256 != data.record.sha256:
        return f"The earlier study {earlier} holds another record (its SHA-256 differs): not compared."
    record = data.record
    time, current, measured = (np.asarray(a, dtype=float) for a in (record.time, record.current, record.displacement))
    curves = []
    for fit in (before.fit, data.fit):
        curve, valid = fit.model.evaluate(fit.theta[None, :], time, current)
        if not valid[0]:
            return f"The earlier study {earlier}: its least-squares model gives a non-finite output on this record."
        curves.append(np.asarray(curve[0], dtype=float))
    energised, span = data.energised, analysis.displacement_range
    errors = [measured - curve for curve in curves]
    cycles = [cycle_errors(time, current, e, energised, analysis.branch_list, span) for e in errors]
    rms = [float(np.sqrt(np.mean(e[energised] ** 2))) for e in errors]
    worst = [float(100.0 * np.max(np.abs(e[energised])) / span) for e in errors]
    return Comparison(
        earlier=earlier,
        found=str(named.get("found") or ""),
        effects_before=tuple(before.fit.model.effect_names),
        effects_after=tuple(data.model.effect_names),
        model_before=curves[0],
        model_after=curves[1],
        error_before=errors[0],
        error_after=errors[1],
        rms_before=rms[0],
        rms_after=rms[1],
        max_pct_before=worst[0],
        max_pct_after=worst[1],
        cycles_before=cycles[0],
        cycles_after=cycles[1],
    )


def _effects_text(effects) -> str:
    return "GPI + " + " + ".join(effects) if effects else "GPI alone"


@plots.styled
def comparison_figure(data: ReportData, comparison: Comparison):
    """Three panels: the two models' hysteresis loops over the measurement, the two errors vs
    time, and each cycle's RMS error before and after (legends below the axes, off the data)."""
    record = data.record
    time, current, measured = (np.asarray(a, dtype=float) for a in (record.time, record.current, record.displacement))
    before, after = _effects_text(comparison.effects_before), _effects_text(comparison.effects_after)
    fig = plots.new_figure(14, 4.8)
    loops, errors, cycles = fig.subplots(1, 3)
    shown = data.energised
    loops.plot(current[shown], measured[shown], color="0.55", lw=0.8, label="measurement")
    loops.plot(current[shown], comparison.model_before[shown], color="tab:blue", lw=1.0, ls="--", label=before)
    loops.plot(current[shown], comparison.model_after[shown], color="tab:red", lw=1.0, label=after)
    loops.set_xlabel(plots.axis_label(record.input_name, record.input_unit))
    loops.set_ylabel(plots.axis_label(record.output_name, record.output_unit))
    loops.set_title("Hysteresis loops")
    errors.plot(time, comparison.error_after, color="tab:red", lw=0.6, label=after)
    errors.plot(
        time, comparison.error_before, color="tab:blue", lw=0.6, alpha=0.8, label=before
    )  # on top: it is larger
    errors.set_xlabel(plots.axis_label("time", "s"))
    errors.set_ylabel(plots.axis_label("measurement − model", record.output_unit))
    errors.set_title("Error vs time")
    index = np.array([c.index for c in comparison.cycles_before])
    cycles.bar(index - 0.2, [c.rms for c in comparison.cycles_before], 0.4, color="tab:blue", label=before)
    cycles.bar(index + 0.2, [c.rms for c in comparison.cycles_after], 0.4, color="tab:red", label=after)
    cycles.set_xlabel("input cycle")
    cycles.set_ylabel(plots.axis_label("RMS error", record.output_unit))
    cycles.set_title("RMS error per cycle")
    cycles.xaxis.get_major_locator().set_params(integer=True)
    for ax in (loops, errors, cycles):
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3 if ax is loops else 2, frameon=False)
    return fig


def _comparison_html(data: ReportData, comparison, figure_html: str) -> str:
    """The section "Before and after": the error of the earlier study and of this one."""
    if comparison is None:
        return ""
    parts = ['<h2 id="comparison">Before and after</h2>']
    if isinstance(comparison, str):
        parts.append(f'<div class="note" id="comparison-missing">{escape(comparison)}</div>')
        return "\n".join(parts)
    unit = plots.unit_label(data.record.output_unit)
    before, after = _effects_text(comparison.effects_before), _effects_text(comparison.effects_after)
    improved = comparison.improved_cycles
    n_cycles = len(comparison.cycles_before)
    falls = comparison.rms_after < comparison.rms_before
    parts.append(
        f'<p id="comparison-summary">The same record studied before with <b>{escape(before)}</b> (<code>'
        f"{escape(str(comparison.earlier))}</code>, {escape(comparison.found)}) and now with <b>{escape(after)}</b>: "
        f"the least-squares RMS error {'falls' if falls else 'does not fall'} from "
        f"{number_text(comparison.rms_before, 4)} to {number_text(comparison.rms_after, 4)} {escape(unit)} "
        f"(the sensor noise σ is {number_text(data.noise_sigma, 4)} {escape(unit)}), and {len(improved)} of "
        f"{n_cycles} input cycles improved"
        + (f" (cycles {', '.join(map(str, improved))})" if improved and len(improved) < n_cycles else "")
        + ".</p>"
    )
    rows = [
        [
            text_cell(f"RMS error [{unit}]"),
            number_cell(comparison.rms_before, "comparison.rms_before", 4),
            number_cell(comparison.rms_after, "comparison.rms_after", 4),
        ],
        [
            text_cell("RMS error / σ"),
            number_cell(comparison.rms_before / data.noise_sigma, "comparison.rms_ratio_before", 4),
            number_cell(comparison.rms_after / data.noise_sigma, "comparison.rms_ratio_after", 4),
        ],
        [
            text_cell("max error [% of the displacement range]"),
            number_cell(comparison.max_pct_before, "comparison.max_pct_before", 4),
            number_cell(comparison.max_pct_after, "comparison.max_pct_after", 4),
        ],
        [
            text_cell("input cycles with a smaller RMS error"),
            text_cell(""),
            text_cell(f"{len(improved)} of {n_cycles}"),
        ],
    ]
    parts.append(
        html_table(
            "comparison-table",
            ["least squares, energised samples", f"before: {before}", f"after: {after}"],
            rows,
            caption="The error before and after",
        )
    )
    parts.append(figure_html)
    return "\n".join(parts)


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
        holds fewer samples after burn-in). With 200 the 2.5 % quantile lies between the
        5th and 6th draw: enough for a band, and one model call of 200 rows is cheap.
    rng : numpy.random.Generator, optional
        Chooses the draws and the corner-plot samples; default
        ``numpy.random.default_rng(0)``, so the same folder gives the same page.

    Returns
    -------
    Path
        ``DIR/report.html``.

    Raises
    ------
    ResultsError
        The folder is incomplete or inconsistent (the message names the file).
    ValueError
        ``n_draws`` is not an integer >= 2.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 2:
        raise ValueError(f"n_draws must be an integer >= 2, got {n_draws!r}")
    started = _time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    from .joint_report import is_joint_folder, write_joint_report

    if is_joint_folder(result_dir):  # a study of several records: its own page
        return write_joint_report(result_dir, rng=rng)
    data = load_report_data(result_dir)
    analysis = analyse_report(data, int(n_draws), rng)
    figure_html = {}
    for stem, figure, caption in report_figures(data, analysis, rng):
        png = png_bytes(figure, DPI.get(stem, DPI["default"]))
        atomic_write_bytes(data.directory / f"{stem}.png", png)
        figure_html[stem] = embedded_figure(stem, FIGURES[stem], png, caption)
    comparison = load_comparison(data, analysis)
    if isinstance(comparison, Comparison):
        png = png_bytes(comparison_figure(data, comparison), DPI["default"])
        atomic_write_bytes(data.directory / "comparison.png", png)
        caption = (
            "Left: the loops of the two least-squares models over the measurement. Middle: measurement minus "
            "each model. Right: each input cycle's RMS error (cycles split at the input's minima)."
        )
        figure_html["comparison"] = embedded_figure("comparison", COMPARISON_FIGURE["comparison"], png, caption)
    figure_html["comparison-section"] = _comparison_html(data, comparison, figure_html.get("comparison", ""))
    page = _page(data, analysis, figure_html, _time.perf_counter() - started)
    path = data.directory / results.FILES["report"]
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
