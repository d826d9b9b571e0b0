r"""Where the model fails: statistics of a residual, on plain arrays.

Everything here is pure (arrays in, dataclasses out; no I/O, no plots, no model
calls), so the diagnosis (:mod:`identify.diagnosis.diagnose`), the figures
(:mod:`identify.output.diagnosis_plots`) and the tests share one set of numbers.

What is computed
----------------
*Location of the error.* Input reversals (peaks and troughs of the drive, found by a
zig-zag rule that ignores wiggles smaller than ``min_swing``), the branch each sample
lies on (rising/falling between reversals), the input rate, the time since the last
reversal, and the residual binned against each of them; the residual level at every
peak and trough; RMS, max and mean error cycle by cycle (trough to trough).

*Is it noise?* The noise reference of the quiet segment and the tests (``variance``,
``ljung_box``, ``low_frequency``, and ``level`` where the model's output is given) are in
:mod:`identify.diagnosis.noise_tests`; :func:`residual_profile` runs them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..data.reversals import Reversals, as_1d, branch_direction, find_reversals, input_rate, time_since_reversal
from .noise_tests import (
    ARNoise,
    StatTest,
    autocorrelation,
    fit_ar_noise,
    level_test,
    ljung_box,
    low_frequency_test,
    variance_ratio_test,
)

__all__ = [
    "BinnedResidual",
    "binned_residual",
    "CycleStatistics",
    "cycle_statistics",
    "ExtremumLevels",
    "extremum_levels",
    "autocorrelation",
    "ARNoise",
    "fit_ar_noise",
    "StatTest",
    "ljung_box",
    "variance_ratio_test",
    "low_frequency_test",
    "level_test",
    "ResidualProfile",
    "residual_profile",
    "noise_tests",
]


def _as_mask(name, mask, size):
    if mask is None:
        return np.ones(size, dtype=bool)
    m = np.asarray(mask)
    if m.dtype != bool or m.shape != (size,):
        raise ValueError(f"{name} must be a boolean array of shape ({size},), got {m.dtype} {m.shape}")
    return m


# -- binned views -------------------------------------------------------------------------


@dataclass(frozen=True)
class BinnedResidual:
    """Residual statistics in bins of some variable ``x``.

    Attributes
    ----------
    edges : ndarray, shape (B+1,)
        Bin edges in the units of ``x``.
    centres : ndarray, shape (B,)
    count : ndarray of int, shape (B,)
    mean : ndarray, shape (B,)
        Mean residual [output units]; NaN where ``count == 0``.
    rms : ndarray, shape (B,)
        RMS residual; NaN where ``count == 0``.
    sem : ndarray, shape (B,)
        Standard error of the mean (sample sd / sqrt(count)); NaN where ``count < 2``.
    """

    edges: np.ndarray
    centres: np.ndarray
    count: npt.NDArray[np.integer]
    mean: np.ndarray
    rms: np.ndarray
    sem: np.ndarray

    def to_dict(self) -> dict:
        return {
            k: [None if not np.isfinite(x) else float(x) for x in getattr(self, k)]
            for k in ("edges", "centres", "mean", "rms", "sem")
        } | {"count": [int(c) for c in self.count]}


def binned_residual(x, residual, n_bins=20, mask=None, edges=None) -> BinnedResidual:
    """Mean, RMS and standard error of ``residual`` in bins of ``x``.

    Parameters
    ----------
    x : array_like, shape (T,)
        The variable to bin by (current, rate, time since reversal, ...). NaN entries
        are left out.
    residual : array_like, shape (T,)
        Data minus model.
    n_bins : int, default 20
        Equal-width bins over the selected ``x`` range (ignored when ``edges`` is given).
    mask : array_like of bool, shape (T,), optional
        Samples to use.
    edges : array_like, shape (B+1,), optional
        Explicit increasing bin edges.
    """
    r = as_1d("residual", residual)
    xv = np.asarray(x, dtype=float)
    if xv.shape != r.shape:
        raise ValueError(f"x has shape {xv.shape}, residual {r.shape}: they must match")
    use = _as_mask("mask", mask, r.size) & np.isfinite(xv)
    if edges is None:
        if int(n_bins) < 1:
            raise ValueError(f"n_bins must be >= 1, got {n_bins}")
        if use.any():
            lo, hi = float(xv[use].min()), float(xv[use].max())
        else:
            lo, hi = 0.0, 1.0
        if hi <= lo:
            hi = lo + 1.0
        edges = np.linspace(lo, hi, int(n_bins) + 1)
    edges = np.asarray(edges, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or not (np.diff(edges) > 0).all():
        raise ValueError("edges must be a 1-D increasing array with at least 2 entries")
    nb = edges.size - 1
    which = np.clip(np.searchsorted(edges, xv[use], side="right") - 1, 0, nb - 1)
    inside = (xv[use] >= edges[0]) & (xv[use] <= edges[-1])
    which, rr = which[inside], r[use][inside]
    count = np.bincount(which, minlength=nb)
    total = np.bincount(which, weights=rr, minlength=nb)
    total_sq = np.bincount(which, weights=rr * rr, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        rms = np.where(count > 0, np.sqrt(total_sq / np.maximum(count, 1)), np.nan)
        var = (total_sq - count * np.nan_to_num(mean) ** 2) / np.maximum(count - 1, 1)
        sem = np.where(count > 1, np.sqrt(np.maximum(var, 0.0) / np.maximum(count, 1)), np.nan)
    return BinnedResidual(edges, 0.5 * (edges[:-1] + edges[1:]), count, mean, rms, sem)


# -- cycle by cycle ---------------------------------------------------------------------


@dataclass(frozen=True)
class CycleStatistics:
    """Error statistics per drive cycle (trough to next trough).

    Attributes
    ----------
    start, stop : ndarray of int, shape (C,)
        Sample range ``[start, stop)`` of each cycle.
    t_start, t_stop : ndarray, shape (C,)
        [s].
    rms, max_abs, mean : ndarray, shape (C,)
        Residual RMS, max absolute value and mean over the cycle [output units].
    max_error_pct : ndarray, shape (C,)
        ``max_abs`` as % of the measured output range of the whole record.
    """

    start: np.ndarray
    stop: np.ndarray
    t_start: np.ndarray
    t_stop: np.ndarray
    rms: np.ndarray
    max_abs: np.ndarray
    mean: np.ndarray
    max_error_pct: np.ndarray

    def __len__(self):
        return int(self.start.size)

    def to_dict(self) -> dict:
        return {
            k: [float(x) for x in getattr(self, k)]
            for k in ("t_start", "t_stop", "rms", "max_abs", "mean", "max_error_pct")
        }


def cycle_statistics(time, residual, reversals: Reversals, output_range) -> CycleStatistics:
    """RMS, max and mean error for each trough-to-trough cycle.

    Parameters
    ----------
    time, residual : array_like, shape (T,)
    reversals : Reversals
    output_range : float
        Measured displacement range (max - min) [output units], > 0, for the % figure.
    """
    t = as_1d("time", time)
    r = as_1d("residual", residual, t.size)
    if not (np.isfinite(output_range) and output_range > 0):
        raise ValueError(f"output_range must be a positive number, got {output_range!r}")
    troughs = reversals.troughs
    starts, stops = troughs[:-1], troughs[1:]
    if starts.size == 0 and len(reversals) > 0:  # less than one full cycle: use what there is
        starts, stops = reversals.index[:1], np.array([t.size])
    rms, max_abs, mean = [], [], []
    for a, b in zip(starts, stops):
        seg = r[a:b]
        rms.append(float(np.sqrt(np.mean(seg**2))))
        max_abs.append(float(np.abs(seg).max()))
        mean.append(float(seg.mean()))
    starts = np.asarray(starts, dtype=int)
    stops = np.asarray(stops, dtype=int)
    max_abs_arr = np.asarray(max_abs, dtype=float)
    return CycleStatistics(
        starts,
        stops,
        t[starts] if starts.size else np.zeros(0),
        t[np.minimum(stops, t.size - 1)] if stops.size else np.zeros(0),
        np.asarray(rms, dtype=float),
        max_abs_arr,
        np.asarray(mean, dtype=float),
        100.0 * max_abs_arr / float(output_range),
    )


@dataclass(frozen=True)
class ExtremumLevels:
    """Residual level at each reversal (the paper: "error peaks occur for input signal returns").

    Attributes
    ----------
    index : ndarray of int, shape (R,)
    time : ndarray, shape (R,) [s]
    kind : ndarray of int, shape (R,)
        ``+1`` peak, ``-1`` trough.
    current : ndarray, shape (R,)
        Drive at the reversal [A].
    residual : ndarray, shape (R,)
        Mean residual over ``index - half_window .. index + half_window``.
    """

    index: npt.NDArray[np.integer]
    time: np.ndarray
    kind: npt.NDArray[np.integer]
    current: np.ndarray
    residual: np.ndarray

    def to_dict(self) -> dict:
        return {
            "time": [float(x) for x in self.time],
            "kind": ["peak" if k > 0 else "trough" for k in self.kind],
            "current": [float(x) for x in self.current],
            "residual": [float(x) for x in self.residual],
        }


def extremum_levels(time, current, residual, reversals: Reversals, half_window=2) -> ExtremumLevels:
    """Residual averaged over a short window around every peak and trough.

    Parameters
    ----------
    time, current, residual : array_like, shape (T,)
    reversals : Reversals
    half_window : int, default 2
        Samples either side of the reversal averaged (5 samples by default: less
        noise, still local).
    """
    t = as_1d("time", time)
    v = as_1d("current", current, t.size)
    r = as_1d("residual", residual, t.size)
    if int(half_window) < 0:
        raise ValueError(f"half_window must be >= 0, got {half_window}")
    h = int(half_window)
    levels = np.array([r[max(k - h, 0) : k + h + 1].mean() for k in reversals.index], dtype=float)
    idx = reversals.index
    return ExtremumLevels(idx, t[idx], reversals.kind, v[idx], levels)


# -- correlation and the noise reference ------------------------------------------------


@dataclass(frozen=True)
class ResidualProfile:
    """Where a fit fails, and whether its residual is noise: everything for the report.

    Attributes
    ----------
    time, current, residual : ndarray, shape (T,)
        [s], [A], data - model [output units].
    energised : ndarray of bool, shape (T,)
        Samples after the quiet segment.
    reversals : Reversals
    direction : ndarray of int8, shape (T,)
        ``+1`` rising, ``-1`` falling, ``0`` before the first reversal.
    rate : ndarray, shape (T,)
        Input rate [A/s].
    since_reversal : ndarray, shape (T,)
        [s], NaN before the first reversal.
    rising, falling : BinnedResidual
        Residual vs current on each branch (energised samples).
    by_rate, by_since_reversal : BinnedResidual
    cycles : CycleStatistics
    extrema : ExtremumLevels
    lags : ndarray of int, shape (M+1,)
    residual_acf : ndarray, shape (M+1,)
        Sample autocorrelation of the energised residual.
    quiet_acf : ndarray, shape (M+1,)
        Sample autocorrelation of the (detrended) quiet segment.
    noise : ARNoise
        Noise model of the quiet segment.
    tests : dict of str -> StatTest
        ``variance``, ``ljung_box``, ``low_frequency`` over the whole record; ``level`` where
        the model's output is given.
    rms, max_abs, max_error_pct : float
        Over the energised part; % of the measured output range.
    by_level : BinnedResidual or None
        Residual vs the model's output, in bins of equal count (energised samples); None
        without the model's output.
    """

    time: np.ndarray
    current: np.ndarray
    residual: np.ndarray
    energised: np.ndarray
    reversals: Reversals
    direction: np.ndarray
    rate: np.ndarray
    since_reversal: np.ndarray
    rising: BinnedResidual
    falling: BinnedResidual
    by_rate: BinnedResidual
    by_since_reversal: BinnedResidual
    cycles: CycleStatistics
    extrema: ExtremumLevels
    lags: np.ndarray
    residual_acf: np.ndarray
    quiet_acf: np.ndarray
    noise: ARNoise
    tests: dict
    rms: float
    max_abs: float
    max_error_pct: float
    by_level: BinnedResidual | None = None

    @property
    def structure_rms(self) -> float:
        """RMS of the slowly varying (non-noise) part of the residual [output units]."""
        return float(np.sqrt(self.tests["low_frequency"].structure_variance))

    def to_dict(self) -> dict:
        """JSON-ready summary (binned and per-cycle figures, tests; not the raw arrays)."""
        return {
            "rms": self.rms,
            "max_abs": self.max_abs,
            "max_error_pct": self.max_error_pct,
            "structure_rms": self.structure_rms,
            "noise": self.noise.to_dict(),
            "tests": {k: t.to_dict() for k, t in self.tests.items()},
            "n_reversals": len(self.reversals),
            "cycles": self.cycles.to_dict(),
            "extrema": self.extrema.to_dict(),
            "rising": self.rising.to_dict(),
            "falling": self.falling.to_dict(),
            "by_rate": self.by_rate.to_dict(),
            "by_since_reversal": self.by_since_reversal.to_dict(),
            **({} if self.by_level is None else {"by_level": self.by_level.to_dict()}),
            "acf": {
                "lags": [int(k) for k in self.lags],
                "residual": [float(x) for x in self.residual_acf],
                "quiet": [float(x) for x in self.quiet_acf],
            },
        }


def residual_profile(
    time,
    current,
    residual,
    quiet,
    *,
    output_range,
    noise: ARNoise | None = None,
    block_seconds=0.2,
    n_lags=40,
    n_bins=20,
    n_fitted=0,
    min_swing=None,
    level=None,
) -> ResidualProfile:
    """Compute every "where it fails" statistic of a residual.

    Parameters
    ----------
    time, current, residual : array_like, shape (T,)
        [s], [A], data - model [output units].
    quiet : slice or None
        The unenergised segment (noise reference), at least 20 samples. None: the
        record has none; ``noise`` must then be given (e.g. white noise of a
        user-given sigma), every sample counts as energised and the "quiet"
        autocorrelation is the noise model's.
    output_range : float
        Measured output range [output units] for % figures.
    noise : ARNoise, optional
        Noise model; by default fitted to ``residual[quiet]`` (detrended).
    block_seconds, n_lags, n_fitted, min_swing : optional
        Passed to :func:`noise_tests` and :func:`find_reversals`; ``n_bins`` (20): binned views.
    level : array_like, shape (T,), optional
        The model's output [output units]: adds the ``level`` test and the view by level.
    """
    t = as_1d("time", time)
    v = as_1d("current", current, t.size)
    r = as_1d("residual", residual, t.size)
    q_start, q_stop = _quiet_bounds(quiet, noise, t.size)
    if noise is None:
        noise = fit_ar_noise(r[q_start:q_stop])
    energised = np.zeros(t.size, dtype=bool)
    energised[q_stop:] = True
    if energised.sum() < 20:
        raise ValueError("fewer than 20 energised samples after the quiet segment")
    reversals = find_reversals(v, min_swing)
    direction = branch_direction(t.size, reversals)
    rate = input_rate(t, v)
    since = time_since_reversal(t, reversals)
    cur_edges = np.linspace(float(v[energised].min()), float(v[energised].max()) + 1e-12, n_bins + 1)
    r_en = r[energised]
    lags, residual_acf, quiet_acf = _autocorrelations(r_en, r[q_start:q_stop], noise, n_lags)
    max_abs = float(np.abs(r_en).max())
    level_en = None if level is None else as_1d("level", level, t.size)[energised]
    return ResidualProfile(
        t,
        v,
        r,
        energised,
        reversals,
        direction,
        rate,
        since,
        binned_residual(v, r, mask=energised & (direction > 0), edges=cur_edges),
        binned_residual(v, r, mask=energised & (direction < 0), edges=cur_edges),
        binned_residual(rate, r, n_bins=n_bins, mask=energised),
        binned_residual(since, r, n_bins=n_bins, mask=energised),
        cycle_statistics(t, r, reversals, output_range),
        extremum_levels(t, v, r, reversals),
        lags,
        residual_acf,
        quiet_acf,
        noise,
        noise_tests(t, r, r_en, noise, n_fitted=n_fitted, n_lags=n_lags, block_seconds=block_seconds, level=level_en),
        float(np.sqrt(np.mean(r_en**2))),
        max_abs,
        100.0 * max_abs / float(output_range),
        None if level_en is None else _binned_by_level(level_en, r_en, n_bins),
    )


def _binned_by_level(level, residual, n_bins) -> BinnedResidual:
    """The residual in ``n_bins`` bins of the model's output holding equal numbers of samples."""
    edges = np.unique(np.quantile(level, np.linspace(0.0, 1.0, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([edges[0], edges[0] + 1.0])
    return binned_residual(level, residual, edges=edges)


def _quiet_bounds(quiet, noise, size: int) -> tuple[int, int]:
    """``(start, stop)`` of the quiet segment (``(0, 0)`` for None, which needs ``noise``)."""
    if quiet is None:
        if noise is None:
            raise ValueError("without a quiet segment the noise model must be given (noise=ARNoise(...))")
        return 0, 0
    if not isinstance(quiet, slice):
        raise ValueError(f"quiet must be a slice of the record or None, got {type(quiet).__name__}")
    start, stop, _ = quiet.indices(size)
    if stop - start < 20:
        raise ValueError(f"the quiet segment {quiet} has {stop - start} samples; at least 20 are needed")
    return start, stop


def _autocorrelations(energised, quiet, noise: ARNoise, n_lags: int):
    """``(lags, residual acf, quiet acf)``: the energised residual's autocorrelation and the
    (detrended) quiet segment's, or the noise model's where there is no quiet segment."""
    n_quiet = quiet.size
    n_acf = int(min(n_lags, energised.size - 1, n_quiet - 1 if n_quiet else n_lags))
    if n_quiet:
        k = np.arange(n_quiet, dtype=float)
        quiet_acf = autocorrelation(quiet - np.polyval(np.polyfit(k, quiet, 1), k), n_acf)
    else:
        quiet_acf = noise.autocorrelation(n_acf)
    return np.arange(n_acf + 1), autocorrelation(energised, n_acf), quiet_acf


def noise_tests(
    time, residual, energised, noise: ARNoise, *, n_fitted=0, n_lags=40, block_seconds=0.2, level=None
) -> dict:
    """The noise tests of a residual (:mod:`identify.diagnosis.noise_tests`):
    ``{"variance", "ljung_box", "low_frequency"}`` -> :class:`StatTest`, on the whole residual
    (``energised``: its energised part, for the variance test). ``block_seconds`` is the
    low-frequency test's block [s], far longer than the noise's correlation, far shorter than the
    drive's period; ``n_lags`` the Ljung-Box lags; ``n_fitted`` the parameters fitted (the
    variance test's expectation). ``level``: the model's output on the energised samples,
    which adds ``"level"`` (:func:`level_test`, on the energised residual)."""
    dt = float(np.median(np.diff(time)))
    block = max(int(round(block_seconds / dt)), 1)
    block = min(block, max(time.size // 8, 1))
    filter_dof = max(noise.order, 1)  # the whitening filter's estimated coefficients (at least one: the order choice)
    return {
        "variance": variance_ratio_test(energised, noise, n_fitted),
        "ljung_box": ljung_box(
            noise.whiten(residual), n_lags, filter_error=time.size / noise.n_samples * filter_dof, filter_dof=filter_dof
        ),
        "low_frequency": low_frequency_test(residual, noise, block),
    } | ({} if level is None else {"level": level_test(level, energised, noise)})
