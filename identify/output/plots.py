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

import contourpy
import matplotlib
import numpy as np
from matplotlib.collections import LineCollection, PatchCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.patches import Rectangle as _Rectangle
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullLocator, ScalarFormatter
from matplotlib.transforms import Bbox, TransformedBbox

__all__ = [
    "unit_label",
    "column_extremes",
    "PIXEL_COLUMNS",
    "axis_label",
    "input_figure",
    "displacement_figure",
    "error_figure",
    "loops_figure",
    "corner_figure",
    "CORNER",
    "trace_figure",
    "TRACES",
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


def legend_below(fig, ax=None, handles=None, labels=None, ncols=3, **options):
    """A legend under the axes, outside the data: matplotlib's ``"outside lower center"`` of the
    figure, for which the constrained layout makes room (never over a curve).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    ax : Axes, optional
        Whose artists are listed (default: the handles given).
    handles, labels : list, optional
        Default ``ax.get_legend_handles_labels()``.
    ncols : int, default 3
    """
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    if labels is None:
        return fig.legend(handles=handles, loc="outside lower center", ncols=ncols, frameon=False, **options)
    return fig.legend(handles, labels, loc="outside lower center", ncols=ncols, frameon=False, **options)


def new_figure(width, height):
    """A detached figure of ``width`` x ``height`` inches with constrained layout."""
    return Figure(figsize=(width, height), layout="constrained")


def styled(function):
    """Run a figure builder inside :data:`STYLE` (rcParams are read when artists are made)."""

    def wrapper(*args, **kwargs):
        with matplotlib.rc_context(STYLE):
            return function(*args, **kwargs)

    wrapper.__name__ = function.__name__
    wrapper.__doc__ = function.__doc__
    wrapper.__wrapped__ = function
    return wrapper


#: Columns a long time series is reduced to before it is drawn (:func:`column_extremes`): about
#: one per pixel of the axes of a 10-inch figure at 100 dpi.
PIXEL_COLUMNS = 1000


def column_extremes(x, lower, upper=None, *, columns=PIXEL_COLUMNS):
    """A time series reduced to what ``columns`` pixel columns can show.

    The samples are split into ``columns`` runs of equal length (a record is sampled at a
    constant rate, so the runs are columns of equal width); of each run the lowest of
    ``lower`` and the highest of ``upper`` are kept. A line (``upper`` None) keeps both at
    their own samples, in the order they occur, so that it is drawn through every column's
    extremes as before; a band keeps them at the run's first and last sample. A series of
    at most twice ``columns`` samples is returned as it is.

    Returns
    -------
    x, lower, upper : ndarray
        For a line ``upper`` is ``lower``.
    """
    x, lower = np.asarray(x, dtype=float), np.asarray(lower, dtype=float)
    band = upper is not None
    upper = np.asarray(upper, dtype=float) if band else lower
    run = int(np.ceil(x.size / columns))
    if x.size <= 2 * columns or run < 2:
        return x, lower, upper
    pad = (-x.size) % run
    index = np.concatenate([np.arange(x.size), np.full(pad, x.size - 1)]).reshape(-1, run)
    lows = index[np.arange(index.shape[0]), np.argmin(lower[index], axis=1)]
    highs = index[np.arange(index.shape[0]), np.argmax(upper[index], axis=1)]
    if band:
        ends = np.column_stack([index[:, 0], index[:, -1]]).ravel()
        return x[ends], np.repeat(lower[lows], 2), np.repeat(upper[highs], 2)
    kept = np.unique(np.concatenate([lows, highs, [0, x.size - 1]]))
    return x[kept], lower[kept], lower[kept]


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

    def shown(lower, upper=None):  # the whole record: what the pixel columns show (a zoom: every sample)
        if window is not None:
            return t, lower[keep], (lower if upper is None else upper)[keep]
        return column_extremes(t, lower, upper)

    ax.fill_between(
        *shown(predictive_lo, predictive_hi),
        color=PREDICTIVE_COLOUR,
        alpha=0.25,
        lw=0,
        label="95 % predictive band (model + noise)",
    )
    ax.fill_between(
        *shown(credible_lo, credible_hi),
        color=MODEL_COLOUR,
        alpha=0.45,
        lw=0,
        label="95 % credible band (model)",
    )
    marker = "." if window is not None else None
    ax.plot(
        *shown(measured)[:2],
        color=MEASUREMENT_COLOUR,
        lw=0.8 if window is None else 0.6,
        marker=marker,
        ms=3,
        label="measurement",
    )
    ax.plot(*shown(median)[:2], color=MODEL_COLOUR, lw=1.2, label="model (posterior median)")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label(output_name, output_unit))
    ax.set_title(title or f"{output_name.capitalize()} vs time (paper Fig. 6)")
    legend_below(fig, ax, ncols=4, fontsize=9)  # off the data, and no search for the emptiest corner
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
        *column_extremes(time, error_lo, error_hi),
        color=MODEL_COLOUR,
        alpha=0.35,
        lw=0,
        label="95 % credible band of the error",
    )
    ax.plot(
        *column_extremes(time, error_median)[:2],
        color=MEASUREMENT_COLOUR,
        lw=0.7,
        label="measurement − model (posterior median)",
    )
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
    legend_below(fig, handles=handles, ncols=3, fontsize=9)
    return fig


