"""Figures of the identification report.

Every function takes arrays (already computed by :mod:`identify.output.report`) and returns a
:class:`matplotlib.figure.Figure`; none computes a fit or a statistic. Figures are made
with :class:`~matplotlib.figure.Figure` directly (no :mod:`matplotlib.pyplot`, no global
figure registry), so they render with the Agg canvas on any machine without a display
and never leak memory. Save one with ``fig.savefig(path, format="png")``.

Colours follow the paper: measurement black, model red. The hysteresis-loop figure
colours the rising branches red and the falling branches blue.
"""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle

__all__ = [
    "unit_label",
    "axis_label",
    "input_figure",
    "displacement_figure",
    "error_figure",
    "loops_figure",
    "corner_figure",
    "trace_figure",
    "autocorrelation_figure",
    "STYLE",
    "new_figure",
    "styled",
]

#: rcParams applied while a figure is drawn (readable at normal size in a browser).
STYLE = {
    "font.size": 11,
    "axes.titlesize": 12,
    "axes.labelsize": 11,
    "legend.fontsize": 10,
    "xtick.labelsize": 10,
    "ytick.labelsize": 10,
    "axes.grid": True,
    "grid.alpha": 0.3,
}

MEASUREMENT_COLOUR = "black"
MODEL_COLOUR = "tab:red"
RISING_COLOUR = "tab:red"
FALLING_COLOUR = "tab:blue"
PREDICTIVE_COLOUR = "tab:orange"
NOISE_COLOUR = "tab:blue"

_UNIT_DISPLAY = {"um": "µm", "1/A": "1/A", "um/A": "µm/A"}


def unit_label(unit: str) -> str:
    """Display form of a unit string (``"um"`` -> ``"µm"``); ``""`` for dimensionless stays ``"-"``."""
    if not unit:
        return "-"
    return _UNIT_DISPLAY.get(unit, unit.replace("um", "µm"))


def axis_label(quantity: str, unit: str) -> str:
    """``"quantity [unit]"`` with the unit in display form, e.g. ``"displacement [µm]"``."""
    return f"{quantity} [{unit_label(unit)}]"


def new_figure(width, height):
    """A detached figure of ``width`` x ``height`` inches with constrained layout."""
    return Figure(figsize=(width, height), layout="constrained")


def styled(function):
    """Run a figure builder inside :data:`STYLE` (rcParams are read when artists are made)."""

    def wrapper(*args, **kwargs):
        import matplotlib

        with matplotlib.rc_context(STYLE):
            return function(*args, **kwargs)

    wrapper.__name__ = function.__name__
    wrapper.__doc__ = function.__doc__
    wrapper.__wrapped__ = function
    return wrapper


@styled
def input_figure(time, current, *, input_name="current", input_unit="A", reversals=None):
    """The drive against time, as the paper's Fig. 5.

    Parameters
    ----------
    time : ndarray, shape (T,)
        Seconds.
    current : ndarray, shape (T,)
        Drive in ``input_unit``.
    input_name, input_unit : str
        For the axis label.
    reversals : ndarray of int, optional
        Sample indices of the input reversals, marked with dots.
    """
    fig = new_figure(10, 3.6)
    ax = fig.add_subplot()
    ax.plot(time, current, color=MEASUREMENT_COLOUR, lw=1.2, label=f"input {input_name}")
    if reversals is not None and len(reversals):
        ax.plot(time[reversals], current[reversals], "o", ms=4, color=MODEL_COLOUR, label="input reversals")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label(input_name, input_unit))
    ax.set_title(f"Input {input_name} vs time (paper Fig. 5)")
    ax.legend(loc="upper right")
    return fig


