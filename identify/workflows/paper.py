"""Table 1 on the paper's input, as the paper's figures, with the reading's evidence (``python -m identify paper``).

Example::

    python -m identify paper --out reports/paper

writes into ``reports/paper``:

``fig5_input.png``
    drive current vs time (the paper's Fig. 5);
``fig6_displacement.png``
    simulated displacement vs time (Fig. 6, model line only: the measurement is not published);
``fig8_loops.png``
    displacement vs current (Fig. 8);
``readings.png``
    both readings of eq. (5) side by side, vs time and vs current: the evidence for the default;
``paper.md``
    the reading used and its evidence (rest level, extremes, range, operator-bound margins
    for both readings).

Every file is written to a temporary name and renamed, so an interrupted run leaves no
half-written file.
"""

from __future__ import annotations

import time as wallclock
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from model import QUIET_SECONDS, READINGS, TABLE1, envelope, gpi, paper_current

from ..data.fileio import atomic_write
from ..data.locks import FolderLock

__all__ = ["ReadingEvidence", "reading_evidence", "paper_input", "write_paper", "FIGURE_FILES", "N_OPERATORS"]


#: Number of operators used by the paper.
N_OPERATORS = 12

#: figure key -> file name, in the order paper.md lists them.
FIGURE_FILES = {
    "input": "fig5_input.png",
    "displacement": "fig6_displacement.png",
    "loops": "fig8_loops.png",
    "readings": "readings.png",
}

_READING_WORDS = {
    "swapped": "rising branch along eq. (6) (the a-envelope), falling along eq. (7) (the b-envelope)",
    "literal": "rising branch along eq. (7) (the b-envelope), falling along eq. (6) (the a-envelope), as eq. (5) "
    "labels them",
}
_INPUT_WORDS = {
    "literal": "eq. (16) as printed multiplies the whole signal: troughs stay at 0 A, peaks fall toward 2.5 A at 70 s",
    "centred": "only the sine's amplitude decays, so peaks and troughs close in on the 2.5 A line",
}


@dataclass(frozen=True)
class ReadingEvidence:
    """What Table 1 does on one input under one reading of eq. (5).

    Attributes
    ----------
    reading : str
        ``"swapped"`` or ``"literal"`` (see :mod:`model.gpi`).
    displacement : ndarray, shape (T,)
        The response [um].
    rest_um : float
        Response at ``t = 0``, coils off [um]; the paper says the model output is 0 there.
    quiet_spread_um : float
        Peak-to-peak response over the unenergised first 10 s [um].
    min_um, max_um, range_um : float
        Extremes and their difference over the record [um].
    smallest_margin : float
        ``min over samples and operators of (upper bound - lower bound)`` [A-units of the
        envelopes]; negative means the bounds cross (the operator is not a clamp).
    margin_at_current : float
        Drive current where the smallest margin occurs [A].
    crossing_fraction : float
        Fraction of samples at which the bounds of at least one operator cross.
    """

    reading: str
    displacement: np.ndarray
    rest_um: float
    quiet_spread_um: float
    min_um: float
    max_um: float
    range_um: float
    smallest_margin: float
    margin_at_current: float
    crossing_fraction: float


_EVIDENCE_COLUMNS = (
    "reading",
    "rest, t = 0 [µm]",
    "spread over the quiet first 10 s [µm]",
    "min [µm]",
    "max [µm]",
    "range [µm]",
    "smallest bound margin (upper - lower)",
    "samples with crossing bounds",
)
_EVIDENCE_HEADER = "| " + " | ".join(_EVIDENCE_COLUMNS) + " |\n" + "|---" * len(_EVIDENCE_COLUMNS) + "|"