#: The corner plot's look (that of ``corner.corner`` with the options the report used).
CORNER = {
    "bins": 20,
    "levels": (1 - np.exp(-0.5), 1 - np.exp(-2.0)),  # the 1 sigma and 2 sigma regions of a 2-D Gaussian
    "quantiles": (0.025, 0.5, 0.975),
    "max_ticks": 3,
    "space": 0.06,  # between panels, a fraction of a panel
    "line_width": 1.5,
    "hist_width": 1.0,
    "frame_width": 0.8,
    "tick_length": 3.5,  # points
    "tick_pad": 3.5,  # points
    "tick_label_size": 8,
    "label_size": 11,
    "label_offset": 0.55,  # inches from the panel to the parameter names (past the rotated tick labels)
    "title_size": 14,
    "marker_size": 6.0,
    "colour": "black",
    "reference_colour": "tab:blue",
}


def _contour_levels(H, levels):
    """corner.hist2d's density thresholds: the bin counts enclosing ``levels`` of the samples."""
    flat = np.sort(H.ravel())[::-1]
    cumulative = np.cumsum(flat)
    cumulative /= cumulative[-1]
    V = np.empty(len(levels))
    for i, v0 in enumerate(levels):
        below = flat[cumulative <= v0]
        V[i] = below[-1] if below.size else flat[0]
    V.sort()
    m = np.diff(V) == 0
    while np.any(m):
        V[np.where(m)[0][0]] *= 1.0 - 1e-4
        m = np.diff(V) == 0
    V.sort()
    return V


def _padded_grid(H, X, Y):
    """corner.hist2d's grid for the contours: bin centres and counts, extended by two bins
    on every side (edge values repeated once), so contours close at the plot's edges."""
    X1, Y1 = 0.5 * (X[1:] + X[:-1]), 0.5 * (Y[1:] + Y[:-1])
    H2 = H.min() + np.zeros((H.shape[0] + 4, H.shape[1] + 4))
    H2[2:-2, 2:-2] = H
    H2[2:-2, 1] = H[:, 0]
    H2[2:-2, -2] = H[:, -1]
    H2[1, 2:-2] = H[0]
    H2[-2, 2:-2] = H[-1]
    H2[1, 1] = H[0, 0]
    H2[1, -2] = H[0, -1]
    H2[-2, 1] = H[-1, 0]
    H2[-2, -2] = H[-1, -1]

    def extended(c):
        return np.concatenate(
            [c[0] + np.array([-2, -1]) * np.diff(c[:2]), c, c[-1] + np.array([1, 2]) * np.diff(c[-2:])]
        )

    return extended(X1), extended(Y1), H2


def _ticks(low, high, max_ticks, prune="lower", clear=0.0):
    """The tick values and labels (and offset text) an axis from ``low`` to ``high`` shows with
    ``MaxNLocator(max_ticks, prune=prune)`` and a ``ScalarFormatter``, as corner's; a tick closer
    than ``clear`` (a fraction of the range) to ``low`` is left out."""
    locator = MaxNLocator(max_ticks, prune=prune)
    locs = locator.tick_values(low, high)
    formatter = ScalarFormatter()
    formatter.create_dummy_axis()
    formatter.axis.set_view_interval(low, high)
    labels = formatter.format_ticks(locs)
    tolerance = 1e-10 * (high - low)
    inside = (locs >= low - tolerance + clear * (high - low)) & (locs <= high + tolerance)
    return locs[inside], [t for t, k in zip(labels, inside) if k], formatter.get_offset()