@styled
def displacement_figure(
    time,
    measured,
    median,
    credible_lo,
    credible_hi,
    predictive_lo,
    predictive_hi,
    *,
    output_name="displacement",
    output_unit="um",
    window=None,
    title=None,
):
    """Measurement and posterior model against time with 95 % bands (the paper's Fig. 6).

    Parameters
    ----------
    time : ndarray, shape (T,)
        Seconds.
    measured, median : ndarray, shape (T,)
        Measured output and the pointwise posterior median of the model, ``output_unit``.
    credible_lo, credible_hi : ndarray, shape (T,)
        95 % credible band of the model (2.5 % and 97.5 % pointwise quantiles of the draws).
    predictive_lo, predictive_hi : ndarray, shape (T,)
        95 % predictive band (model plus sensor noise).
    window : tuple of float, optional
        ``(t_start, t_end)`` [s]: plot only this window (a zoom); the y range follows it.
    title : str, optional
    """
    fig = new_figure(10, 4.6)
    ax = fig.add_subplot()
    if window is not None:
        keep = (time >= window[0]) & (time <= window[1])
    else:
        keep = np.ones(time.shape, dtype=bool)
    t = time[keep]
    ax.fill_between(
        t,
        predictive_lo[keep],
        predictive_hi[keep],
        color=PREDICTIVE_COLOUR,
        alpha=0.25,
        lw=0,
        label="95 % predictive band (model + noise)",
    )
    ax.fill_between(
        t,
        credible_lo[keep],
        credible_hi[keep],
        color=MODEL_COLOUR,
        alpha=0.45,
        lw=0,
        label="95 % credible band (model)",
    )
    marker = "." if window is not None else None
    ax.plot(
        t,
        measured[keep],
        color=MEASUREMENT_COLOUR,
        lw=0.8 if window is None else 0.6,
        marker=marker,
        ms=3,
        label="measurement",
    )
    ax.plot(t, median[keep], color=MODEL_COLOUR, lw=1.2, label="model (posterior median)")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label(output_name, output_unit))
    ax.set_title(title or f"{output_name.capitalize()} vs time (paper Fig. 6)")
    ax.legend(loc="best")
    if window is not None:
        ax.set_xlim(window)
    return fig


@styled
def error_figure(
    time,
    error_median,
    error_lo,
    error_hi,
    *,
    noise_sigma,
    max_error_pct,
    max_error_index,
    output_unit="um",
    energised_from=None,
):
    """Model error against time with the ±2 sigma noise band (the paper's Fig. 7).

    Parameters
    ----------
    time : ndarray, shape (T,)
        Seconds.
    error_median : ndarray, shape (T,)
        Measurement minus the posterior-median model, ``output_unit``.
    error_lo, error_hi : ndarray, shape (T,)
        95 % credible band of the error (measurement minus the model's band).
    noise_sigma : float
        Sensor noise standard deviation, ``output_unit``.
    max_error_pct : float
        Max |error| over the energised part, % of the measured displacement range.
    max_error_index : int
        Sample index of that maximum (circled).
    energised_from : float, optional
        Time [s] where the quiet segment ends (shaded before it).
    """
    fig = new_figure(10, 4.8)
    ax = fig.add_subplot()
    ax.axhspan(
        -2 * noise_sigma,
        2 * noise_sigma,
        color=NOISE_COLOUR,
        alpha=0.15,
        lw=0,
        label=f"±2σ sensor noise (σ = {noise_sigma:.3g} {unit_label(output_unit)})",
    )
    ax.fill_between(
        time, error_lo, error_hi, color=MODEL_COLOUR, alpha=0.35, lw=0, label="95 % credible band of the error"
    )
    ax.plot(time, error_median, color=MEASUREMENT_COLOUR, lw=0.7, label="measurement − model (posterior median)")
    ax.axhline(0.0, color="grey", lw=0.8)
    if energised_from is not None and energised_from > time[0]:
        ax.axvspan(time[0], energised_from, color="grey", alpha=0.12, lw=0, label="quiet segment (not energised)")
    k = int(max_error_index)
    ax.plot(time[k], error_median[k], "o", mfc="none", mec=MODEL_COLOUR, ms=12, mew=2, label="largest error")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label("model error", output_unit))
    ax.set_title(
        f"Model error vs time (paper Fig. 7): max |error| = {abs(error_median[k]):.3g} {unit_label(output_unit)} "
        f"= {max_error_pct:.3g} % of the displacement range, at t = {time[k]:.4g} s"
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=9, frameon=False)
    return fig


def _branch_polygons(x, lower, upper, segments):
    """One closed polygon per branch: along ``upper`` forward, back along ``lower``."""
    polygons = []
    for start, stop in segments:
        xs = x[start : stop + 1]
        polygons.append(
            np.concatenate(
                [
                    np.column_stack([xs, upper[start : stop + 1]]),
                    np.column_stack([xs[::-1], lower[start : stop + 1][::-1]]),
                ]
            )
        )
    return polygons


def _draw_loops(ax, current, measured, median, credible_lo, credible_hi, segments, rising):
    rising = np.asarray(rising, dtype=bool)
    for direction, colour in ((True, RISING_COLOUR), (False, FALLING_COLOUR)):
        chosen = [s for s, r in zip(segments, rising) if r == direction]
        if not chosen:
            continue
        ax.add_collection(
            PolyCollection(
                _branch_polygons(current, credible_lo, credible_hi, chosen),
                facecolors=colour,
                edgecolors="none",
                alpha=0.35,
            )
        )
        lines = [np.column_stack([current[a : b + 1], median[a : b + 1]]) for a, b in chosen]
        ax.add_collection(LineCollection(lines, colors=colour, linewidths=1.0))
    ax.plot(current, measured, color=MEASUREMENT_COLOUR, lw=0.5, alpha=0.8)


