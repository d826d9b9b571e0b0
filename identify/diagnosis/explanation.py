"""The explanation: a decision and its evidence in sentences a user reads.

Every sentence states the comparison that was made, with the digits that show it: a test's
``z`` against its threshold, a misfit's size against the floor, a gap between two explanations
against what the noise gives it. A tie says what would tell the tied effects apart in another
record (each effect's :attr:`model.Effect.signature`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from model import EFFECTS

from .adequacy import Adequacy, Thresholds, excess_over_noise, rms_change_and_size
from .decision import Decision
from .evidence import Evidence, Explanation

__all__ = ["TEXTS", "explain", "noise_tests_text", "telling_apart", "figure", "below_text", "where_text"]


def figure(x: float) -> str:
    """``x`` as text: whole numbers from 100 up, three significant digits below."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def below_text(x: float, limit: float, decimals=(1, 2, 3)) -> str:
    """``x``, which is below ``limit``, with the fewest of ``decimals`` that still show it below
    (truncated at the last where none does): 2.497 against 2.5 reads "2.497", never "2.5 < 2.5"."""
    for digits in decimals:
        text = f"{x:.{digits}f}"
        if float(text) < limit:
            return text
    last = decimals[-1]
    return f"{math.floor(x * 10**last) / 10**last:.{last}f}"


def noise_tests_text(adequacy: Adequacy, th: Thresholds) -> str:
    """One sentence stating the comparison the adequacy rule made."""
    zc = th.z_critical
    if not adequacy.failed:
        largest = below_text(max(adequacy.z.values()), zc)
        return f"The residual passes the noise tests: no test's excess reaches z = {zc:g} (largest {largest})."
    failed = ", ".join(f"{name} z {adequacy.z[name]:.1f}" for name in adequacy.failed)
    if adequacy.adequate:
        size = below_text(adequacy.size_ratio, th.structure_floor, (3, 4, 5))
        return (
            f"The residual is at the noise level up to a negligible misfit: tests above z = {zc:g} ({failed}) "
            f"see a non-noise part of {size} sigma, below the {th.structure_floor:g} sigma floor."
        )
    return (
        f"The residual is not noise (tests above z = {zc:g}: {failed}; non-noise part "
        f"{adequacy.size_ratio:.2f} sigma >= the {th.structure_floor:g} sigma floor)."
    )


def telling_apart(*names: str) -> str:
    """What would tell effects ``names`` apart in another record, as one sentence (empty with
    fewer than two single library effects among them)."""
    singles = sorted({n for name in names for n in name.split("+")})
    parts = [f"'{n}' {EFFECTS[n].signature}" for n in singles if n in EFFECTS and EFFECTS[n].signature]
    if len(parts) < 2:
        return ""
    return " What would tell them apart: " + "; ".join(parts) + "."


def _one(e: Explanation, ev: Evidence) -> str:
    state = "consistent with the noise" if e.adequate else "structure left"
    return (
        f"'{e.name}' (delta BIC {e.delta_bic:.0f}, RMS {ev.baseline_rms:.4g} -> {e.rms:.4g}, "
        f"explains {100 * e.explained:.0f} %, {state})"
    )


def _apart(row: dict, th: Thresholds) -> str:
    """Why a rival is not separated from the best, as a clause."""
    if row["better"] != row.get("best", row["better"]) or row["gap"] <= 0:
        return "fits at least as well"
    if row["gap"] <= th.bic_significant:
        return f"{figure(row['gap'])} apart in likelihood, not more than {th.bic_significant:g}"
    return (
        f"{figure(row['gap'])} apart, but the noise alone moves that gap by {figure(row['noise_sd'])} "
        f"(one standard deviation; {below_text(row['z'], th.gap_z)} sd < {th.gap_z:g})"
    )


def _closest(ev: Evidence, d: Decision, th: Thresholds) -> str:
    """The rival closest to the named explanation, with the separation the data show."""
    rows = [r for r in d.numbers.get("rivals", []) if r["better"] == d.best and r["other"] != d.best]
    if not rows:
        return ""
    row = min(rows, key=lambda r: r["z"])
    return (
        f" The data separate it from every other explanation (closest: '{row['other']}', "
        f"{figure(row['gap'])} apart, {figure(row['z'])} noise standard deviations of the gap)."
    )