def corner_figure(samples, labels, *, reference=None, reference_label="least squares"):
    """Corner plot of the posterior of the varying parameters: the 1-D histograms on the
    diagonal (dashed: 2.5 %, 50 %, 97.5 %), the 1 sigma and 2 sigma contours of every pair
    below it (20 x 20 bins), the reference values as lines and squares.

    The look and the numbers are those of ``corner.corner`` (2.3) with the options the report
    used (:data:`CORNER`: contours only, no density shading, three ticks, labels rotated by
    45 degrees): the same histograms, contour levels and padded contour grid, the same axis
    ranges (a histogram's data range plus 5 %, a contour panel's grid), ticks and tick labels
    (``MaxNLocator``, ``ScalarFormatter``). Drawn without :data:`STYLE` (no grid). The panels
    are drawn as artists on one figure instead of as 324 matplotlib axes, whose creation and
    drawing took 5-10 s of the report's time for 18 parameters; here it takes a fraction of a
    second.

    Parameters
    ----------
    samples : ndarray, shape (S, D)
        Posterior samples after burn-in.
    labels : sequence of str, length D
        Axis labels (name and unit).
    reference : ndarray, shape (D,), optional
        Values drawn as lines (the least-squares estimate).
    """
    c = CORNER
    samples = np.asarray(samples, dtype=float)
    n_dim = samples.shape[1]
    size = max(6.0, 0.9 * n_dim)  # inches; ~1200 px at the report's 80 dpi for 18 parameters
    fig = Figure(figsize=(size, size))
    # room for the rotated tick labels and the names, which are written across the panels' row or
    # column (vertical below, horizontal at the left) so that long names never run into each other
    name_inches = c["label_size"] * 0.75 * max(len(str(label)) for label in labels) / 72.0
    margin = min(0.35, (c["label_offset"] + name_inches + 0.2) / size)
    max_ticks = c["max_ticks"] if size / n_dim >= 1.2 else 2  # narrow panels: two ticks
    left, bottom, right, top = margin, margin, 0.99, 1 - 0.4 / size
    width = (right - left) / (n_dim + (n_dim - 1) * c["space"])
    height = (top - bottom) / (n_dim + (n_dim - 1) * c["space"])
    point = 1.0 / (72.0 * size)  # one point as a fraction of the figure
    ranges = [(float(x.min()), float(x.max())) for x in samples.T]
    for j, (low, high) in enumerate(ranges):
        if not high > low:
            raise ValueError(f"parameter {labels[j]} has no dynamic range in the samples")
    bins = [np.linspace(low, high, c["bins"] + 1) for low, high in ranges]
    reference = None if reference is None else np.asarray(reference, dtype=float)

    # view limits: a histogram's x range is its data range plus matplotlib's 5 % margins; a
    # contour panel's ranges are its padded contour grid's (corner's limits, merged with both)
    hist_view = [(low - 0.05 * (high - low), high + 0.05 * (high - low)) for low, high in ranges]
    grid_view = []
    for b in bins:
        centres = 0.5 * (b[1:] + b[:-1])
        step_low, step_high = np.diff(centres[:2])[0], np.diff(centres[-2:])[0]
        grid_view.append((centres[0] - 2 * step_low, centres[-1] + 2 * step_high))

    def box(i, j):
        return left + j * width * (1 + c["space"]), top - i * height * (1 + c["space"]) - height

    def to_figure(i, j, x, y, xview, yview):
        x0, y0 = box(i, j)
        return (
            x0 + width * (np.asarray(x) - xview[0]) / (xview[1] - xview[0]),
            y0 + height * (np.asarray(y) - yview[0]) / (yview[1] - yview[0]),
        )

    known_ticks = {}

    # the locator prunes its lowest tick, which can lie outside the view, so a tick can remain at
    # a panel's low edge, where its label (one line high along the axis) meets the next panel's
    # label across the gap, or the other axis's at the corner: none within a line of the low edge
    clear = c["tick_label_size"] * point / min(width, height)

    def ticks_of(view):  # a column's or row's panels share their view: its ticks are found once
        if view not in known_ticks:
            known_ticks[view] = _ticks(*view, max_ticks, clear=clear)
        return known_ticks[view]

    frames, contours, steps, dashed, lines, ticks, squares = [], [], [], [], [], [], []
    texts = []  # (x, y, text, keyword arguments)
    tick = c["tick_length"] * point
    pad = (c["tick_length"] + c["tick_pad"]) * point
    # tick labels across the axis (vertical below, horizontal at the left): each is one line high
    # along the axis, and the lowest tick is pruned, so neighbouring panels' labels never touch
    tick_text = dict(fontsize=c["tick_label_size"])
    for i in range(n_dim):
        for j in range(i + 1):
            x0, y0 = box(i, j)
            frames.append(_Rectangle((x0, y0), width, height))
            xview = hist_view[j] if i == j else grid_view[j]
            if i == j:
                counts, _ = np.histogram(samples[:, i], bins=bins[i])
                yview = (0.0, 1.1 * counts.max())
                edges = np.repeat(bins[i], 2)
                heights = np.concatenate([[0.0], np.repeat(counts, 2).astype(float), [0.0]])
                steps.append(np.column_stack(to_figure(i, j, edges, heights, xview, yview)))
                for q in np.percentile(samples[:, i], [100.0 * q for q in c["quantiles"]]):
                    if xview[0] <= q <= xview[1]:
                        dashed.append(np.column_stack(to_figure(i, j, [q, q], yview, xview, yview)))
            else:
                yview = grid_view[i]
                H, X, Y = np.histogram2d(samples[:, j], samples[:, i], bins=[bins[j], bins[i]])
                X2, Y2, H2 = _padded_grid(H, X, Y)
                generator = contourpy.contour_generator(X2, Y2, H2.T)
                for level in _contour_levels(H, c["levels"]):
                    for path in generator.lines(level):
                        contours.append(np.column_stack(to_figure(i, j, path[:, 0], path[:, 1], xview, yview)))
                if reference is not None:
                    if yview[0] <= reference[i] <= yview[1]:
                        lines.append(np.column_stack(to_figure(i, j, xview, [reference[i]] * 2, xview, yview)))
                    if xview[0] <= reference[j] <= xview[1] and yview[0] <= reference[i] <= yview[1]:
                        squares.append(to_figure(i, j, reference[j], reference[i], xview, yview))
            if reference is not None and xview[0] <= reference[j] <= xview[1]:
                lines.append(np.column_stack(to_figure(i, j, [reference[j]] * 2, yview, xview, yview)))
            # ticks below every panel, left of every contour panel; labels at the figure's edges
            locs, tick_labels, offset = ticks_of(xview)
            xs, _ = to_figure(i, j, locs, np.zeros_like(locs), xview, (0.0, 1.0))
            ticks += [((x, y0), (x, y0 - tick)) for x in xs]
            if i == n_dim - 1:
                texts += [
                    (x, y0 - pad, t, dict(ha="center", va="top", rotation=90, **tick_text))
                    for x, t in zip(xs, tick_labels)
                ]
                if offset:
                    texts.append((x0 + width, y0 - 6 * pad, offset, dict(ha="right", va="top", fontsize=8)))
                texts.append(
                    (
                        x0 + 0.5 * width,
                        y0 - c["label_offset"] / size,
                        labels[j],
                        dict(ha="center", va="top", rotation=90),
                    )
                )
            if i != j:
                locs, tick_labels, offset = ticks_of(yview)
                _, ys = to_figure(i, j, np.zeros_like(locs), locs, (0.0, 1.0), yview)
                ticks += [((x0, y), (x0 - tick, y)) for y in ys]
                if j == 0:
                    texts += [
                        (x0 - pad, y, t, dict(ha="right", va="center_baseline", **tick_text))
                        for y, t in zip(ys, tick_labels)
                    ]
                    if offset:
                        texts.append((x0, y0 + height + pad, offset, dict(ha="left", va="bottom", fontsize=8)))
                    texts.append(
                        (x0 - c["label_offset"] / size, y0 + 0.5 * height, labels[i], dict(ha="right", va="center"))
                    )
    colour, figure = c["colour"], dict(transform=fig.transFigure)
    fig.add_artist(LineCollection(contours, colors=colour, linewidths=c["line_width"], **figure))
    fig.add_artist(LineCollection(steps, colors=colour, linewidths=c["hist_width"], **figure))
    fig.add_artist(LineCollection(dashed, colors=colour, linewidths=c["line_width"], linestyles="--", **figure))
    fig.add_artist(LineCollection(ticks, colors=colour, linewidths=c["frame_width"], **figure))

    fig.add_artist(PatchCollection(frames, facecolors="none", edgecolors=colour, linewidths=c["frame_width"], **figure))
    if lines:
        fig.add_artist(LineCollection(lines, colors=c["reference_colour"], linewidths=c["line_width"], **figure))
    if squares:
        xs, ys = np.array(squares, dtype=float).T
        marker = dict(marker="s", ms=c["marker_size"], linestyle="none", color=c["reference_colour"])
        fig.add_artist(Line2D(xs, ys, **marker, **figure))
    for x, y, text, keywords in texts:
        fig.text(x, y, text, **{"fontsize": c["label_size"], **keywords})
    fig.suptitle(
        f"Posterior of the {n_dim} varying parameters (contours: 1σ and 2σ regions; dashed: 2.5 %, 50 %, 97.5 %"
        + ("" if reference is None else f"; blue lines: {reference_label}")
        + ")",
        fontsize=c["title_size"],
        y=1 - 0.1 / size,
    )
    return fig