@styled
def loops_figure(
    current,
    measured,
    median,
    credible_lo,
    credible_hi,
    *,
    segments,
    rising,
    zoom_box,
    input_name="current",
    input_unit="A",
    output_name="displacement",
    output_unit="um",
):
    """Hysteresis loops, displacement against current, with the band along every branch (Fig. 8).

    The record is split at the input reversals into monotone branches; each branch's
    95 % credible band is a polygon over that branch's own current samples (never a
    sorted current grid, which would mix the rising and falling branches of a system
    with memory). Left: all loops; right: a zoom on the worst region.

    Parameters
    ----------
    current, measured, median, credible_lo, credible_hi : ndarray, shape (T,)
        Drive [``input_unit``], measurement, posterior-median model and its 95 % band
        [``output_unit``].
    segments : sequence of (int, int)
        Inclusive sample ranges ``(start, stop)`` of the branches (consecutive branches
        share their reversal sample).
    rising : sequence of bool
        One per segment: True for a rising branch.
    zoom_box : ((float, float), (float, float))
        ``((current_min, current_max), (displacement_min, displacement_max))`` shown in
        the right-hand panel (and outlined in green on the left).
    """
    fig = new_figure(13, 6.8)
    full_ax, zoom_ax = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.35, 1]})
    for ax in (full_ax, zoom_ax):
        _draw_loops(ax, current, measured, median, credible_lo, credible_hi, segments, rising)
        ax.set_xlabel(axis_label(input_name, input_unit))
        ax.set_ylabel(axis_label(output_name, output_unit))
    full_ax.autoscale_view()
    (x0, x1), (y0, y1) = zoom_box
    zoom_ax.set_xlim(x0, x1)
    zoom_ax.set_ylim(y0, y1)
    zoom_ax.lines[-1].set(marker=".", ms=4, lw=0.6)  # the measurement: show its samples
    full_ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="green", lw=2.0))
    full_ax.set_title("Hysteresis loops (paper Fig. 8)")
    zoom_ax.set_title("Zoom: the worst region (green box)")
    handles = [
        Patch(color=MEASUREMENT_COLOUR, label="measurement"),
        Patch(color=RISING_COLOUR, alpha=0.6, label="model, rising branches: median and 95 % band"),
        Patch(color=FALLING_COLOUR, alpha=0.6, label="model, falling branches: median and 95 % band"),
    ]
    full_ax.legend(handles=handles, loc="upper left", fontsize=9)
    return fig


def corner_figure(samples, labels, *, reference=None, reference_label="least squares"):
    """Corner plot (:mod:`corner`) of the posterior of the varying parameters.

    Drawn without :data:`STYLE` (no grid) and with contour lines only (no density
    shading), which halves the time of a plot of ~20 parameters.

    Parameters
    ----------
    samples : ndarray, shape (S, D)
        Posterior samples after burn-in.
    labels : sequence of str, length D
        Axis labels (name and unit).
    reference : ndarray, shape (D,), optional
        Values drawn as lines (the least-squares estimate).
    """
    import corner

    samples = np.asarray(samples, dtype=float)
    n_dim = samples.shape[1]
    size = max(6.0, 0.9 * n_dim)  # inches; ~1200 px at the report's 80 dpi for 18 parameters
    fig = Figure(figsize=(size, size))
    fig.subplots(n_dim, n_dim)
    corner.corner(
        samples,
        labels=list(labels),
        truths=None if reference is None else list(reference),
        truth_color="tab:blue",
        quantiles=[0.025, 0.5, 0.975],
        fig=fig,
        max_n_ticks=3,
        label_kwargs={"fontsize": 13},
        plot_datapoints=False,
        plot_density=False,
        no_fill_contours=True,
        levels=(1 - np.exp(-0.5), 1 - np.exp(-2.0)),
        bins=20,
        labelpad=0.3,
    )
    for ax in fig.axes:
        ax.tick_params(labelsize=8)
    margin = min(0.2, 1.0 / size)  # 1 inch for the rotated tick labels and the names
    fig.subplots_adjust(left=margin, bottom=margin, right=0.99, top=1 - 0.4 / size, wspace=0.06, hspace=0.06)
    fig.suptitle(
        f"Posterior of the {n_dim} varying parameters (contours: 1σ and 2σ regions; dashed: 2.5 %, 50 %, 97.5 %"
        + ("" if reference is None else f"; blue lines: {reference_label}")
        + ")",
        fontsize=14,
        y=1 - 0.1 / size,
    )
    return fig


