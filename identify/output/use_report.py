"""Pages, figures and files of ``predict`` and ``compensate`` (see :mod:`identify.workflows.use`).

:func:`prediction_files` and :func:`compensation_files` turn a result object
(:class:`identify.workflows.use.Prediction`, :class:`identify.workflows.use.Compensation`; read through their
documented attributes, never imported here) into ``{file name: bytes}``: the JSON, a
self-contained HTML page in the style of the study's report (:mod:`identify.output.report`:
figures embedded as PNG, numbers with ``data-key`` attributes), every figure as a PNG and,
for a compensation, the CSV files. Nothing here computes a fit, a band or an inverse.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..data.reversals import find_reversals
from ..diagnosis import Thresholds
from . import plots
from .diagnosis_plots import (
    cycles_figure,
    diagnosis_figures,
    residual_autocorrelation_figure,
    residual_branches_figure,
    residual_rate_figure,
    residual_time_figure,
)
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
from .plots import axis_label, new_figure, styled, unit_label
from .report import (
    branches,
    loop_zoom_box,
    zoom_samples,
)
from .results import jsonable, now_iso

__all__ = [
    "prediction_files",
    "compensation_files",
    "PREDICTION_FIGURES",
    "COMPENSATION_FIGURES",
    "compensation_target_figure",
    "compensation_current_figure",
    "compensation_error_figure",
    "compensation_loop_figure",
]

#: figure stem -> caption heading, in page order (``where_*`` from the diagnosis' figures).
PREDICTION_FIGURES = {
    "input": "Input of the new record",
    "displacement": "Measured vs predicted displacement, 95% credible and predictive bands",
    "zoom": "Measured vs predicted displacement, zoom on the worst region",
    "error": "Prediction error vs time with the 2-sigma noise band",
    "loops": "Hysteresis loops: measured vs predicted, 95% credible band along each branch",
    "where_1_residual_vs_time": "Where it fails: validation residual vs time",
    "where_2_residual_vs_current": "Where it fails: validation residual vs current, by branch",
    "where_3_residual_vs_rate": (
        "Where it fails: validation residual vs input rate, time since reversal and model output"
    ),
    "where_4_cycles": "Where it fails: per-cycle RMS and max error, levels at the extrema",
    "where_5_autocorrelation": "Where it fails: autocorrelation of the validation residual",
}
COMPENSATION_FIGURES = {
    "comp_target": "Target and the displacement the model predicts for the feedforward current",
    "comp_current": "Feedforward current (posterior median) with the 95% band of the draws' own inverses",
    "comp_error": "Predicted tracking error with its 95% credible and predictive bands",
    "comp_loop": "The inverse loop: feedforward current vs target displacement",
}


def _json_bytes(obj) -> bytes:
    return (json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n").encode("utf-8")


class _BandView:
    """The attributes :func:`identify.output.report.loop_zoom_box` reads."""

    def __init__(self, predictive_lo, predictive_hi):
        self.predictive_lo = predictive_lo
        self.predictive_hi = predictive_hi


def _page(title, body_parts) -> bytes:
    return html_page(title, body_parts).encode("utf-8")


def _notes_html(notes) -> str:
    if not notes:
        return ""
    return (
        '<div class="note" id="notes"><b>Keep in mind:</b><ul>'
        + "".join(f"<li>{plain_text(n)}</li>" for n in notes)
        + "</ul></div>"
    )


# --------------------------------------------------------------------------------------
# prediction
# --------------------------------------------------------------------------------------
def _prediction_figures(p):
    record = p.record
    unit = record.output_unit
    x_names = dict(input_name=record.input_name, input_unit=record.input_unit)
    y_names = dict(output_name=record.output_name, output_unit=unit)
    b = p.bands
    time, current, measured = p.time, p.current, p.measured
    error = p.error
    scored = np.flatnonzero(p.energised)
    worst = int(scored[np.argmax(np.abs(error[scored]))])
    band_arrays = (b.median, b.credible_lo, b.credible_hi, b.predictive_lo, b.predictive_hi)
    turns = find_reversals(current)
    branch_list = branches(current.size, turns)
    reversals = turns.index
    half = 0.5 * float(np.median((b.predictive_hi - b.predictive_lo)[p.energised]))
    zoom = zoom_samples(b.median, worst, half)
    yield (
        "input",
        plots.input_figure(time, current, reversals=reversals, **x_names),
        (
            f"The new record's drive in the scored window ({p.window[0]:.4g}-{p.window[1]:.4g} s); dots: its "
            f"{reversals.size} reversals."
        ),
    )
    yield (
        "displacement",
        plots.displacement_figure(
            time, measured, *band_arrays, title="Measured vs predicted displacement (no refit)", **y_names
        ),
        (
            f"Black: the new measurement. Red: pointwise median of {b.n_draws} posterior draws of the study's model "
            "on this "
            f"record's drive, with the 95 % credible band. Orange: 95 % predictive band (model plus sensor noise, σ = "
            f"{p.noise_sigma:.3g} {unit_label(unit)}); {100 * p.inside_predictive_band:.1f} % of the scored samples "
            "lie "
            "inside it (about 95 % when the model predicts this record as well as it fitted its own)."
        ),
    )
    window = (float(time[zoom.start]), float(time[zoom.stop - 1]))
    yield (
        "zoom",
        plots.displacement_figure(
            time,
            measured,
            *band_arrays,
            window=window,
            title=f"Zoom on the worst region: {window[0]:.4g}–{window[1]:.4g} s",
            **y_names,
        ),
        f"The samples around the largest prediction error (t = {time[worst]:.4g} s).",
    )
    energised_from = None if p.energised[0] else float(time[np.argmax(p.energised)])
    yield (
        "error",
        plots.error_figure(
            time,
            error,
            measured - b.credible_hi,
            measured - b.credible_lo,
            noise_sigma=p.noise_sigma,
            max_error_pct=p.max_error_pct,
            max_error_index=worst,
            output_unit=unit,
            energised_from=energised_from,
        ),
        (
            "Measurement minus the posterior-median prediction. Inside the blue ±2σ band the prediction is as good as "
            "the "
            "sensor; systematic excursions are what the model does not carry over to this record."
        ),
    )
    box = loop_zoom_box(current, measured, _BandView(b.predictive_lo, b.predictive_hi), zoom, p.energised)
    yield (
        "loops",
        plots.loops_figure(
            current,
            measured,
            b.median,
            b.credible_lo,
            b.credible_hi,
            segments=[(r.start, r.stop) for r in branch_list],
            rising=[r.rising for r in branch_list],
            zoom_box=box,
            **x_names,
            **y_names,
        ),
        (
            f"The record split at its input reversals into {len(branch_list)} branches (rising red, falling blue), "
            "each with "
            "the 95 % credible band over its own samples; right: zoom on the largest error."
        ),
    )
    profile = p.profile
    in_unit = record.input_unit
    yield (
        "where_1_residual_vs_time",
        residual_time_figure(profile, output_unit=unit, title="Where it fails: validation residual vs time"),
        (
            "The least-squares prediction's residual (the diagnosis' convention) with the reversals dashed, the ±2σ "
            "noise "
            "band and the RMS per cycle."
        ),
    )
    yield (
        "where_2_residual_vs_current",
        residual_branches_figure(profile, input_unit=in_unit, output_unit=unit),
        (
            "Binned residual against the drive, rising and falling branches apart: a branch-dependent offset is a "
            "hysteresis "
            "misfit, a drive-dependent trend a static one."
        ),
    )
    yield (
        "where_3_residual_vs_rate",
        residual_rate_figure(profile, input_unit=in_unit, output_unit=unit),
        (
            "Binned residual against the drive's rate and the time since the last reversal: rate dependence (lag) or "
            "slow "
            "relaxation (creep) show here."
        ),
    )
    yield (
        "where_4_cycles",
        cycles_figure(profile, output_unit=unit),
        "Per-cycle error and the level at every peak and trough.",
    )
    yield (
        "where_5_autocorrelation",
        residual_autocorrelation_figure(profile),
        ("Autocorrelation of the residual against the noise reference's: slow structure keeps it high."),
    )


def _prediction_tables(p) -> str:
    training = p.training
    unit = unit_label(p.record.output_unit)
    sigma_v, sigma_t = p.noise_sigma, training["noise_sigma"]

    def ratio(a, b):
        return None if a is None or not b else a / b

    rows = [
        [
            text_cell("samples scored (energised)"),
            number_cell(training.get("n_scored", training["n_samples"]), "training.n_scored"),
            number_cell(int(p.energised.sum()), "validation.n_scored"),
        ],
        [
            text_cell(f"sensor noise σ [{unit}]"),
            number_cell(sigma_t, "training.noise_sigma"),
            number_cell(sigma_v, "validation.noise_sigma"),
        ],
        [
            text_cell(f"RMS error, posterior median [{unit}]"),
            number_cell(training["rms"], "training.rms"),
            number_cell(p.rms, "validation.rms"),
        ],
        [
            text_cell("RMS / σ"),
            number_cell(ratio(training["rms"], sigma_t), "training.rms_ratio"),
            number_cell(ratio(p.rms, sigma_v), "validation.rms_ratio", css="alert" if p.rms > 1.2 * sigma_v else "ok"),
        ],
        [
            text_cell(f"RMS error, least squares [{unit}]"),
            number_cell(training["rms_lsq"], "training.rms_lsq"),
            number_cell(p.rms_lsq, "validation.rms_lsq"),
        ],
        [
            text_cell("max error, posterior median [% of range]"),
            number_cell(training["max_error_pct"], "training.max_error_pct"),
            number_cell(p.max_error_pct, "validation.max_error_pct"),
        ],
        [
            text_cell("max error, least squares [% of range]"),
            number_cell(training["max_error_pct_lsq"], "training.max_error_pct_lsq"),
            number_cell(p.max_error_pct_lsq, "validation.max_error_pct_lsq"),
        ],
        [
            text_cell("inside the 95 % predictive band [%]"),
            number_cell(100 * training["inside_predictive_band"], "training.inside_predictive_band_pct"),
            number_cell(100 * p.inside_predictive_band, "validation.inside_predictive_band_pct"),
        ],
        [
            text_cell("reduced χ² of the fit"),
            number_cell(training.get("reduced_chi2"), "training.reduced_chi2"),
            text_cell("— (no fit)"),
        ],
    ]
    return html_table(
        "validation-vs-training",
        ["quantity", "training (the study's record)", "validation (this record)"],
        rows,
        caption=f"Validation beside training: the same {training.get('n_draws', '')} posterior draws on both "
        "records, nothing refitted (the study report draws its own 200, so its posterior-median numbers can differ in "
        "the last digits; the least-squares numbers are the study's own)",
    )


#: The prediction's verdicts (``prediction.json`` ``verdict``) in words.
_VERDICTS = {
    "adequate": "adequate",
    "missing_effect": "an effect is missing",
    "tied": "tied",
    "unexplained": "unexplained",
    "parameters_differ": "the parameters differ",
    "not_adequate": "not adequate",
}


def _verdict_html(p) -> str:
    parts = ['<h2 id="verdict">3. Is the misfit noise? The diagnosis\' verdict</h2>']
    adequacy = p.adequacy
    text = {
        "adequate": "the validation residual is consistent with the sensor noise: the model carries over to this "
        "record.",
        "missing_effect": f"the record reveals the effect <b><code>{escape(str(p.missing))}</code></b>, which the "
        "study's model "
        "lacks; identify it again with <code>--effects "
        f"{escape(','.join(list(p.study.model.effect_names) + [str(p.missing)]))}</code>.",
        "tied": "the record reveals structure that several explanations repair and this record does not separate: "
        + " or ".join(f"<b><code>{escape(str(n))}</code></b>" for n in getattr(p.diagnosis, "tied", ()) or ())
        + ".",
        "unexplained": "structure remains in the validation residual that no effect of the library explains.",
        "parameters_differ": "the validation residual is not noise, yet no effect is missing: refitted on this record "
        "the "
        "same model is adequate, so the study's parameters do not carry over (they drifted between the records, or the "
        "study's record did not determine them where this one needs them).",
        "not_adequate": "the validation residual is not the sensor noise (the candidate search was not run: "
        "<code>--diagnosis adequacy</code>).",
    }[p.verdict]
    css = "ok" if p.verdict == "adequate" else "alert"
    parts.append(
        f'<div class="{css}" id="prediction-verdict">Verdict: '
        f'<b data-key="verdict">{escape(_VERDICTS[p.verdict])}</b>: {text}</div>'
    )
    a = adequacy.to_dict()

    z_critical = Thresholds().z_critical
    rows = [
        [text_cell(name), number_cell(z, f"adequacy.z.{name}", css="alert" if z > z_critical else None)]
        for name, z in a["z"].items()
    ]
    rows.append(
        [
            text_cell(f"structure RMS (slow part) [{unit_label(p.record.output_unit)}]"),
            number_cell(a["structure_rms"], "adequacy.structure_rms"),
        ]
    )
    rows.append(
        [
            text_cell(f"excess RMS over the noise [{unit_label(p.record.output_unit)}]"),
            number_cell(a["excess_rms"], "adequacy.excess_rms"),
        ]
    )
    parts.append(
        html_table(
            "adequacy-tests",
            ["noise test", "standardised excess z"],
            rows,
            caption=f"Noise tests on the least-squares validation residual: adequate unless a test has z > "
            f"{z_critical:g} and the misfit it sees is at least {Thresholds().structure_floor:g} σ",
        )
    )
    if p.diagnosis is not None:
        d = p.diagnosis
        refitted = not np.array_equal(np.asarray(d.fit.theta), np.asarray(p.study.fit.theta))
        about = (
            "The diagnosis refits the model's parameters on this record before it judges the residual, so its reason "
            "is about the refitted residual, not the study's residual in the table above: "
            if refitted
            else "The diagnosis, on the residual of the table above: "
        )
        parts.append(f'<p id="diagnosis-reason">{escape(about)}{plain_text(d.reason)}</p>')
        rows = []
        for c in d.ranking:
            c = c.to_dict()
            rows.append(
                [
                    text_cell(c.get("effect")),
                    number_cell(c.get("rms_after"), f"diagnosis.{c.get('effect')}.rms_after"),
                    number_cell(c.get("delta_bic"), f"diagnosis.{c.get('effect')}.delta_bic"),
                    number_cell(c.get("explained_fraction"), f"diagnosis.{c.get('effect')}.explained_fraction"),
                    text_cell("yes" if c.get("adequate_after") else "no"),
                ]
            )
        if rows:
            parts.append(
                html_table(
                    "diagnosis-ranking",
                    ["effect", "RMS after", "ΔBIC", "explained fraction", "adequate after"],
                    rows,
                    caption="Candidate effects on the validation window, best first (refitted on it)",
                )
            )
    return "\n".join(parts)


def prediction_files(p) -> dict:
    """``{name: bytes}``: ``prediction.json``, ``prediction.html`` and every figure as PNG."""
    files: dict[str, bytes] = {}
    figure_html = []
    for stem, figure, caption in _prediction_figures(p):
        png = png_bytes(figure, 100)
        files[f"{stem}.png"] = png
        figure_html.append((stem, embedded_figure(stem, PREDICTION_FIGURES[stem], png, caption)))
    diagnosis_html = []
    if p.diagnosis is not None:
        window_record = replace(p.record, time=p.time, current=p.current, displacement=p.measured)
        for stem, figure in diagnosis_figures(p.diagnosis, window_record).items():
            png = png_bytes(figure, 100)
            files[f"diagnosis/{stem}.png"] = png
            diagnosis_html.append(
                embedded_figure(
                    f"diagnosis-{stem}",
                    f"Diagnosis of the validation window: {stem.replace('_', ' ')}",
                    png,
                    f"From diagnosis/{stem}.png.",
                )
            )
    files["prediction.json"] = _json_bytes(p.to_dict())
    study = p.study
    unit = escape(unit_label(p.record.output_unit))  # page text: put into the markup below
    by_stem = dict(figure_html)
    effects = ", ".join(study.model.effect_names) or "none"
    glance_css = "ok" if p.verdict == "adequate" else "alert"
    body = [
        f"<p>Study <code>{escape(str(study.path))}</code> (GPI with {study.model.n_operators} operators, effects: "
        f"{plain_text(effects)}; trained on <code>{escape(str(p.training.get('file')))}</code>) applied to "
        f"<code>{escape(str(p.record.source))}</code>, window {p.window[0]:.6g}–{p.window[1]:.6g} s "
        f"({p.stop - p.start} samples, the model run from the record's first sample). Nothing is refitted.</p>",
        '<h2 id="glance">At a glance</h2>',
        f'<div class="{glance_css}" id="glance-box">Validation RMS <b data-key="rms">{number_text(p.rms, 4)}</b> '
        f"{unit} "
        f"= {p.rms / p.noise_sigma:.3g} σ (training {number_text(p.training['rms'], 4)} {unit}); max error "
        f'<b data-key="max_error_pct">{number_text(p.max_error_pct, 4)}</b> % of the range (training '
        f'{number_text(p.training["max_error_pct"], 4)} %); <span data-key="inside_predictive_band">'
        f"{100 * p.inside_predictive_band:.1f}</span> % inside the 95 % predictive band; verdict "
        f"<b>{escape(_VERDICTS[p.verdict])}</b>{' (<code>' + escape(str(p.missing)) + '</code>)' if p.missing else ''}"
        ".</div>",
        _notes_html(p.notes),
        _prediction_tables(p),
        '<h2 id="measurement">1. Measured vs predicted</h2>',
        *(by_stem[s] for s in ("input", "displacement", "zoom", "error", "loops")),
        '<h2 id="where">2. Where the prediction fails</h2>',
        *(by_stem[s] for s in by_stem if s.startswith("where_")),
        _verdict_html(p),
        *diagnosis_html,
        '<h2 id="provenance">4. Provenance</h2>',
        html_table(
            "provenance",
            ["item", "value"],
            [
                [text_cell("study folder"), text_cell(str(study.path))],
                [
                    text_cell("study data"),
                    text_cell(
                        f"{study.manifest.get('data', {}).get('file')} (sha256 "
                        f"{study.manifest.get('data', {}).get('sha256')})"
                    ),
                ],
                [text_cell("study converged"), text_cell("yes" if study.converged else "NOT CONVERGED")],
                [text_cell("record"), text_cell(f"{p.record.source} (sha256 {p.record.sha256 or '—'})")],
                [text_cell("posterior draws"), number_cell(p.bands.n_draws)],
                [text_cell("draws outside the model's domain"), number_cell(p.bands.n_outside)],
                *([[text_cell(f"time: {k} [s]"), number_cell(v, digits=3)] for k, v in p.seconds.items()]),
                [text_cell("written at (UTC)"), text_cell(now_iso())],
            ],
            caption="Provenance",
        ),
    ]
    title = f"Prediction report — {Path(str(p.record.source)).name} with the study {study.path.name}"
    files["prediction.html"] = _page(title, body)
    return files


# --------------------------------------------------------------------------------------
# compensation
# --------------------------------------------------------------------------------------
@styled
def compensation_target_figure(
    time, target, model_output, band_lo, band_hi, *, output_name="displacement", output_unit="um"
):
    """Target, the median model's output on the feedforward current, and the posterior's 95 % band of it."""
    fig = new_figure(10, 4.4)
    ax = fig.add_subplot()
    ax.fill_between(
        time,
        band_lo,
        band_hi,
        color=plots.MODEL_COLOUR,
        alpha=0.35,
        lw=0,
        label="95 % credible band: posterior draws on the feedforward current",
    )
    ax.plot(time, target, color=plots.MEASUREMENT_COLOUR, lw=1.6, label="target")
    ax.plot(time, model_output, color=plots.MODEL_COLOUR, lw=0.9, ls="--", label="median model on its feedforward")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label(output_name, output_unit))
    ax.set_title("Target and predicted displacement with the feedforward current")
    ax.legend(loc="best", fontsize=9)
    return fig


@styled
def compensation_current_figure(time, current, lo, hi, limits, *, input_name="current", input_unit="A", status=None):
    """The feedforward current with the band of the draws' own inverses and the current limits."""
    fig = new_figure(10, 4.0)
    ax = fig.add_subplot()
    ax.fill_between(time, lo, hi, color="tab:blue", alpha=0.3, lw=0, label="95 % band: each draw's own inverse")
    ax.plot(time, current, color="tab:blue", lw=1.0, label="feedforward (posterior median)")
    for limit in limits:
        ax.axhline(limit, color="grey", ls=":", lw=1.0)
    if status is not None and np.any(status != 0):
        k = np.flatnonzero(status != 0)
        ax.plot(time[k], current[k], "x", color="tab:red", ms=5, label="target not reached (limit or Omega gap)")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label(input_name, input_unit))
    ax.set_title(f"Feedforward {input_name} (limits {limits[0]:g}–{limits[1]:g} {unit_label(input_unit)} dotted)")
    ax.legend(loc="best", fontsize=9)
    return fig