#: The trace figure's look: panels, ticks and texts as the axes of :data:`STYLE` drew them.
TRACES = {
    "columns": 4,
    "panel_height": 1.9,  # inches per row of panels
    "width": 15.0,  # inches
    "hspace": 0.5,  # between rows, a fraction of a panel's height
    "wspace": 0.22,  # between columns, a fraction of a panel's width
    "max_ticks": (7, 4),  # along the steps, along the values
    "margin": 0.05,  # of the data range on either side, as matplotlib's autoscaling
    "tick_length": 3.5,  # points
    "tick_pad": 3.5,  # points
    "tick_label_size": 8,
    "title_size": 10,
    "grid_colour": "#b0b0b0",
    "grid_alpha": 0.3,
    "burn_in_colour": "tab:orange",
}


def _trace_views(values, steps, discard, is_log_prob):
    """A panel's view (x range, y range): the data's ranges plus the 5 % margins; the log
    posterior's y range follows the post-burn-in values (earlier, lower values leave the panel)."""
    margin = TRACES["margin"]
    x_low, x_high = float(min(steps[0], discard)), float(steps[-1])
    x_view = (x_low - margin * (x_high - x_low), x_high + margin * (x_high - x_low))
    finite = values[np.isfinite(values)]
    settled = values[steps > discard]
    settled = settled[np.isfinite(settled)]
    if is_log_prob and settled.size:
        low, high = float(settled.min()), float(settled.max())
        return x_view, (low - 0.5 * (high - low + 1.0), high + 0.1 * (high - low + 1.0))
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    span = high - low if high > low else max(abs(low), 1.0) * 1e-3
    return x_view, (low - margin * span, high + margin * span)


