"""The decision: a pure function of the evidence, one rule table.

An explanation (an effect, or a pair of effects, added to the model) *repairs* the model when
its residual passes the noise tests, it is needed (delta BIC against the baseline above
``bic_significant``: the nested question, its parameters charged) and what it explains matters
against the noise (the practical size). Then:

1. The repairing explanations are reduced to the minimal ones: a pair that is not needed beside
   a member that repairs alone says nothing more than that member; a member is dropped where a
   pair that contains it is needed beside it.
2. The best is the repairing explanation of lowest chi-square. Its rivals are every other
   explanation the search finished, repairing or not, that the data do not separate from it:
   a likelihood gap of at most ``bic_significant``, or within ``gap_z`` noise standard
   deviations of the gap (:mod:`identify.diagnosis.evidence`). Parameters are not counted
   here: a penalty for parameters may say whether a term or a second effect is needed, never
   which physics it is. So explanations are compared at the same number of effects: a pair
   that is best is also compared with the pairs that add nothing beside a single that repairs
   alone (that single given a second effect's freedom, as the best has).
3. The verdict is what all of them share: one effect common to the best and its rivals is
   named (from a pair, the member stronger alone); none in common is a tie, and ``tied`` lists
   them. A tie is a verdict: the record cannot tell them apart, and another record can.

:data:`RULES` lists every rule with its status and its reason; :func:`decide` returns the
:class:`Decision` with the rule that made it and the numbers behind it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .adequacy import Thresholds, excess_over_noise, rms_change_and_size
from .evidence import Evidence, Explanation, Gap

__all__ = ["STATUSES", "RULES", "Decision", "decide", "repairs", "separated", "FIRST_LOADING_SHARE"]

#: The four verdicts.
STATUSES = ("adequate", "missing_effect", "tied", "unexplained")

#: A name whose part of the fit lies at least this share (in squares) in the first loading rests
#: on one stretch of the record: the record has one first loading, and physics that acts there
#: alone (a virgin material that trains at once, the memory a run before the record left, a gap
#: in the output that closes on the first rise) cannot be told apart on it.
FIRST_LOADING_SHARE = 0.95

#: rule -> (status, the general reason).
RULES = {
    "noise": ("adequate", "the residual passes the noise tests and no candidate repairs a misfit that matters"),
    "negligible": (
        "adequate",
        "a candidate's targeted refit repairs a misfit, but the residual holds less structure "
        "in excess of the noise than the floor",
    ),
    "first_loading_only": (
        "adequate",
        "the residual passes the noise tests, and the one candidate that repairs "
        "something puts its part in the first loading, which other physics can take as well",
    ),
    "too_small": ("adequate", "the candidates that reach the noise explain less than the practical size"),
    "none_repairs": ("unexplained", "no candidate or pair leaves a residual consistent with the noise"),
    "first_loading_again": (
        "unexplained",
        "the explanation puts its part in the first loading, beside first-cycle physics the model already has",
    ),
    "named": ("missing_effect", "one effect repairs the model and the data separate it from every rival"),
    "named_from_pair": (
        "missing_effect",
        "a pair repairs the model; the effect every explanation the data cannot separate from it shares is named",
    ),
    "tied": ("tied", "several explanations repair the model and the data do not separate them"),
}


@dataclass(frozen=True)
class Decision:
    """The verdict and what it rests on.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    rule : str
        The rule of :data:`RULES` that decided.
    missing : str or None
        The effect to add (``missing_effect``).
    tied : tuple of str
        The explanations the data do not separate, best first (``tied``; the alternatives to a
        named explanation otherwise, also best first).
    best : str or None
        The explanation the decision rests on (the best repairing one, or the best refitted).
    partner : str or None
        The other member of a pair the name comes from.
    numbers : dict
        The comparisons made (gaps and their noise, sizes), for the explanation.
    """

    status: str
    rule: str
    missing: str | None = None
    tied: tuple = ()
    best: str | None = None
    partner: str | None = None
    numbers: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "status": self.status,
            "rule": self.rule,
            "missing": self.missing,
            "tied": list(self.tied),
            "best": self.best,
            "partner": self.partner,
            "numbers": dict(self.numbers),
        }


def _practical(before_rms: float, after: Explanation, sigma: float, th: Thresholds) -> bool:
    change, size = rms_change_and_size(before_rms, after.rms, sigma)
    return change >= th.practical_rms_change and size >= th.structure_floor


def repairs(e: Explanation, ev: Evidence, th: Thresholds) -> bool:
    """Does ``e`` repair the model: an adequate residual, needed, and of practical size?"""
    return e.adequate and e.delta_bic > th.bic_significant and _practical(ev.baseline_rms, e, ev.sigma, th)


def _needed_beside(pair: Explanation, member: Explanation, ev: Evidence, th: Thresholds) -> bool:
    """Is the pair's second effect needed beside ``member`` (nested: parameters charged)?"""
    return pair.delta_bic - member.delta_bic > th.bic_significant and _practical(member.rms, pair, ev.sigma, th)


