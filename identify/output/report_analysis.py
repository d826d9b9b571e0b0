"""What the study's report computes from a results folder, before any figure or HTML.

Reading (:func:`load_report_data`: the folder through :func:`identify.output.results.load_results`;
:func:`read_chain`: ``chain.h5`` thinned to at most :data:`MAX_CHAIN_ROWS` rows), posterior
draws pushed through the model in one vectorised call (:func:`model_bands`: the pointwise
median, 95 % credible and predictive bands), the record split at the input reversals into
branches and at the input's minima into cycles (:func:`branches`, :func:`cycle_errors`), the
zoom on the worst region (:func:`zoom_samples`, :func:`loop_zoom_box`), the autocorrelation
time against chain length (:func:`autocorrelation_curve`), and all of it for one page
(:func:`analyse_report` -> :class:`ReportAnalysis`). Used by :mod:`identify.output.report`
(figures and page), :mod:`identify.output.report_sections` (the HTML sections) and
:mod:`identify.output.use_report`. Nothing here draws or writes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.reversals import Reversals, find_reversals
from ..fitting.noise import energised_mask
from ..fitting.posterior import ChainBackend, autocorrelation_times
from . import results
from .bands import mixture_quantile
from .diagnosis_files import DIAGNOSIS_FILE

__all__ = [
    "load_report_data",
    "read_chain",
    "posterior_draws",
    "model_bands",
    "branches",
    "cycle_errors",
    "zoom_samples",
    "loop_zoom_box",
    "autocorrelation_curve",
    "analyse_report",
    "ReportData",
    "ChainSample",
    "PosteriorDraws",
    "ModelBands",
    "Branch",
    "CycleError",
    "ReportAnalysis",
    "ResultsError",
    "NOISE_COORDINATE",
    "MAX_CHAIN_ROWS",
    "ZOOM_BAND_MULTIPLE",
]

#: Name of the sampled log noise sigma (last chain column when the noise is free).
NOISE_COORDINATE = "noise_log_sigma"
#: At most this many stored chain rows are read (the chain is thinned to fit).
MAX_CHAIN_ROWS = 4000
#: The zoom window is wide enough for the output to move this many predictive half-widths.
ZOOM_BAND_MULTIPLE = 15.0


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
class ReportAnalysis:
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


def analyse_report(data: ReportData, n_draws: int, rng: np.random.Generator) -> ReportAnalysis:
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
    return ReportAnalysis(
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