def trace_figure(chain, log_prob, labels, *, steps, discard):
    """Walker traces of every varying parameter and of the log-posterior, burn-in shaded.

    The panels (:data:`TRACES`: four columns, a frame, grid, ticks and tick labels, the burn-in
    shaded, the parameter as the panel's title, the steps labelled under the lowest panels) are
    drawn as artists of one figure, as :func:`corner_figure` draws its panels, instead of one
    matplotlib axes each: the axes' tick objects and layout took most of the report's drawing
    time; each panel's walker lines are clipped to its frame.

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
    c = TRACES
    n_steps, n_walkers, n_dim = chain.shape
    n_cols = c["columns"]
    n_rows = int(np.ceil((n_dim + 1) / n_cols))
    height = c["panel_height"] * n_rows + 0.6
    fig = Figure(figsize=(c["width"], height))
    left, right, bottom, top = 0.05, 0.99, 0.5 / height, 1 - 0.8 / height
    width = (right - left) / (n_cols + (n_cols - 1) * c["wspace"])
    panel_height = (top - bottom) / (n_rows + (n_rows - 1) * c["hspace"])
    point_x, point_y = 1.0 / (72.0 * c["width"]), 1.0 / (72.0 * height)  # one point as a figure fraction
    steps = np.asarray(steps, dtype=float)
    line_alpha = float(np.clip(8.0 / n_walkers, 0.08, 0.6))
    series = [(chain[:, :, i], labels[i]) for i in range(n_dim)] + [(log_prob, "log posterior")]
    frames, shades, grid, ticks, texts = [], [], [], [], []
    tick_text = dict(fontsize=c["tick_label_size"])
    for k, (values, label) in enumerate(series):
        row, col = divmod(k, n_cols)
        x0 = left + col * width * (1 + c["wspace"])
        y0 = top - row * panel_height * (1 + c["hspace"]) - panel_height
        x_view, y_view = _trace_views(np.asarray(values, dtype=float), steps, discard, k == n_dim)

        def fx(x, x0=x0, x_view=x_view):
            return x0 + width * (np.asarray(x, dtype=float) - x_view[0]) / (x_view[1] - x_view[0])

        def fy(y, y0=y0, y_view=y_view):
            return y0 + panel_height * (np.asarray(y, dtype=float) - y_view[0]) / (y_view[1] - y_view[0])

        frames.append(Rectangle((x0, y0), width, panel_height))
        shade_to = min(max(float(fx(discard)), x0), x0 + width)
        shades.append(
            Rectangle((max(float(fx(steps[0])), x0), y0), shade_to - max(float(fx(steps[0])), x0), panel_height)
        )
        finite = np.where(np.isfinite(values), values, np.nan)
        walkers = [np.column_stack([fx(steps), fy(finite[:, w])]) for w in range(finite.shape[1])]
        lines = LineCollection(walkers, colors="black", linewidths=0.5, alpha=line_alpha, transform=fig.transFigure)
        lines.set_clip_box(TransformedBbox(Bbox.from_bounds(x0, y0, width, panel_height), fig.transFigure))
        fig.add_artist(lines)
        texts.append(
            (
                x0 + 0.5 * width,
                y0 + panel_height + 6 * point_y,
                label,
                dict(ha="center", va="bottom", fontsize=c["title_size"]),
            )
        )
        locs, tick_labels, offset = _ticks(*y_view, c["max_ticks"][1], prune=None)
        for y, text in zip(fy(locs), tick_labels):
            grid.append(((x0, y), (x0 + width, y)))
            ticks.append(((x0, y), (x0 - c["tick_length"] * point_x, y)))
            texts.append(
                (
                    x0 - (c["tick_length"] + c["tick_pad"]) * point_x,
                    y,
                    text,
                    dict(ha="right", va="center_baseline", **tick_text),
                )
            )
        if offset:
            texts.append((x0, y0 + panel_height + 2 * point_y, offset, dict(ha="left", va="bottom", **tick_text)))
        locs, tick_labels, offset = _ticks(*x_view, c["max_ticks"][0], prune=None)
        lowest = k >= len(series) - n_cols
        for x, text in zip(fx(locs), tick_labels):
            grid.append(((x, y0), (x, y0 + panel_height)))
            ticks.append(((x, y0), (x, y0 - c["tick_length"] * point_y)))
            if lowest:
                texts.append(
                    (
                        x,
                        y0 - (c["tick_length"] + c["tick_pad"]) * point_y,
                        text,
                        dict(ha="center", va="top", **tick_text),
                    )
                )
        if lowest:
            texts.append((x0 + 0.5 * width, y0 - 20 * point_y, "step", dict(ha="center", va="top", fontsize=9)))
    figure = dict(transform=fig.transFigure)
    fig.add_artist(PatchCollection(shades, facecolors=c["burn_in_colour"], edgecolors="none", alpha=0.2, **figure))
    fig.add_artist(LineCollection(grid, colors=c["grid_colour"], alpha=c["grid_alpha"], linewidths=0.8, **figure))
    fig.add_artist(LineCollection(ticks, colors="black", linewidths=0.8, **figure))
    fig.add_artist(PatchCollection(frames, facecolors="none", edgecolors="black", linewidths=0.8, **figure))
    for x, y, text, keywords in texts:
        fig.text(x, y, text, **keywords)
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
    for axis in (ax.xaxis, ax.yaxis):  # plain numbers at 1, 2, 5 x 10^k: no minor ticks to lay out
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        axis.set_minor_locator(NullLocator())
    ax.set_xlabel("chain length N [steps]")
    ax.set_ylabel("integrated autocorrelation time τ [steps]")
    ax.set_title("Autocorrelation time vs chain length")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=9)  # beside the data
    return fig
