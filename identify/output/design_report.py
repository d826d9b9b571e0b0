"""What ``design`` leaves behind: the proposed drive, its numbers and a page.

``next_input.csv`` (``time,current``: the drive to apply, from 0 s at the records' sampling rate,
starting with the quiet segment), ``design.json`` (the contenders, the limits, every ordered
pair's predicted gap with its noise sd and chance of a right name, the confirmation's realised
gaps) and ``design.html`` with the figures ``design_drive.png`` (the drive) and
``design_predictions.png`` (each contender's predicted response on it, and where they diverge).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..data.fileio import atomic_write_bytes, atomic_write_text
from .page import embedded_figure, escape, html_page, html_table, number_cell, plain_text, png_bytes, text_cell
from .plots import axis_label, new_figure, styled

__all__ = ["write_design", "DESIGN_FILES"]

#: The files a design writes, by role.
DESIGN_FILES = {
    "drive": "next_input.csv",
    "json": "design.json",
    "page": "design.html",
    "drive_figure": "design_drive.png",
    "predictions_figure": "design_predictions.png",
}


@styled
def _drive_figure(time, current, unit: str):
    fig = new_figure(10, 3.2)
    ax = fig.subplots()
    ax.plot(time, current, color="black", lw=1.2)
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label("drive current", unit))
    ax.set_title("The proposed next record's drive")
    return fig


@styled
def _predictions_figure(time, predictions: dict, output_unit: str):
    fig = new_figure(10, 6.0)
    top, bottom = fig.subplots(2, 1, sharex=True)
    names = list(predictions)
    for name in names:
        top.plot(time, predictions[name], lw=1.1, label=name)
    top.set_ylabel(axis_label("predicted displacement", output_unit))
    top.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    reference = predictions[names[0]]
    for name in names[1:]:
        bottom.plot(time, predictions[name] - reference, lw=1.1, label=f"{name} minus {names[0]}")
    bottom.axhline(0.0, color="0.6", lw=0.8)
    bottom.set_xlabel(axis_label("time", "s"))
    bottom.set_ylabel(axis_label("difference", output_unit))
    bottom.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    top.set_title("Each contender's response to the proposed drive, and where they diverge")
    return fig


def _predictions(design) -> dict:
    drive = design.best
    found = {}
    for c in design.contenders:
        y, valid = c.model.evaluate(c.theta, drive.time, drive.current)
        if valid[0]:
            found[c.name] = y[0]
    return found


def _pairs_table(design) -> str:
    confirmed = {(c["truth"], c["rival"]): c for c in design.best.confirmed}
    rows = []
    for p in design.best.pairs:
        c = confirmed.get((p["truth"], p["rival"]))
        simulated = c is not None and c.get("gap") is not None
        realised = f"{c['gap']:.4g} ± {c['gap_sd']:.3g} ({len(c['realised_gaps'])} draws)" if simulated else "—"
        right = f"{c['right_names']} of {c['draws']}" if c else "—"
        rows.append(
            [
                text_cell(p["truth"]),
                text_cell(p["rival"]),
                number_cell(p["gap"], digits=4),
                number_cell(p["noise_sd"], digits=3),
                number_cell(100.0 * p["p_right"], digits=3),
                text_cell(realised),
                text_cell(right),
            ]
        )
    header = [
        "truth",
        "rival",
        "predicted gap",
        "noise sd of the gap",
        "chance of a right name (%)",
        "simulated gap (mean ± sd)",
        "right names in the simulation",
    ]
    caption = "Every ordered pair: the chi-square gap after the rival is refitted to mimic the truth"
    return html_table("design-pairs", header, rows, caption=caption)


def _limits_table(design, input_unit: str) -> str:
    limits = design.limits
    lo, hi = limits.current_range
    rows = [
        [text_cell("current range"), text_cell(f"{lo:g} to {hi:g} {input_unit}")],
        [text_cell("largest slew"), text_cell(f"{limits.max_slew:.4g} {input_unit}/s")],
        [text_cell("duration"), text_cell(f"{limits.duration:g} s")],
        *(
            [[text_cell("longest record the rig takes"), text_cell(f"{limits.longest_record:g} s")]]
            if limits.longest_record > limits.duration
            else []
        ),
        [text_cell("largest RMS current (heating)"), text_cell(f"{limits.max_rms_current:.4g} {input_unit}")],
        [text_cell("sampling rate"), text_cell(f"{limits.fs:g} Hz")],
        [text_cell("quiet start"), text_cell(f"{limits.quiet:g} s")],
    ]
    return html_table("design-limits", ["limit", "value"], rows, caption="The rig's limits the drive keeps")


def write_design(design, out, *, input_unit: str = "A", output_unit: str = "um") -> dict:
    """Write the design's files into folder ``out`` (:data:`DESIGN_FILES`); ``{role: path}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    drive = design.best
    lines = ["time,current"] + [f"{t:.10g},{i:.10g}" for t, i in zip(drive.time, drive.current)]
    paths = {role: out / name for role, name in DESIGN_FILES.items()}
    atomic_write_text(paths["drive"], "\n".join(lines) + "\n")
    predictions = _predictions(design)
    figures = {
        "drive_figure": png_bytes(_drive_figure(drive.time, drive.current, input_unit), 110),
        "predictions_figure": png_bytes(_predictions_figure(drive.time, predictions, output_unit), 110),
    }
    for role, data in figures.items():
        atomic_write_bytes(paths[role], data)
    content = design.to_dict() | {"files": {role: p.name for role, p in paths.items()}}
    atomic_write_text(paths["json"], json.dumps(content, indent=1))
    body = [
        f'<div class="ok" id="design-verdict">{plain_text(design.reason)}</div>',
        f"<p>Contenders: {plain_text(', '.join(c.name for c in design.contenders))}. Apply "
        f"<code>{escape(DESIGN_FILES['drive'])}</code> to the transducer, record it with the same sensor, and "
        "diagnose all records together (<code>python -m identify diagnose A.csv B.csv</code>).</p>",
        _pairs_table(design),
        _limits_table(design, input_unit),
        embedded_figure(
            "design-drive",
            "The proposed drive",
            figures["drive_figure"],
            f"The '{drive.family}' drive, within the limits above.",
        ),
        embedded_figure(
            "design-predictions",
            "Predictions",
            figures["predictions_figure"],
            "Each contender's fit driven by the proposed current; below, their differences: where the "
            "record will tell them apart.",
        ),
    ]
    atomic_write_text(paths["page"], html_page("The next record: a drive that decides", body))
    return paths


def predicted_divergence(design) -> float:
    """The largest difference between two contenders' predictions on the proposed drive [output unit]."""
    predictions = list(_predictions(design).values())
    if len(predictions) < 2:
        return 0.0
    stack = np.vstack(predictions)
    return float(np.max(stack.max(axis=0) - stack.min(axis=0)))