def reading_evidence(time, current, reading, theta=TABLE1, n_operators=N_OPERATORS):
    """Simulate ``theta`` under ``reading`` and summarise the evidence for that reading.

    Parameters
    ----------
    time : ndarray, shape (T,)
        Sample times [s].
    current : ndarray, shape (T,)
        Drive current [A].
    reading : {"swapped", "literal"}
    theta : ndarray, shape (19,), default Table 1
    n_operators : int, default 12

    Returns
    -------
    ReadingEvidence
    """
    displacement = gpi(theta, current, n_operators, reading=reading)
    rising_slice, falling_slice = (slice(3, 7), slice(7, 11)) if READINGS[reading] else (slice(7, 11), slice(3, 7))
    thresholds = theta[0] * np.arange(1, n_operators + 1)
    # upper_j - lower_j = falling + r_j - (rising - r_j); smallest at the smallest r_j.
    margins = envelope(theta[falling_slice], current) - envelope(theta[rising_slice], current) + 2.0 * thresholds.min()
    worst = int(np.argmin(margins))
    quiet = displacement[time < QUIET_SECONDS]
    return ReadingEvidence(
        reading=reading,
        displacement=displacement,
        rest_um=float(displacement[0]),
        quiet_spread_um=float(np.ptp(quiet)) if quiet.size else 0.0,
        min_um=float(displacement.min()),
        max_um=float(displacement.max()),
        range_um=float(np.ptp(displacement)),
        smallest_margin=float(margins[worst]),
        margin_at_current=float(current[worst]),
        crossing_fraction=float(np.mean(margins < 0.0)),
    )


def _save_figure(figure, path: Path) -> None:
    atomic_write(path, lambda fh: figure.savefig(fh, format="png", dpi=110))


def _single_curve_figure(figsize, x, y, *, xlabel, ylabel, title, label=None, legend_loc=None, **style):
    """One curve on one grid-lined axes, labelled; returns ``(figure, axes)`` (Agg canvas, no pyplot)."""
    figure = Figure(figsize=figsize, layout="constrained")
    axes = figure.add_subplot()
    axes.plot(x, y, label=label, **style)
    axes.set(xlabel=xlabel, ylabel=ylabel, title=title)
    if legend_loc is not None:
        axes.legend(loc=legend_loc)
    axes.grid(alpha=0.3)
    return figure, axes


def _make_figures(time, current, chosen, other, input_reading):
    """The four figures as ``{key: matplotlib.figure.Figure}`` (Agg canvas, no pyplot)."""
    model_label = f"GPI, Table 1 ({chosen.reading} reading)"
    figures = {}
    figures["input"], axes = _single_curve_figure(
        (8, 3.6),
        time,
        current,
        color="black",
        lw=1.0,
        xlabel="time [s]",
        ylabel="current [A]",
        title=f"Fig. 5: input signal, eqs. (14)-(17) ({input_reading} reading of eq. (16))",
    )
    axes.axvline(QUIET_SECONDS, color="grey", lw=0.8, ls=":")
    figures["displacement"], _ = _single_curve_figure(
        (8, 3.6),
        time,
        chosen.displacement,
        color="red",
        lw=1.0,
        label=model_label,
        legend_loc="upper right",
        xlabel="time [s]",
        ylabel="displacement [µm]",
        title="Fig. 6: displacement vs time (simulation; the measurement is not published)",
    )
    figures["loops"], _ = _single_curve_figure(
        (6, 4.8),
        current,
        chosen.displacement,
        color="red",
        lw=0.8,
        label=model_label,
        legend_loc="upper left",
        xlabel="current [A]",
        ylabel="displacement [µm]",
        title="Fig. 8: displacement vs current",
    )

    figure = Figure(figsize=(11, 4.2), layout="constrained")
    over_time, over_current = figure.subplots(1, 2)
    styles = {"swapped": dict(color="red", lw=1.0), "literal": dict(color="tab:blue", lw=0.8, ls="--")}
    for evidence in (chosen, other):
        label = f"{evidence.reading} reading (rest {evidence.rest_um:.1f} µm)"
        over_time.plot(time, evidence.displacement, label=label, **styles[evidence.reading])
        over_current.plot(
            current, evidence.displacement, label=f"{evidence.reading} reading", **styles[evidence.reading]
        )
    for axes in (over_time, over_current):
        axes.axhline(0.0, color="grey", lw=0.8, ls=":")
        axes.grid(alpha=0.3)
    over_time.set(xlabel="time [s]", ylabel="displacement [µm]", title="Table 1 under both readings of eq. (5)")
    over_current.set(xlabel="current [A]", ylabel="displacement [µm]", title="the same vs current")
    over_time.legend(loc="lower right")
    figures["readings"] = figure
    return figures