def _first_loading_caution(d: Decision) -> str:
    share = d.numbers.get("first_loading_share")
    if share is None or share < 0.95:
        return ""
    return (
        f" Caution: {100 * share:.1f} % of what '{d.missing}' adds lies in the first loading (before the drive's "
        "first reversal), so the record cannot tell it from other physics that changes only the first loading: a "
        "virgin material that trains at once, the memory a run before the record left ('initial_state'), or a gap "
        "in the output that closes on the first rise. A record that starts with a few small cycles tells them apart."
    )


def _candidates(ev: Evidence) -> str:
    ranked = sorted(ev.explanations, key=lambda e: e.chi2)[:4]
    return "; ".join(_one(e, ev) for e in ranked) if ranked else "none refitted"


@dataclass(frozen=True)
class _Context:
    """What every rule's text draws on."""

    d: Decision
    ev: Evidence
    th: Thresholds
    tests: str
    best: Explanation | None
    tail: str


def _noise(c: _Context) -> str:
    return c.tests


def _negligible(c: _Context) -> str:
    change, _ = rms_change_and_size(c.ev.baseline_rms, c.best.rms, c.ev.sigma)
    excess = excess_over_noise(c.ev.baseline_rms, c.ev.sigma)
    return (
        f"{c.tests} The targeted refit of '{c.best.name}' (delta BIC {c.best.delta_bic:.0f}) changes the RMS by "
        f"{100 * change:.2f} %, but the residual holds {excess:.2f} sigma in excess of the noise, below the "
        f"{c.th.structure_floor:g} sigma floor: there is nothing to explain, so it is not a finding."
    )


def _too_small(c: _Context) -> str:
    change, size = rms_change_and_size(c.ev.baseline_rms, c.best.rms, c.ev.sigma)
    return (
        f"{c.tests} The best candidate that reaches the noise, '{c.best.name}' (delta BIC {c.best.delta_bic:.0f}), "
        f"would change the RMS by {100 * change:.2f} % and explain {size:.2f} sigma of structure: below the "
        f"practical size ({100 * c.th.practical_rms_change:g} % and {c.th.structure_floor:g} sigma), so nothing "
        "is named."
    )


def _first_loading_only(c: _Context) -> str:
    share = c.d.numbers.get("first_loading_share") or 0.0
    return (
        f"{c.tests} The targeted refit of '{c.best.name}' (delta BIC {c.best.delta_bic:.0f}) puts {100 * share:.1f} % "
        "of its part of the fit in the first loading (before the drive's first reversal): the record has one "
        "first loading and cannot tell a small misfit there from other physics that acts on it alone, so it is "
        "not a finding. A record that starts with a few small cycles can tell them apart."
    )


def _none_repairs(c: _Context) -> str:
    if not c.ev.explanations:  # nothing was fitted: say so rather than what fits would have shown
        return (
            f"{c.tests} No library effect promised to lower the misfit in the search (screening and short "
            f"refits), so none was fitted on the whole record and none is named.{c.tail}"
        )
    return (
        f"{c.tests} No library effect, alone or with another, leaves a residual consistent with the noise, so "
        f"none is named.{c.tail}"
    )


def _first_loading_again(c: _Context) -> str:
    share = c.d.numbers.get("first_loading_share") or 0.0
    held = ", ".join(f"'{n}'" for n in c.ev.first_cycle)
    return (
        f"{c.tests} The best explanation, '{c.best.name}', puts {100 * share:.1f} % of its part of the fit in the "
        f"first loading (before the drive's first reversal), and the model already has first-cycle physics "
        f"({held}): the record has one first loading and cannot tell a further part of it from another form of "
        f"that physics, so nothing is named.{c.tail}"
    )


def _tied(c: _Context) -> str:
    rows = {r["other"]: r for r in c.d.numbers.get("rivals", [])}
    parts = [_one(c.best, c.ev)]
    for name in c.d.tied[1:]:
        detail = f": {_apart(rows[name] | {'best': c.d.best}, c.th)}" if name in rows else ""
        parts.append(_one(c.ev.explanation(name), c.ev) + detail)
    return (
        f"{c.tests} These explanations fit the record about equally well and the data do not separate them, so "
        "none is named (tied): " + "; ".join(parts) + "." + telling_apart(*c.d.tied) + " Another record can decide "
        "between them: one with a hold at constant current and a quiet end, or a joint diagnosis with the "
        "records you have."
    )