@styled
def compensation_error_figure(
    time, median, lo, hi, predictive_lo, predictive_hi, self_error, *, noise_sigma, output_unit="um"
):
    """Predicted tracking error: posterior median, 95 % credible and predictive bands, the median model's own."""
    fig = new_figure(10, 4.4)
    ax = fig.add_subplot()
    ax.fill_between(
        time,
        predictive_lo,
        predictive_hi,
        color=plots.PREDICTIVE_COLOUR,
        alpha=0.25,
        lw=0,
        label=f"95 % predictive band (as measured, σ = {noise_sigma:.3g})",
    )
    ax.fill_between(time, lo, hi, color=plots.MODEL_COLOUR, alpha=0.45, lw=0, label="95 % credible band (displacement)")
    ax.plot(time, median, color=plots.MODEL_COLOUR, lw=0.9, label="posterior median")
    ax.plot(time, self_error, color="black", lw=0.8, label="median model on its own inverse")
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set(
        xlabel=axis_label("time", "s"),
        ylabel=axis_label("tracking error (model − target)", output_unit),
        title="Predicted tracking error of the feedforward current",
    )
    ax.legend(loc="best", fontsize=9)
    return fig


@styled
def compensation_loop_figure(
    target, current, *, input_name="current", input_unit="A", output_name="displacement", output_unit="um"
):
    """The inverse hysteresis: current against the target displacement."""
    fig = new_figure(7, 6)
    ax = fig.add_subplot()
    ax.plot(target, current, color="tab:blue", lw=0.8)
    ax.set_xlabel(axis_label(f"target {output_name}", output_unit))
    ax.set_ylabel(axis_label(f"feedforward {input_name}", input_unit))
    ax.set_title("The inverse loop")
    return fig