def _minimal(repairing: list, ev: Evidence, th: Thresholds) -> tuple[list, set]:
    """``(the minimal repairing explanations, names of the pairs that add nothing)``."""
    singles = {e.name: e for e in repairing if len(e.effects) == 1}
    kept, superfluous, dropped = [], set(), set()
    for e in repairing:
        if len(e.effects) < 2:
            continue
        inside = [singles[m] for m in e.effects if m in singles]
        if any(not _needed_beside(e, m, ev, th) for m in inside):
            superfluous.add(e.name)
            continue
        dropped.update(m.name for m in inside)
        kept.append(e)
    kept += [e for e in singles.values() if e.name not in dropped]
    return kept, superfluous


def separated(g: Gap | None, better: str, th: Thresholds) -> bool:
    """Does gap ``g`` put explanation ``better`` ahead of the other: ``better`` the lower
    chi-square, the likelihood gap above ``bic_significant`` and above ``gap_z`` noise standard
    deviations of it?"""
    return g is not None and g.better == better and g.gap > th.bic_significant and g.z > th.gap_z


def _separated(ev: Evidence, best: Explanation, other: Explanation, th: Thresholds) -> bool:
    """Do the data put ``best`` ahead of ``other`` (:func:`separated`)?"""
    return separated(ev.gap(best.name, other.name), best.name, th)


def _gap_numbers(ev: Evidence, best: Explanation, others) -> list:
    rows = []
    for e in others:
        g = ev.gap(best.name, e.name)
        if g is not None:
            rows.append({"other": e.name, "better": g.better, "gap": g.gap, "noise_sd": g.noise_sd, "z": g.z})
    return rows


def _judge(repairing: list, ev: Evidence, th: Thresholds) -> Decision:
    """Steps 1-3 of the module docstring on the repairing explanations."""
    minimal, superfluous = _minimal(repairing, ev, th)
    best = min(minimal, key=lambda e: e.chi2)
    # every other explanation is compared, but a pair that only adds to the best (a superset of
    # it) says no other physics, nor, against a single, a pair that adds nothing to a repairing
    # member; against a pair it is that member at the same number of effects
    compared = [
        e
        for e in ev.explanations
        if e.name != best.name
        and (e.name not in superfluous or len(e.effects) <= len(best.effects))
        and not set(best.effects) < set(e.effects)
    ]
    rivals = [e for e in compared if not _separated(ev, best, e, th)]
    group = [best, *sorted(rivals, key=lambda e: e.chi2)]
    numbers = {"best": best.name, "rivals": _gap_numbers(ev, best, compared)}
    common = set.intersection(*(set(e.effects) for e in group))
    if not common:
        return Decision("tied", "tied", tied=tuple(e.name for e in group), best=best.name, numbers=numbers)
    named = max(sorted(common), key=lambda n: ev.strength.get(n, float("-inf")))
    partner = next((n for n in best.effects if n != named), None)
    rule = "named" if best.effects == (named,) else "named_from_pair"
    alternatives = tuple(e.name for e in group[1:])
    return Decision("missing_effect", rule, named, alternatives, best.name, partner, numbers)


def _first_loading_share(ev: Evidence, decision: Decision) -> float | None:
    """The named effect's share of its part of the fit in the first loading (its single
    explanation's, else the explanation the name rests on)."""
    e = ev.explanation(decision.missing) or ev.explanation(decision.best)
    return None if e is None else e.first_loading_share


def decide(ev: Evidence, th: Thresholds | None = None) -> Decision:
    """The verdict on the evidence (module docstring; every rule in :data:`RULES`).

    Parameters
    ----------
    ev : Evidence
    th : Thresholds, optional
        Default :class:`~identify.diagnosis.adequacy.Thresholds()`.

    Returns
    -------
    Decision
    """
    th = Thresholds() if th is None else th
    repairing = [e for e in ev.explanations if repairs(e, ev, th)]
    excess = excess_over_noise(ev.baseline_rms, ev.sigma)
    if ev.baseline.adequate:
        if not repairing:
            return Decision("adequate", "noise", numbers={"excess_over_noise": excess})
        if excess < th.structure_floor:
            best = min(repairing, key=lambda e: e.chi2)
            return Decision("adequate", "negligible", best=best.name, numbers={"excess_over_noise": excess})
    elif not repairing:
        small = [e for e in ev.explanations if e.adequate and e.delta_bic > th.bic_significant]
        if small:
            best = min(small, key=lambda e: e.chi2)
            return Decision("adequate", "too_small", best=best.name, numbers={"excess_over_noise": excess})
        best = min(ev.explanations, key=lambda e: e.chi2, default=None)
        return Decision("unexplained", "none_repairs", best=None if best is None else best.name)
    decision = _judge(repairing, ev, th)
    if decision.status != "missing_effect":
        return decision
    share = _first_loading_share(ev, decision)
    numbers = decision.numbers | {"first_loading_share": share}
    if share is not None and share >= FIRST_LOADING_SHARE:
        if ev.baseline.adequate:
            return Decision("adequate", "first_loading_only", best=decision.best, numbers=numbers)
        if ev.first_cycle:
            return Decision("unexplained", "first_loading_again", best=decision.best, numbers=numbers)
    return Decision(
        decision.status, decision.rule, decision.missing, decision.tied, decision.best, decision.partner, numbers
    )