@styled
def trace_figure(chain, log_prob, labels, *, steps, discard):
    """Walker traces of every varying parameter and of the log-posterior, burn-in shaded.

    Parameters
    ----------
    chain : ndarray, shape (S, W, D)
        Stored (possibly thinned) chain: ``S`` steps of ``W`` walkers.
    log_prob : ndarray, shape (S, W)
        Log-posterior of the same samples; its panel's y range follows the post-burn-in
        values (lower burn-in values run off the bottom).
    labels : sequence of str, length D
    steps : ndarray of int, shape (S,)
        Sampler step number of each stored row (for the x axis).
    discard : int
        Burn-in steps (shaded and excluded from the posterior summaries).
    """
    n_steps, n_walkers, n_dim = chain.shape
    n_cols = 4
    n_rows = int(np.ceil((n_dim + 1) / n_cols))
    height = 1.9 * n_rows + 0.6
    fig = Figure(figsize=(15, height))  # fixed margins: constrained layout triples the drawing time here
    grid = dict(left=0.05, right=0.99, bottom=0.5 / height, top=1 - 0.8 / height, hspace=0.5, wspace=0.22)
    axes = np.atleast_1d(fig.subplots(n_rows, n_cols, sharex=True, gridspec_kw=grid)).ravel()
    line_alpha = float(np.clip(8.0 / n_walkers, 0.08, 0.6))
    series = [(chain[:, :, i], labels[i]) for i in range(n_dim)] + [(log_prob, "log posterior")]
    for ax, (values, label) in zip(axes, series):
        finite = np.where(np.isfinite(values), values, np.nan)
        walkers = [np.column_stack([steps, finite[:, w]]) for w in range(finite.shape[1])]
        ax.add_collection(LineCollection(walkers, colors="black", linewidths=0.5, alpha=line_alpha))
        ax.autoscale_view()
        ax.axvspan(steps[0], discard, color="tab:orange", alpha=0.2, lw=0)
        ax.set_title(label, fontsize=10)
        ax.tick_params(labelsize=8)
    settled = log_prob[steps > discard]
    settled = settled[np.isfinite(settled)]
    if settled.size:  # keep the post-burn-in spread readable; earlier, lower values leave the panel
        low, high = settled.min(), settled.max()
        axes[len(series) - 1].set_ylim(low - 0.5 * (high - low + 1.0), high + 0.1 * (high - low + 1.0))
    for ax in axes[len(series) :]:
        ax.set_visible(False)
    for ax in axes[max(0, len(series) - n_cols) : len(series)]:
        ax.set_xlabel("step", fontsize=9)
        ax.xaxis.set_tick_params(labelbottom=True)
    fig.suptitle(f"Walker traces ({n_walkers} walkers; shaded: burn-in, the first {discard} steps, discarded)")
    return fig


@styled
def autocorrelation_figure(chain_lengths, tau, labels, *, tau_reported=None):
    """Integrated autocorrelation time estimate against chain length, with the N/50 line.

    The chain is long enough (emcee's criterion) where the estimates lie below the
    N/50 line and have stopped growing.

    Parameters
    ----------
    chain_lengths : ndarray, shape (K,)
        Steps ``N`` used for each estimate.
    tau : ndarray, shape (K, D)
        Estimated tau [steps] of each parameter from the first ``N`` steps.
    labels : sequence of str, length D
    tau_reported : float, optional
        The run's reported max tau (summary.json), drawn as a dotted line.
    """
    fig = new_figure(9, 5.2)
    ax = fig.add_subplot()
    tau = np.asarray(tau, dtype=float)
    finals = np.where(np.isfinite(tau[-1]), tau[-1], -np.inf)
    slowest = set(np.argsort(-finals)[:4].tolist())
    for i, label in enumerate(labels):
        if i in slowest:
            ax.loglog(chain_lengths, tau[:, i], "o-", lw=1.6, ms=4, label=f"{label} (slow)")
        else:
            ax.loglog(chain_lengths, tau[:, i], "-", color="grey", lw=0.8, alpha=0.6)
    ax.loglog(chain_lengths, np.asarray(chain_lengths) / 50.0, "k--", lw=1.5, label="N / 50 (converged below this)")
    if tau_reported is not None and np.isfinite(tau_reported):
        ax.axhline(tau_reported, color="tab:purple", ls=":", lw=1.5, label=f"reported max τ = {tau_reported:.3g}")
    ax.plot([], [], color="grey", lw=0.8, label="other parameters")
    ax.set_xlabel("chain length N [steps]")
    ax.set_ylabel("integrated autocorrelation time τ [steps]")
    ax.set_title("Autocorrelation time vs chain length")
    ax.legend(loc="upper left", fontsize=9)
    return fig