def _markdown(out, fs, input_reading, reading, time, chosen, other):
    rows = []
    for evidence in (chosen, other):
        used = " (used)" if evidence is chosen else ""
        crossing = f"{100 * evidence.crossing_fraction:.0f} %"
        rows.append(
            f"| {evidence.reading}{used} | {evidence.rest_um:.4f} | {evidence.quiet_spread_um:.3g} | "
            f"{evidence.min_um:.2f} | "
            f"{evidence.max_um:.2f} | {evidence.range_um:.2f} | {evidence.smallest_margin:.4f} at "
            f"{evidence.margin_at_current:.2f} A | {crossing} |"
        )
    swapped, literal = (chosen, other) if chosen.reading == "swapped" else (other, chosen)
    figures = "\n".join(
        f"- [`{name}`]({name}): {text}"
        for name, text in (
            (FIGURE_FILES["input"], "drive current vs time (paper's Fig. 5)"),
            (FIGURE_FILES["displacement"], "displacement vs time (Fig. 6, simulation only)"),
            (FIGURE_FILES["loops"], "displacement vs current (Fig. 8)"),
            (FIGURE_FILES["readings"], "both readings of eq. (5), vs time and vs current"),
        )
    )
    return f"""# Table 1 of the seed paper on its own input

Generated by `python -m identify paper --out {out} --fs {fs:g} --input {input_reading} --reading {reading}`
on {wallclock.strftime("%Y-%m-%d %H:%M")}.

- Model: generalized Prandtl-Ishlinskii, eqs. (5)-(13), Table 1 parameters, N = {N_OPERATORS} operators
  (`model.gpi`).
- Input: eqs. (14)-(17) sampled at {fs:g} Hz ({time.size} samples, 0-{time[-1]:g} s), **{input_reading}** reading:
  {_INPUT_WORDS[input_reading]}.
- **Reading of eq. (5) used: {chosen.reading}**: {_READING_WORDS[chosen.reading]}.

## Evidence

{_EVIDENCE_HEADER}
{chr(10).join(rows)}

The paper says the model output is 0 while the transducer is not energised (first 10 s).
The swapped reading rests at {swapped.rest_um:.2f} µm and rises to {swapped.max_um:.1f} µm; its
operator bounds stay apart on the whole input (smallest margin {swapped.smallest_margin:.4f} at
{swapped.margin_at_current:.2f} A), so every operator is a well-defined clamp. The literal reading
rests at {literal.rest_um:.1f} µm, swings between {literal.min_um:.1f} and {literal.max_um:.1f} µm,
and its bounds cross at {100 * literal.crossing_fraction:.0f} % of the samples: not a transducer.

## Figures

{figures}
"""


def paper_input(fs: float = 100.0, input_reading: str = "literal"):
    """The paper's drive current (eqs. (14)-(17)) sampled at ``fs`` Hz: ``(time, current)``.

    Raises
    ------
    ValueError
        An invalid ``fs`` or ``input_reading``.
    """
    return paper_current(fs, input_reading)


def write_paper(out, time, current, *, fs: float = 100.0, input_reading: str = "literal", reading: str = "swapped"):
    """Write the figures (:data:`FIGURE_FILES`) and ``paper.md`` into ``out`` (locked meanwhile).

    Parameters
    ----------
    out : str or os.PathLike
        Folder (created).
    time, current : ndarray
        The paper's input (:func:`paper_input`).
    fs, input_reading, reading
        How the input was sampled and read, and the reading of eq. (5) used.

    Returns
    -------
    tuple of ReadingEvidence
        The evidence of the reading used, then of the other one.
    """
    chosen = reading_evidence(time, current, reading)
    other = reading_evidence(time, current, "literal" if reading == "swapped" else "swapped")

    matplotlib.use("Agg")

    folder = Path(out)
    with FolderLock(folder, command=f"python -m identify paper --out {folder}"):
        for key, figure in _make_figures(time, current, chosen, other, input_reading).items():
            _save_figure(figure, folder / FIGURE_FILES[key])
        text = _markdown(out, fs, input_reading, reading, time, chosen, other)
        atomic_write(folder / "paper.md", text)
    return chosen, other