def _csv(header, columns, formats) -> bytes:
    lines = [",".join(header)]
    for row in zip(*columns):
        lines.append(",".join(f % v for f, v in zip(formats, row)))
    return ("\n".join(lines) + "\n").encode("ascii")


def compensation_files(c) -> dict:
    """``{name: bytes}``: ``compensation.csv`` (``time,current``), ``compensation.json``, the bands CSV, page,
    figures."""
    study = c.study
    record = study.record
    unit, in_unit = record.output_unit, record.input_unit
    t, y = c.target.time, c.target.displacement
    files: dict[str, bytes] = {}
    files["compensation.csv"] = _csv(["time", "current"], [t, c.current], ["%.17g", "%.17g"])
    files["compensation_bands.csv"] = _csv(
        [
            "time",
            "target",
            "current",
            "current_lo95",
            "current_hi95",
            "model_output",
            "status",
            "error_median",
            "error_lo95",
            "error_hi95",
            "measured_error_lo95",
            "measured_error_hi95",
        ],
        [
            t,
            y,
            c.current,
            c.current_lo,
            c.current_hi,
            c.model_output,
            c.status,
            c.error_median,
            c.error_lo,
            c.error_hi,
            c.predictive_lo,
            c.predictive_hi,
        ],
        ["%.17g"] * 6 + ["%d"] + ["%.17g"] * 5,
    )
    files["compensation.json"] = _json_bytes(c.to_dict())
    figures = {
        "comp_target": (
            compensation_target_figure(
                t, y, c.model_output, y + c.error_lo, y + c.error_hi, output_name=record.output_name, output_unit=unit
            ),
            "Black: the target. Red: the band of the true displacement the posterior predicts when the "
            "feedforward current drives the transducer; dashed: the median model itself (on the target where "
            "its inverse is exact).",
        ),
        "comp_current": (
            compensation_current_figure(
                t,
                c.current,
                c.current_lo,
                c.current_hi,
                c.current_range,
                input_name=record.input_name,
                input_unit=in_unit,
                status=c.status,
            ),
            "The current to apply (compensation.csv). The band: every posterior draw inverted on its own; "
            "its width is how precisely the identification determines the feedforward.",
        ),
        "comp_error": (
            compensation_error_figure(
                t,
                c.error_median,
                c.error_lo,
                c.error_hi,
                c.predictive_lo,
                c.predictive_hi,
                c.model_output - y,
                noise_sigma=c.summary["noise_sigma"],
                output_unit=unit,
            ),
            "Tracking error the posterior predicts for the feedforward current (identification error only: "
            "the inverse of each model is exact). Credible band: the true displacement; predictive band: a "
            "sensor with the study's noise.",
        ),
        "comp_loop": (
            compensation_loop_figure(
                y,
                c.current,
                input_name=record.input_name,
                input_unit=in_unit,
                output_name=record.output_name,
                output_unit=unit,
            ),
            "The current against the target: the inverse of the hysteresis loop; the steps at the target's "
            "reversals take back Omega's branch switch.",
        ),
    }
    figure_html = []
    for stem, (figure, caption) in figures.items():
        png = png_bytes(figure, 100)
        files[f"{stem}.png"] = png
        figure_html.append(embedded_figure(stem, COMPENSATION_FIGURES[stem], png, caption))
    s = c.summary
    te, mt = s["tracking_error"], s["model_tracking"]
    u = unit_label(unit)
    rows = [
        [
            text_cell(f"tracking error RMS [{u}]"),
            number_cell(te["rms"]["median"], "tracking_error.rms.median"),
            number_cell(te["rms"]["lo95"], "tracking_error.rms.lo95"),
            number_cell(te["rms"]["hi95"], "tracking_error.rms.hi95"),
        ],
        [
            text_cell("tracking error RMS [% of the target's range]"),
            number_cell(te["rms_pct"]["median"], "tracking_error.rms_pct.median"),
            number_cell(te["rms_pct"]["lo95"], "tracking_error.rms_pct.lo95"),
            number_cell(te["rms_pct"]["hi95"], "tracking_error.rms_pct.hi95"),
        ],
        [
            text_cell(f"max |tracking error| [{u}]"),
            number_cell(te["max_abs"]["median"], "tracking_error.max_abs.median"),
            number_cell(te["max_abs"]["lo95"], "tracking_error.max_abs.lo95"),
            number_cell(te["max_abs"]["hi95"], "tracking_error.max_abs.hi95"),
        ],
        [
            text_cell("max |tracking error| [% of the target's range]"),
            number_cell(te["max_abs_pct"]["median"], "tracking_error.max_abs_pct.median"),
            number_cell(te["max_abs_pct"]["lo95"], "tracking_error.max_abs_pct.lo95"),
            number_cell(te["max_abs_pct"]["hi95"], "tracking_error.max_abs_pct.hi95"),
        ],
    ]
    counts = mt["samples"]
    inverse_rows = [
        [
            text_cell(f"median model on its own inverse: RMS / max [{u}]"),
            text_cell(f"{number_text(mt['rms'], 3)} / {number_text(mt['max_abs'], 3)}"),
        ],
        [
            text_cell("samples exact / at a current limit / in an Omega gap"),
            text_cell(f"{counts['exact']} / {counts['saturated']} / {counts['branch']}"),
        ],
        [
            text_cell(f"feedforward current range [{unit_label(in_unit)}]"),
            text_cell(f"{s['current']['min']:.4g} – {s['current']['max']:.4g}"),
        ],
        [
            text_cell(f"half-width of the draws' current band, median [{unit_label(in_unit)}]"),
            number_cell(s["current"]["draws_band_half_width_median"]),
        ],
        [text_cell("posterior draws (outside the domain)"), text_cell(f"{s['n_draws']} ({s['n_outside']})")],
        [
            text_cell("model steps evaluated per sample (median inverse)"),
            number_cell(s["inverse"]["evaluations_per_sample"], digits=3),
        ],
        *([[text_cell(f"time: {k} [s]"), number_cell(v, digits=3)] for k, v in c.seconds.items()]),
    ]
    effects = ", ".join(study.model.effect_names) or "none"
    body = [
        f"<p>Study <code>{escape(str(study.path))}</code> (GPI with {study.model.n_operators} operators, effects: "
        f"{plain_text(effects)}); target <code>{escape(c.target.source)}</code>, {t.size} samples, "
        f"{y.min():.6g}–{y.max():.6g} {escape(u)}; current limits {c.current_range[0]:g}–{c.current_range[1]:g} "
        f"{escape(unit_label(in_unit))}. The feedforward current is the exact inverse of the posterior-median model "
        "(<code>model.inverse</code>: a root find per sample carried forward with the model's state); the tracking "
        "error below is what the posterior predicts when that current drives the transducer.</p>",
        _notes_html(c.notes),
        html_table(
            "tracking-error",
            ["quantity", "median over draws", "2.5 %", "97.5 %"],
            rows,
            caption="Predicted tracking error (posterior draws driven by the feedforward current)",
        ),
        html_table("inverse", ["quantity", "value"], inverse_rows, caption="The inverse"),
        *figure_html,
    ]
    files["compensation.html"] = _page(
        f"Compensation — {Path(c.target.source).name} with the study {study.path.name}", body
    )
    return files