def _alternatives(d: Decision) -> str:
    if not d.tied:
        return ""
    return (
        " Every explanation the data cannot separate from it contains it too ("
        + ", ".join(f"'{n}'" for n in d.tied)
        + ")."
    )


def _share(explained: float) -> str:
    """What an explanation removes: its share of the misfit, or, where the baseline's misfit measure
    was already at the noise's (the structure was in the tests' pattern, not in the size), that."""
    if explained > 0:
        return f"{100 * explained:.0f} % of the misfit"
    return "the structure the noise tests found (the misfit's size was already within the noise)"


def _named(c: _Context) -> str:
    d, best = c.d, c.best
    return (
        f"Adding '{d.missing}' explains {_share(best.explained)} (delta BIC {best.delta_bic:.0f}) "
        "and leaves a residual consistent with the noise."
        + (_alternatives(d) if d.tied else _closest(c.ev, d, c.th))
        + _first_loading_caution(d)
    )


def _named_from_pair(c: _Context) -> str:
    d, best, strength = c.d, c.best, c.ev.strength
    stronger = ""
    if d.partner in strength and d.missing in strength:
        stronger = (
            f" (the stronger of the two alone: delta BIC {strength[d.missing]:.0f} against "
            f"{strength[d.partner]:.0f} for '{d.partner}')"
        )
    lead = (
        f"Two effects seem to be missing: '{d.missing}' and '{d.partner}' together"
        if d.partner
        else (f"The explanation '{best.name}'")
    )
    return (
        f"{lead} explain {_share(best.explained)} (delta BIC {best.delta_bic:.0f}; RMS "
        f"{c.ev.baseline_rms:.4g} -> {best.rms:.4g}, consistent with the noise).{_alternatives(d)} Add "
        f"'{d.missing}'{stronger} and diagnose again." + _first_loading_caution(d)
    )


#: rule -> its text (one for every rule of :data:`identify.diagnosis.decision.RULES`).
TEXTS = {
    "noise": _noise,
    "negligible": _negligible,
    "too_small": _too_small,
    "first_loading_only": _first_loading_only,
    "none_repairs": _none_repairs,
    "first_loading_again": _first_loading_again,
    "tied": _tied,
    "named": _named,
    "named_from_pair": _named_from_pair,
}


def explain(d: Decision, ev: Evidence, th: Thresholds | None = None, where: str = "") -> str:
    """The reason of a decision, in sentences (module docstring; one text per rule, :data:`TEXTS`).

    Parameters
    ----------
    d : Decision
    ev : Evidence
    th : Thresholds, optional
    where : str
        A sentence on where the error concentrates, appended where nothing is named.
    """
    th = Thresholds() if th is None else th
    tail = f" Candidates: {_candidates(ev)}." + (f" {where}" if where else "")
    best = ev.explanation(d.best) if d.best else None
    return TEXTS[d.rule](_Context(d, ev, th, noise_tests_text(ev.baseline, th), best, tail))


def where_text(profile, z_critical: float = Thresholds.z_critical) -> str:
    """One sentence on where the error of a residual profile concentrates (largest per-cycle RMS,
    rising against falling branches, and the output levels where the residual has a mean when
    the level test's ``z`` exceeds ``z_critical``); empty when there is nothing to say."""
    parts = []
    level = profile.tests.get("level")
    if level is not None and level.z > z_critical:
        lo, hi = level.details["level_range"]
        parts.append(f"a mean error of {level.details['mean']:+.3g} at model outputs {lo:.4g} to {hi:.4g}")
    if len(profile.cycles):
        worst = int(np.argmax(profile.cycles.rms))
        parts.append(
            f"the largest cycle RMS ({profile.cycles.rms[worst]:.3g}) is in {profile.cycles.t_start[worst]:.1f}-"
            f"{profile.cycles.t_stop[worst]:.1f} s"
        )
    rising = profile.rising.rms[np.isfinite(profile.rising.rms)]
    falling = profile.falling.rms[np.isfinite(profile.falling.rms)]
    if rising.size and falling.size:
        r, f = float(np.sqrt(np.mean(rising**2))), float(np.sqrt(np.mean(falling**2)))
        parts.append(f"rising-branch RMS {r:.3g} vs falling {f:.3g}")
    return ("Where: " + "; ".join(parts) + ".") if parts else ""
