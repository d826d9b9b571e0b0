"""The HTML sections of the study's report, each a function of the read folder and its analysis.

"At a glance" (:func:`glance_html`: convergence, residual vs noise, the next step),
"2. Fit quality" (:func:`fit_quality_html`), "3. Parameters" (:func:`parameters_html`: the
table, priors, how far the intervals can be trusted, sampling settings, identifiability),
"4. Diagnosis" (:func:`diagnosis_html`) and "5. Provenance" (:func:`provenance_html`); and
the verdict "far above the noise" (:func:`residual_above_noise`, with the limits
:data:`RMS_RATIO_LIMIT` and :data:`REDUCED_CHI2_LIMIT`). Every function returns ready
markup (strings from outside the code escaped through :mod:`identify.output.page`); the
page is assembled by :mod:`identify.output.report`.
"""

from __future__ import annotations

import math

from model import EFFECTS

from ..fitting.posterior import BENCH_COVERAGE
from . import plots, results
from .diagnosis_files import DIAGNOSIS_FIGURES, DIAGNOSIS_FILE, next_step
from .page import escape, html_table, linked_figure, number_cell, number_text, plain_text, text_cell
from .report_analysis import ReportAnalysis, ReportData

__all__ = [
    "RMS_RATIO_LIMIT",
    "REDUCED_CHI2_LIMIT",
    "STATUS_LABELS",
    "residual_above_noise",
    "fit_verdict",
    "glance_html",
    "next_step_html",
    "fit_quality_html",
    "calibration_reading",
    "parameters_html",
    "priors_html",
    "identifiability_html",
    "diagnosis_html",
    "provenance_html",
]

#: Residual RMS above this multiple of the noise sigma is "far above the noise".
RMS_RATIO_LIMIT = 1.2
#: Reduced chi-square above this is "far above the noise".
REDUCED_CHI2_LIMIT = 1.5


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
    return fit_verdict(summary, float(sigma))[1]


def fit_verdict(summary, noise_sigma):
    """(RMS / sigma, far above the noise?) from the least-squares numbers of ``summary``."""
    fit = summary["fit"]
    ratio = float(fit["rms"]) / noise_sigma
    chi2 = fit.get("reduced_chi2")
    misfit = ratio > RMS_RATIO_LIMIT or (chi2 is not None and chi2 > REDUCED_CHI2_LIMIT)
    return ratio, misfit


def glance_html(data: ReportData, analysis: ReportAnalysis) -> str:
    summary, posterior, fit = data.summary, data.summary["posterior"], data.summary["fit"]
    record = data.record
    unit = escape(plots.unit_label(record.output_unit))  # page text: put into the markup below
    ratio, misfit = fit_verdict(summary, data.noise_sigma)
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
        parts.append(next_step_html(data))
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


def next_step_html(data: ReportData) -> str:
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


def fit_quality_html(data: ReportData, analysis: ReportAnalysis) -> str:
    summary, fit, noise = data.summary, data.summary["fit"], data.summary["noise"]
    record = data.record
    unit = plots.unit_label(record.output_unit)
    ratio, _ = fit_verdict(summary, data.noise_sigma)
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


def calibration_reading(coverage: dict) -> str:
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


def parameters_html(data: ReportData, analysis: ReportAnalysis, figures_html: str) -> str:
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
    parts.append(priors_html(summary.get("priors"), summary["parameters"]))
    parts.append(
        '<p class="note" id="interval-calibration">How far to trust the intervals: on the virtual bench '
        f"({BENCH_COVERAGE['n_records']} seeded records, truth known; docs/method.md) the posterior 95 % "
        f"intervals covered the truth at {BENCH_COVERAGE['posterior']:.3f} ± {BENCH_COVERAGE['posterior_se']:.3f} and "
        f"the least-squares ones (estimate ± 1.96 std. errors) at {BENCH_COVERAGE['least_squares']:.3f} ± "
        f"{BENCH_COVERAGE['least_squares_se']:.3f} (nominal {BENCH_COVERAGE['nominal']:.2f}; ± is the standard error "
        f"across records). {calibration_reading(BENCH_COVERAGE)} Off the bench, both are conditional on the model: "
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
    parts.append(identifiability_html(summary.get("identifiability")))
    return "\n".join(parts)


def priors_html(priors, parameters) -> str:
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


def identifiability_html(identifiability) -> str:
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


def diagnosis_html(data: ReportData) -> str:
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
            linked_figure(
                f"diagnosis-{path.stem}",
                alt,
                f"{DIAGNOSIS_FIGURES}/{path.name}",
                f"From {DIAGNOSIS_FIGURES}/{path.name}.",
            )
        )
    return "\n".join(parts)


def _effect_parameters_cell(parameters: dict) -> str:
    """A ranking entry's fitted effect parameters as a readable ``name = value unit`` list.

    ``parameters`` is ``{parameter name: value}`` (``diagnosis.json``'s ranking entry); the
    unit comes from the effect library (:data:`model.EFFECTS`), blank when unknown.
    """
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


def provenance_html(data: ReportData, analysis: ReportAnalysis, seconds: float) -> str:
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
