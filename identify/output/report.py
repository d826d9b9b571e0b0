"""The uncertainty report of a finished study: one HTML page and its figures as PNGs beside it.

:func:`write_report` reads a results folder written by ``study`` (layout in
docs/CONTRACTS.md, read through :func:`identify.output.results.load_results`: ``data.npz``,
``chain.h5``, ``fit.json``, ``summary.json``, ``manifest.json``) and writes
every figure as ``DIR/<name>.png`` (names in :data:`FIGURES`) and ``DIR/report.html``
(tables as HTML, each figure shown from its PNG by a path relative to the folder: it opens in
any browser without a server, from the folder or a copy of the whole folder; each figure is
stored once). It never refits: model curves come from posterior draws
pushed through the forward model in ONE vectorised :meth:`model.Model.evaluate` call.

This module holds the figures (:func:`report_figures`), the page's assembly
(:func:`page_html`) and :func:`write_report`; what the page computes is in
:mod:`identify.output.report_analysis`, its HTML sections in
:mod:`identify.output.report_sections`, the section "Before and after" in
:mod:`identify.output.report_comparison`. Their public names are importable from here too.

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
  shown (sorted by name; the file stem becomes the alt text).
* **5. Provenance**: ``manifest.json`` (data file and sha256, seed, settings, versions,
  git commit, run times) and the convergence status stated plainly.

Numbers in tables carry ``data-key`` attributes (``fit.rms``,
``parameters.alpha.median``, ...) and are printed with :data:`DIGITS` significant
digits, so a test can parse them back and compare them with ``summary.json``.
"""

from __future__ import annotations

import math
import time as _time
from pathlib import Path

import numpy as np

from ..data.fileio import atomic_write_bytes
from . import plots, results
from .diagnosis_files import DIAGNOSIS_FIGURES, DIAGNOSIS_FILE
from .joint_report import is_joint_folder, write_joint_report
from .page import escape, html_page, linked_figure, png_bytes
from .report_analysis import (
    NOISE_COORDINATE,
    ZOOM_BAND_MULTIPLE,
    Branch,
    ChainSample,
    CycleError,
    ModelBands,
    PosteriorDraws,
    ReportAnalysis,
    ReportData,
    ResultsError,
    analyse_report,
    autocorrelation_curve,
    branches,
    cycle_errors,
    load_report_data,
    loop_zoom_box,
    model_bands,
    posterior_draws,
    read_chain,
    zoom_samples,
)
from .report_comparison import COMPARISON_FIGURE, Comparison, comparison_figure, comparison_html, load_comparison
from .report_sections import (
    REDUCED_CHI2_LIMIT,
    RMS_RATIO_LIMIT,
    diagnosis_html,
    fit_quality_html,
    glance_html,
    parameters_html,
    provenance_html,
    residual_above_noise,
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
    "analyse_report",
    "report_figures",
    "ReportData",
    "ReportAnalysis",
    "ChainSample",
    "PosteriorDraws",
    "ModelBands",
    "Branch",
    "CycleError",
    "ResultsError",
    "FIGURES",
    "DPI",
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

#: At most this many rows per walker are drawn in the trace plots: about one per pixel column of
#: a panel (a quarter of the figure's width), more would not show.
MAX_TRACE_ROWS = 300
#: At most this many samples go into the corner plot.
MAX_CORNER_SAMPLES = 6000
#: PNG resolution [dots per inch]; the corner plot and the traces are larger in inches, so lower:
#: the page is at most 1250 px wide, and a wider PNG is only shrunk by the browser.
DPI = {"default": 100, "corner": 80, "traces": 80}

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


def report_figures(data: ReportData, analysis: ReportAnalysis, rng: np.random.Generator):
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


def page_html(data: ReportData, analysis: ReportAnalysis, figure_html: dict, seconds: float) -> str:
    """The whole page: title, "At a glance", "Before and after" (``figure_html["comparison-section"]``),
    sections 1-5 in order; ``figure_html`` maps each stem of :data:`FIGURES` to its ready ``<figure>``."""
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
        glance_html(data, analysis),
        figure_html.get("comparison-section", ""),
        '<h2 id="measurement">1. Measurement vs model</h2>',
        *(figure_html[s] for s in ("fig5_input", "fig6_displacement", "fig6_zoom", "fig7_error", "fig8_loops")),
        fit_quality_html(data, analysis),
        parameters_html(data, analysis, "\n".join(figure_html[s] for s in ("corner", "traces", "autocorrelation"))),
        diagnosis_html(data),
        provenance_html(data, analysis, seconds),
    ]
    return html_page(title, parts)


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

    if is_joint_folder(result_dir):  # a study of several records: its own page
        return write_joint_report(result_dir, rng=rng)
    data = load_report_data(result_dir)
    analysis = analyse_report(data, int(n_draws), rng)
    figure_html = {}
    for stem, figure, caption in report_figures(data, analysis, rng):
        png = png_bytes(figure, DPI.get(stem, DPI["default"]))
        atomic_write_bytes(data.directory / f"{stem}.png", png)
        figure_html[stem] = linked_figure(stem, FIGURES[stem], f"{stem}.png", caption)
    comparison = load_comparison(data, analysis)
    if isinstance(comparison, Comparison):
        png = png_bytes(comparison_figure(data, comparison), DPI["default"])
        atomic_write_bytes(data.directory / "comparison.png", png)
        caption = (
            "Left: the loops of the two least-squares models over the measurement. Middle: measurement minus "
            "each model. Right: each input cycle's RMS error (cycles split at the input's minima)."
        )
        figure_html["comparison"] = linked_figure(
            "comparison", COMPARISON_FIGURE["comparison"], "comparison.png", caption
        )
    figure_html["comparison-section"] = comparison_html(data, comparison, figure_html.get("comparison", ""))
    page = page_html(data, analysis, figure_html, _time.perf_counter() - started)
    path = data.directory / results.FILES["report"]
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
