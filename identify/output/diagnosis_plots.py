"""Figures of the diagnosis: where the model fails, and the error before and after adding an effect.

Every function takes already computed numbers (a :class:`~identify.diagnosis.residuals.ResidualProfile`,
a :class:`~identify.diagnosis.diagnose.Diagnosis`, arrays) and returns a
:class:`matplotlib.figure.Figure` made without :mod:`matplotlib.pyplot` (Agg canvas, no
global figure registry, no display needed); nothing here fits or evaluates a model.
The model output of a fit is ``data - residual``. Save with
``fig.savefig(path, format="png")``. :data:`FIGURES` lists the figures
:func:`diagnosis_figures` makes, by file stem.

Colours as the report's: measurement black, model before red, model after green,
rising branch red, falling branch blue.
"""

from __future__ import annotations

import numpy as np

from .plots import axis_label, legend_below, new_figure, styled, unit_label

__all__ = [
    "residual_time_figure",
    "residual_branches_figure",
    "residual_rate_figure",
    "cycles_figure",
    "residual_autocorrelation_figure",
    "before_after_loops_figure",
    "before_after_error_figure",
    "ranking_figure",
    "diagnosis_figures",
    "FIGURES",
]

MEASUREMENT_COLOUR = "black"
BEFORE_COLOUR = "tab:red"
AFTER_COLOUR = "tab:green"
RISING_COLOUR = "tab:red"
FALLING_COLOUR = "tab:blue"
NOISE_COLOUR = "0.6"
_MAX_POINTS = 4000


def _thin(n, max_points=_MAX_POINTS):
    """Indices of at most ``max_points`` evenly spread samples of ``n`` (for scatter backgrounds)."""
    step = max(1, int(np.ceil(n / max_points)))
    return np.arange(0, n, step)


def _mark_reversals(ax, profile, with_labels=True):
    for k, kind in zip(profile.reversals.index, profile.reversals.kind):
        colour = RISING_COLOUR if kind > 0 else FALLING_COLOUR
        ax.axvline(profile.time[k], color=colour, lw=0.7, alpha=0.5, ls="--")
    if with_labels and len(profile.reversals):
        ax.plot([], [], color=RISING_COLOUR, ls="--", lw=0.7, label="input peak")
        ax.plot([], [], color=FALLING_COLOUR, ls="--", lw=0.7, label="input trough")


@styled
def residual_time_figure(profile, *, output_unit="um", title=None):
    """Residual against time with the input reversals marked, the noise band and per-cycle RMS.

    Parameters
    ----------
    profile : ResidualProfile
    output_unit : str, default "um"
    title : str, optional
    """
    fig = new_figure(11, 4.2)
    ax = fig.add_subplot()
    sigma = profile.noise.sigma
    ax.plot(profile.time, profile.residual, color=MEASUREMENT_COLOUR, lw=0.5, label="residual (data - model)")
    ax.axhspan(-2 * sigma, 2 * sigma, color=NOISE_COLOUR, alpha=0.25, label="±2σ noise (quiet segment)")
    if len(profile.cycles):
        edges = np.append(profile.cycles.t_start, profile.cycles.t_stop[-1])
        ax.stairs(profile.cycles.rms, edges, color="tab:orange", lw=2, label="RMS per cycle")
    _mark_reversals(ax, profile)
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label("residual", output_unit))
    ax.set_title(title or "Where it fails: residual vs time (reversals dashed)")
    ax.legend(loc="upper right", ncols=3, fontsize=9)
    return fig


