"""``python -m identify paper``: Table 1 on the paper's input, as the paper's figures, with the reading's evidence.

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

import argparse
import sys
import time as wallclock
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model import INPUT_READINGS, QUIET_SECONDS, READINGS, TABLE1, envelope, gpi, paper_current

from . import options
from ..data.fileio import atomic_write

__all__ = ["HELP", "add_arguments", "run", "ReadingEvidence", "reading_evidence", "FIGURE_FILES", "N_OPERATORS"]

HELP = "simulate Table 1 on the paper's input: Figs. 5, 6, 8 and the evidence for the reading of eq. (5)"

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
    "literal": "rising branch along eq. (7) (the b-envelope), falling along eq. (6) (the a-envelope), as eq. (5) labels them",
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``paper`` options to ``parser``."""
    parser.add_argument(
        "--out", required=True, type=options.folder_path, metavar="DIR", help="folder to write the figures and paper.md into"
    )
    parser.add_argument("--fs", type=float, default=100.0, metavar="HZ", help="sampling rate of the input in Hz (default 100)")
    parser.add_argument(
        "--input", choices=INPUT_READINGS, default="literal",
        help="reading of eq. (16)'s decay: literal (as printed, default) or centred (as the text says)",
    )  # fmt: skip
    parser.add_argument(
        "--reading", choices=sorted(READINGS), default="swapped",
        help="reading of eq. (5): swapped (rising along eq. (6), default) or literal (rising along eq. (7))",
    )  # fmt: skip


def _save_figure(figure, path: Path) -> None:
    atomic_write(path, lambda fh: figure.savefig(fh, format="png", dpi=110))


def _make_figures(time, current, chosen, other, input_reading):
    """The four figures as ``{key: matplotlib.figure.Figure}`` (Agg canvas, no pyplot)."""
    from matplotlib.figure import Figure

    model_label = f"GPI, Table 1 ({chosen.reading} reading)"
    figures = {}

    figure = Figure(figsize=(8, 3.6), layout="constrained")
    axes = figure.add_subplot()
    axes.plot(time, current, color="black", lw=1.0)
    axes.set(xlabel="time [s]", ylabel="current [A]", title=f"Fig. 5: input signal, eqs. (14)-(17) ({input_reading} reading of eq. (16))")
    axes.axvline(QUIET_SECONDS, color="grey", lw=0.8, ls=":")
    axes.grid(alpha=0.3)
    figures["input"] = figure

    figure = Figure(figsize=(8, 3.6), layout="constrained")
    axes = figure.add_subplot()
    axes.plot(time, chosen.displacement, color="red", lw=1.0, label=model_label)
    axes.set(xlabel="time [s]", ylabel="displacement [µm]", title="Fig. 6: displacement vs time (simulation; the measurement is not published)")
    axes.legend(loc="upper right")
    axes.grid(alpha=0.3)
    figures["displacement"] = figure

    figure = Figure(figsize=(6, 4.8), layout="constrained")
    axes = figure.add_subplot()
    axes.plot(current, chosen.displacement, color="red", lw=0.8, label=model_label)
    axes.set(xlabel="current [A]", ylabel="displacement [µm]", title="Fig. 8: displacement vs current")
    axes.legend(loc="upper left")
    axes.grid(alpha=0.3)
    figures["loops"] = figure

    figure = Figure(figsize=(11, 4.2), layout="constrained")
    over_time, over_current = figure.subplots(1, 2)
    styles = {"swapped": dict(color="red", lw=1.0), "literal": dict(color="tab:blue", lw=0.8, ls="--")}
    for evidence in (chosen, other):
        label = f"{evidence.reading} reading (rest {evidence.rest_um:.1f} µm)"
        over_time.plot(time, evidence.displacement, label=label, **styles[evidence.reading])
        over_current.plot(current, evidence.displacement, label=f"{evidence.reading} reading", **styles[evidence.reading])
    for axes in (over_time, over_current):
        axes.axhline(0.0, color="grey", lw=0.8, ls=":")
        axes.grid(alpha=0.3)
    over_time.set(xlabel="time [s]", ylabel="displacement [µm]", title="Table 1 under both readings of eq. (5)")
    over_current.set(xlabel="current [A]", ylabel="displacement [µm]", title="the same vs current")
    over_time.legend(loc="lower right")
    figures["readings"] = figure
    return figures


def _markdown(args, time, chosen, other):
    rows = []
    for evidence in (chosen, other):
        used = " (used)" if evidence is chosen else ""
        crossing = f"{100 * evidence.crossing_fraction:.0f} %"
        rows.append(
            f"| {evidence.reading}{used} | {evidence.rest_um:.4f} | {evidence.quiet_spread_um:.3g} | {evidence.min_um:.2f} | "
            f"{evidence.max_um:.2f} | {evidence.range_um:.2f} | {evidence.smallest_margin:.4f} at {evidence.margin_at_current:.2f} A | {crossing} |"
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

Generated by `python -m identify paper --out {args.out} --fs {args.fs:g} --input {args.input} --reading {args.reading}`
on {wallclock.strftime('%Y-%m-%d %H:%M')}.

- Model: generalized Prandtl-Ishlinskii, eqs. (5)-(13), Table 1 parameters, N = {N_OPERATORS} operators
  (`model.gpi`).
- Input: eqs. (14)-(17) sampled at {args.fs:g} Hz ({time.size} samples, 0-{time[-1]:g} s), **{args.input}** reading:
  {_INPUT_WORDS[args.input]}.
- **Reading of eq. (5) used: {chosen.reading}**: {_READING_WORDS[chosen.reading]}.

## Evidence

| reading | rest, t = 0 [µm] | spread over the quiet first 10 s [µm] | min [µm] | max [µm] | range [µm] | smallest bound margin (upper - lower) | samples with crossing bounds |
|---|---|---|---|---|---|---|---|
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


def run(args) -> int:
    """Simulate, write the figures and ``paper.md`` into ``args.out``; 0 on success, 2 on bad options."""
    try:
        time, current = paper_current(args.fs, args.input)
    except ValueError as error:
        print(f"paper: {error}", file=sys.stderr)
        return 2
    chosen = reading_evidence(time, current, args.reading)
    other = reading_evidence(time, current, "literal" if args.reading == "swapped" else "swapped")

    import matplotlib

    matplotlib.use("Agg")
    from ..data.locks import FolderLock

    out = Path(args.out)
    with FolderLock(out, command=f"python -m identify paper --out {out}"):
        for key, figure in _make_figures(time, current, chosen, other, args.input).items():
            _save_figure(figure, out / FIGURE_FILES[key])
        text = _markdown(args, time, chosen, other)
        atomic_write(out / "paper.md", text)

    for evidence in (chosen, other):
        print(
            f"{evidence.reading:>8} reading: rest {evidence.rest_um:9.4f} um, min {evidence.min_um:8.2f}, "
            f"max {evidence.max_um:8.2f}, smallest bound margin {evidence.smallest_margin:+.4f}"
        )
    print(f"wrote {', '.join(FIGURE_FILES.values())} and paper.md to {out}")
    return 0
