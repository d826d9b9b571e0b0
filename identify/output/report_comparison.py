"""Before and after: the comparison of a study with an earlier study of the same record.

``study --compare`` (or a study that finds its predecessor by the manifest) leaves
``DIR/comparison.json`` naming the earlier folder; :func:`load_comparison` evaluates both
least-squares models on this record (:class:`Comparison`: curves, errors, RMS, max error,
per-cycle errors), :func:`comparison_figure` draws loops, errors and per-cycle RMS, and
:func:`comparison_html` writes the section "Before and after" of the report.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import plots, results
from .diagnosis_files import COMPARISON_FILE
from .page import escape, html_table, number_cell, number_text, text_cell
from .report_analysis import ReportAnalysis, ReportData, cycle_errors

__all__ = ["Comparison", "load_comparison", "comparison_figure", "comparison_html", "COMPARISON_FIGURE"]

#: The comparison's figure (written only when the study is compared with an earlier one).
COMPARISON_FIGURE = {"comparison": "Before and after: the earlier study's model and this one's"}


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


def load_comparison(data: ReportData, analysis: ReportAnalysis) -> Comparison | str | None:
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


def comparison_html(data: ReportData, comparison, figure_html: str) -> str:
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