@styled
def residual_branches_figure(profile, *, input_unit="A", output_unit="um"):
    """Residual against the drive, rising and falling branches apart (binned mean ± 2 s.e.)."""
    fig = new_figure(9, 4.8)
    ax = fig.add_subplot()
    mask = profile.energised
    for label, direction, colour, binned in (
        ("rising", 1, RISING_COLOUR, profile.rising),
        ("falling", -1, FALLING_COLOUR, profile.falling),
    ):
        select = mask & (profile.direction == direction)
        x = profile.current[select]
        y = profile.residual[select]
        keep = _thin(x.size, _MAX_POINTS // 2)
        ax.plot(x[keep], y[keep], ".", ms=1.5, color=colour, alpha=0.25)
        ok = binned.count > 0
        ax.errorbar(
            binned.centres[ok],
            binned.mean[ok],
            yerr=2 * np.nan_to_num(binned.sem[ok]),
            color=colour,
            lw=2,
            marker="o",
            ms=4,
            capsize=2,
            label=f"{label} branch: binned mean ± 2 s.e.",
        )
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xlabel(axis_label("input current", input_unit))
    ax.set_ylabel(axis_label("residual", output_unit))
    ax.set_title("Where it fails: residual vs current, by branch")
    ax.legend(loc="best")
    return fig


@styled
def residual_rate_figure(profile, *, input_unit="A", output_unit="um"):
    """Residual (binned mean and RMS) against input rate, against time since the last reversal
    and, where the profile has it, against the model's output (bins of equal count)."""
    views = [
        (profile.by_rate, axis_label("input rate", f"{unit_label(input_unit)}/s"), "vs input rate"),
        (profile.by_since_reversal, axis_label("time since last reversal", "s"), "vs time since reversal"),
    ]
    if profile.by_level is not None:
        views.append((profile.by_level, axis_label("model output", output_unit), "vs model output"))
    fig = new_figure(5.5 * len(views), 4.2)
    axes = fig.subplots(1, len(views))
    for ax, (binned, xlabel, title) in zip(axes, views):
        ok = binned.count > 0
        ax.errorbar(
            binned.centres[ok],
            binned.mean[ok],
            yerr=2 * np.nan_to_num(binned.sem[ok]),
            color="tab:purple",
            marker="o",
            ms=4,
            capsize=2,
            label="mean ± 2 s.e.",
        )
        ax.plot(binned.centres[ok], binned.rms[ok], color="tab:orange", marker="s", ms=3, label="RMS")
        ax.axhline(profile.noise.sigma, color=NOISE_COLOUR, ls=":", label="noise σ")
        ax.axhline(0.0, color="0.3", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(axis_label("residual", output_unit))
        ax.set_title(f"Residual {title}")
        ax.legend(loc="best", fontsize=9)
    return fig


@styled
def cycles_figure(profile, *, output_unit="um"):
    """Cycle by cycle: RMS and max error (% of range), and the residual level at each peak and trough."""
    fig = new_figure(11, 4.2)
    axes = fig.subplots(1, 2)
    cyc = profile.cycles
    centre = 0.5 * (cyc.t_start + cyc.t_stop)
    ax = axes[0]
    ax.plot(centre, cyc.rms, "o-", color="tab:orange", label="RMS per cycle")
    ax.axhline(profile.noise.sigma, color=NOISE_COLOUR, ls=":", label="noise σ")
    ax.set_xlabel(axis_label("cycle centre time", "s"))
    ax.set_ylabel(axis_label("RMS error", output_unit))
    twin = ax.twinx()
    twin.plot(centre, cyc.max_error_pct, "s--", color="tab:brown", label="max error (right)")
    twin.set_ylabel(axis_label("max |error| / output range", "%"))
    twin.grid(False)
    lines = ax.get_legend_handles_labels()
    lines2 = twin.get_legend_handles_labels()
    ax.set_title("Error per cycle (trough to trough)")
    ax = axes[1]
    ext = profile.extrema
    peaks = ext.kind > 0
    ax.plot(ext.time[peaks], ext.residual[peaks], "^-", color=RISING_COLOUR, label="at input peaks")
    ax.plot(ext.time[~peaks], ext.residual[~peaks], "v-", color=FALLING_COLOUR, label="at input troughs")
    ax.axhspan(
        -2 * profile.noise.sigma / np.sqrt(5),
        2 * profile.noise.sigma / np.sqrt(5),
        color=NOISE_COLOUR,
        alpha=0.25,
        label="±2σ/√5 (5-sample mean)",
    )
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set(
        xlabel=axis_label("time", "s"),
        ylabel=axis_label("residual", output_unit),
        title="Residual at the reversals, cycle by cycle",
    )
    more = ax.get_legend_handles_labels()
    legend_below(
        fig, handles=lines[0] + lines2[0] + more[0], labels=lines[1] + lines2[1] + more[1], ncols=6, fontsize=9
    )
    return fig


@styled
def residual_autocorrelation_figure(profile):
    """Residual autocorrelation against the quiet segment's, with the whiteness tests' results."""
    fig = new_figure(9, 4.2)
    ax = fig.add_subplot()
    n = int(profile.energised.sum())
    ax.plot(profile.lags, profile.residual_acf, "o-", ms=3, color=BEFORE_COLOUR, label="residual (energised part)")
    ax.plot(profile.lags, profile.quiet_acf, "s-", ms=3, color=NOISE_COLOUR, label="quiet segment (noise)")
    ax.plot(
        profile.lags,
        profile.noise.autocorrelation(int(profile.lags[-1])),
        ":",
        color="tab:blue",
        label=f"AR({profile.noise.order}) noise model",
    )
    band = 2.0 / np.sqrt(max(n, 1))
    ax.axhspan(-band, band, color=NOISE_COLOUR, alpha=0.2, label="±2/√n")
    tests = profile.tests
    text = "\n".join(f"{name}: z = {t.z:.1f}" for name, t in tests.items())
    ax.set_xlabel(axis_label("lag", "samples"))
    ax.set_ylabel("autocorrelation [-]")
    ax.set_title("Is the residual noise? Autocorrelation vs the quiet segment")
    # beside the data: the curves, then the whiteness tests' z as the legend's title
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=9, title=text, title_fontsize=9)
    return fig


@styled
def before_after_loops_figure(
    current,
    displacement,
    model_before,
    model_after,
    energised,
    *,
    after_label="after",
    input_unit="A",
    output_unit="um",
):
    """Hysteresis loops: measurement, model before and after adding the effect, overlaid.

    Parameters
    ----------
    current, displacement : ndarray, shape (T,)
    model_before, model_after : ndarray, shape (T,)
        Model outputs (``data - residual`` of each fit).
    energised : ndarray of bool, shape (T,)
    after_label : str
        Legend text of the after model (e.g. ``"GPI + thermal"``).
    """
    fig = new_figure(11, 5)
    axes = fig.subplots(1, 2)
    x = current[energised]
    ax = axes[0]
    ax.plot(x, displacement[energised], color=MEASUREMENT_COLOUR, lw=0.6, label="measurement")
    ax.plot(x, model_before[energised], color=BEFORE_COLOUR, lw=0.9, label="model before")
    ax.plot(x, model_after[energised], color=AFTER_COLOUR, lw=0.9, ls="--", label=f"model {after_label}")
    ax.set_xlabel(axis_label("input current", input_unit))
    ax.set_ylabel(axis_label("displacement", output_unit))
    ax.set_title("Loops: measurement and models")
    ax.legend(loc="upper left")
    ax = axes[1]
    ax.plot(x, (displacement - model_before)[energised], ".", ms=1.5, color=BEFORE_COLOUR, alpha=0.4, label="before")
    ax.plot(x, (displacement - model_after)[energised], ".", ms=1.5, color=AFTER_COLOUR, alpha=0.4, label=after_label)
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xlabel(axis_label("input current", input_unit))
    ax.set_ylabel(axis_label("residual", output_unit))
    ax.set_title("Residual vs current, before and after")
    ax.legend(loc="best", markerscale=6)
    return fig


@styled
def before_after_error_figure(
    time, residual_before, residual_after, noise_sigma, *, after_label="after", output_unit="um"
):
    """Error against time before and after adding the effect, with the noise band."""
    fig = new_figure(11, 4.2)
    ax = fig.add_subplot()
    ax.plot(time, residual_before, color=BEFORE_COLOUR, lw=0.5, label="before")
    ax.plot(time, residual_after, color=AFTER_COLOUR, lw=0.5, alpha=0.8, label=after_label)
    ax.axhspan(-2 * noise_sigma, 2 * noise_sigma, color=NOISE_COLOUR, alpha=0.25, label="±2σ noise")
    ax.set_xlabel(axis_label("time", "s"))
    ax.set_ylabel(axis_label("residual", output_unit))
    ax.set_title("Error vs time: watch it fall")
    ax.legend(loc="upper right", ncols=3)
    return fig


@styled
def ranking_figure(diagnosis, *, output_unit="um"):
    """Candidates side by side: RMS after, max error % after, delta BIC and explained fraction.

    Horizontal bars, one row per candidate named once on the left (in words: ``rate_width`` ->
    "rate width"), so long names never run into each other whatever their number."""
    ranking = diagnosis.ranking
    names = ["model as given"] + [c.effect.replace("_", " ") for c in ranking]
    rms = [diagnosis.rms] + [c.rms_after for c in ranking]
    max_pct = [diagnosis.max_error_pct] + [
        c.max_error_pct_after if c.max_error_pct_after is not None else np.nan for c in ranking
    ]
    tied = set(getattr(diagnosis, "tied", ()))
    colours = ["0.5"] + [
        AFTER_COLOUR
        if c.effect == diagnosis.missing
        else ("tab:purple" if c.effect in tied else ("tab:olive" if c.refitted else "0.75"))
        for c in ranking
    ]
    rows = np.arange(len(names))
    fig = new_figure(13, 1.6 + 0.32 * len(names))
    axes = fig.subplots(1, 4, sharey=True)
    ax = axes[0]
    ax.barh(rows, rms, color=colours)
    ax.axvline(diagnosis.noise_sigma, color="black", ls=":", label="noise σ")
    ax.set_xlabel(axis_label("RMS error", output_unit))
    ax.set_title("RMS")
    ax = axes[1]
    ax.barh(rows, max_pct, color=colours)
    ax.set_xlabel(axis_label("max |error| / range", "%"))
    ax.set_title("Max error (refitted only)")
    ax = axes[2]
    ax.barh(rows[1:], [c.delta_bic for c in ranking], color=colours[1:])
    ax.axvline(diagnosis.thresholds.bic_significant, color="black", ls="--", label="significant BIC gain")
    ax.set_xscale("symlog", linthresh=10.0)
    ax.set_xlabel("BIC gain [-]")
    ax.set_title("Comparison statistic")
    ax = axes[3]
    ax.barh(rows[1:], [100 * c.explained for c in ranking], color=colours[1:])
    ax.set_xlim(0, 105)
    ax.set_xlabel(axis_label("misfit explained", "%"))
    ax.set_title("Explained fraction")
    axes[0].set_yticks(rows, names)
    axes[0].invert_yaxis()  # the model as given on top, then the candidates best first
    handles = axes[0].get_legend_handles_labels()
    more = axes[2].get_legend_handles_labels()
    legend_below(fig, handles=handles[0] + more[0], labels=handles[1] + more[1], ncols=2, fontsize=9)
    fig.suptitle(f"Candidates (verdict: {diagnosis.verdict_text().replace('missing_effect', 'missing effect')})")
    return fig


#: File stems written by :func:`diagnosis_figures`, in order; the before/after ones only
#: when a candidate was refitted.
FIGURES = (
    "1_residual_vs_time",
    "2_residual_vs_current",
    "3_residual_vs_rate",
    "4_cycles",
    "5_autocorrelation",
    "6_candidates",
    "7_before_after_loops",
    "8_before_after_error",
)


def diagnosis_figures(diagnosis, record) -> dict:
    """Every figure of a diagnosis, ``{file stem: Figure}`` (see :data:`FIGURES`).

    Parameters
    ----------
    diagnosis : Diagnosis
    record : Record
        The record diagnosed (units and measured displacement).
    """
    profile = diagnosis.profile
    out_unit = getattr(record, "output_unit", "um")
    in_unit = getattr(record, "input_unit", "A")
    figures = {
        "1_residual_vs_time": residual_time_figure(profile, output_unit=out_unit),
        "2_residual_vs_current": residual_branches_figure(profile, input_unit=in_unit, output_unit=out_unit),
        "3_residual_vs_rate": residual_rate_figure(profile, input_unit=in_unit, output_unit=out_unit),
        "4_cycles": cycles_figure(profile, output_unit=out_unit),
        "5_autocorrelation": residual_autocorrelation_figure(profile),
        "6_candidates": ranking_figure(diagnosis, output_unit=out_unit),
    }
    best = diagnosis.best
    if best is not None and best.fit is not None:
        data = np.asarray(record.displacement, dtype=float)
        before = data - diagnosis.fit.residual
        after = data - best.fit.residual
        label = "GPI + " + " + ".join(best.fit.model.effect_names)
        figures["7_before_after_loops"] = before_after_loops_figure(
            record.current,
            data,
            before,
            after,
            profile.energised,
            after_label=label,
            input_unit=in_unit,
            output_unit=out_unit,
        )
        figures["8_before_after_error"] = before_after_error_figure(
            record.time,
            diagnosis.fit.residual,
            best.fit.residual,
            diagnosis.noise_sigma,
            after_label=label,
            output_unit=out_unit,
        )
    return figures
