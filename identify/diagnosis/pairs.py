"""Pairs of candidate effects: a wrong effect can absorb part of two hidden ones, and a general
form can reach the noise on a record that hides two other effects, so pairs are searched
beside the single candidates.

The pool is every candidate whose gain alone pays for its parameters (delta BIC > 0 on the
whole record, or on the working copy for one only short-refitted): not only the significant
ones, since an effect can gain almost nothing alone while a larger one distorts the GPI's
compromise, yet decide the pair. Every two of the pool are short-refitted together from their
members' fits (with the partner's parameters; with the partner off but shaped as its own fit)
and from the baseline with both; the best :attr:`~identify.diagnosis.adequacy.Thresholds.max_refits`
by their short refits, and every other within ``bic_significant`` of the best, are finished on
the whole record, never ending above a member alone, then ranked on one GPI basin.

Before a pair's member is named, the pairs that keep its partner and swap the member for
another candidate as strong alone are finished too (:func:`rival_pairs`): a name taken from a
pair must hold against the pairs that would name another effect.
"""

from __future__ import annotations

import itertools
from functools import partial

from model import get_effect

from .candidates import CandidateResult
from .fits import (
    Point,
    attempt,
    attempt_each,
    effect_values,
    embed,
    plain_of,
    same_threshold_sign,
    short_refit,
    whitened,
    with_values,
)
from .search import Round, Setting, Short, finish_candidates, shared_basin
from .starts import members, near, shapes

__all__ = ["search_pairs", "rival_pairs", "pair_pool"]


def pair_pool(rnd: Round) -> list:
    """The candidates among which pairs are searched, as ``(name, model_e, theta_e)`` in the
    baseline's threshold sign: the finished ones by delta BIC (one finished in the other sign
    enters by its finish in the baseline's sign, which it replaced, or its short refit), then the
    short refits by chi-square; each whose gain alone pays for its parameters."""
    fit, pool, seen = rnd.fit, [], set()
    nested = [
        c if same_threshold_sign(c.fit.model, fit.model) else rnd.replaced.get(c.effect)
        for c in rnd.refitted.values()
        if c.fit is not None
    ]
    for c in sorted([c for c in nested if c is not None], key=lambda c: -c.delta_bic):
        if c.delta_bic > 0.0 and c.effect not in seen:
            model_e = fit.model + c.effect
            pool.append((c.effect, model_e, embed(c.fit.model, c.fit.theta, model_e)))
            seen.add(c.effect)
    for name in sorted(rnd.short, key=lambda n: rnd.short[n].chi2):
        short = rnd.short[name]
        if name not in seen and rnd.working_gain(short.chi2, get_effect(name).n_varying()) > 0.0:
            pool.append((name, fit.model + name, short.theta))
            seen.add(name)
    return pool


def _charged(rnd: Round) -> dict:
    """``{effect: parameters}`` each finished single was charged (its parameters less those of the
    optional terms its best form leaves uncharged): a member's charge in a pair's short refit."""
    charged = {}
    for c in rnd.refitted.values():
        if c.fit is not None:
            effect = get_effect(c.effect)
            unused = sum(len(effect.terms[entry.split(".", 1)[1]]) for entry in c.uncharged_terms)
            charged[c.effect] = effect.n_varying() - unused
    return charged


def _short_pair(s: Setting, rnd: Round, one, other, shaped) -> Short:
    """Two pool entries short-refitted together on the working copy from their members' fits
    (:func:`identify.diagnosis.starts.members`) and the baseline with both (near starts only: each
    single's fit already explored the distant GPI basins, and a pair's optimum lies near one of
    its members' optima plus the other's parameters)."""
    model_pair = rnd.fit.model + [one[0], other[0]]
    values = effect_values(one[1], one[2], one[0]) | effect_values(other[1], other[2], other[0])
    group = near(rnd.fit, model_pair, [values], extra=members(model_pair, one, other, shaped))
    chi2, theta = short_refit(s.work.record, model_pair, s.work.noise, [group])
    return Short(chi2, model_pair, theta)


def _from_flipped_member(s: Setting, rnd: Round, one, other, member_fits: dict) -> Short | None:
    """The pair short-refitted in the other threshold sign from its member finished in that sign
    that already leaves a residual consistent with the noise alone (with the partner's
    parameters, and alone); None when it has no such member. Beside a single that reaches the
    noise, a pair that contains it asks what the partner adds to it, so it starts where that
    single is, in its sign."""
    names = (one[0], other[0])
    flipped = [
        n
        for n in names
        if n in member_fits
        and rnd.refitted[n].adequate_after
        and not same_threshold_sign(member_fits[n][1].model, rnd.fit.model)
    ]
    if not flipped:
        return None
    name_m = min(flipped, key=lambda n: member_fits[n][0])
    fit_m = member_fits[name_m][1]
    partner, partner_model, partner_theta = other if name_m == one[0] else one
    if partner in member_fits and same_threshold_sign(member_fits[partner][1].model, fit_m.model):
        partner_model, partner_theta = member_fits[partner][1].model, member_fits[partner][1].theta
    s.say(f"short refit with '{names[0]}' and '{names[1]}' together with the other threshold sign, from '{name_m}'")
    model_pair = plain_of(fit_m.model, rnd.fit.model) + list(names)
    alone = embed(fit_m.model, fit_m.theta, model_pair)
    both = with_values(model_pair, alone, effect_values(partner_model, partner_theta, partner))
    starts = [x for x in (both, alone) if model_pair.in_bounds(x)[0]]
    if not starts:
        return None
    chi2, theta = short_refit(s.work.record, model_pair, s.work.noise, [starts])
    return Short(chi2, model_pair, theta)


def _member_fits(s: Setting, rnd: Round) -> dict:
    """``{name: (chi2, fit)}`` of the finished singles (a pair never ends above a member alone)."""
    fits = {}
    for c in rnd.refitted.values():
        if c.fit is not None:
            w = whitened(s.record, c.fit)
            fits[c.effect] = (float(w @ w), c.fit)
    return fits


def _pair_job(s: Setting, rnd: Round, name: str, short: Short, member_fits: dict) -> tuple:
    """``(name, start, members)`` to finish pair ``name``: from its member finished in the other
    threshold sign where that one reaches the noise (:func:`_from_flipped_member`), else from
    ``short``."""
    one, other = name.split("+")
    pool = {entry[0]: entry for entry in rnd.pair_pool}
    flipped = None
    if one in pool and other in pool:
        flipped = attempt(
            lambda: _from_flipped_member(s, rnd, pool[one], pool[other], member_fits),
            s.say,
            "the pair refit with the other threshold sign failed",
        )
    s.say(f"refitting with '{one}' and '{other}' together")
    return name, flipped or short, [member_fits[n] for n in (one, other) if n in member_fits]


def _finish_pairs(s: Setting, rnd: Round, jobs: list) -> None:
    """The pairs of ``jobs`` (:func:`_pair_job`) finished side by side, each kept in ``rnd.pairs``."""
    for (name, _, _), result in zip(jobs, finish_candidates(s, rnd, jobs)):
        if result is not None:
            rnd.pairs[name] = result


def search_pairs(s: Setting, rnd: Round) -> None:
    """Every two of the pool short-refitted together, the best finished on the whole record and
    ranked on one GPI basin (module docstring); fills ``rnd.pairs`` and ``rnd.pair_shorts``."""
    rnd.pair_pool = pair_pool(rnd)
    shaped = {}
    for name, model_e, theta_e in rnd.pair_pool:
        values = attempt(
            lambda: shapes(s.work, rnd.fit, name, model_e, theta_e), s.say, f"'{name}' could not be shaped"
        )
        if values is not None:
            shaped[name] = values
    combinations = list(itertools.combinations(rnd.pair_pool, 2))
    for one, other in combinations:
        s.say(f"short refit with '{one[0]}' and '{other[0]}' together")
    shorts = attempt_each(
        [partial(_short_pair, s, rnd, one, other, shaped) for one, other in combinations],
        s.say,
        ["the pair refit failed"] * len(combinations),
    )
    for (one, other), short in zip(combinations, shorts):
        if short is not None:
            rnd.pair_shorts[f"{one[0]}+{other[0]}"] = short
    if not rnd.pair_shorts:
        return
    charged = _charged(rnd)

    def gain(name):
        k = sum(charged.get(n, get_effect(n).n_varying()) for n in name.split("+"))
        return rnd.working_gain(rnd.pair_shorts[name].chi2, k)

    ranked = sorted(rnd.pair_shorts, key=gain, reverse=True)
    top = gain(ranked[0])
    chosen = [
        n for i, n in enumerate(ranked) if i < s.thresholds.max_refits or gain(n) >= top - s.thresholds.bic_significant
    ]
    member_fits = _member_fits(s, rnd)
    _finish_pairs(s, rnd, [_pair_job(s, rnd, name, rnd.pair_shorts[name], member_fits) for name in chosen])
    shared_basin(s, rnd, rnd.pairs, lambda name: [member_fits[n] for n in name.split("+") if n in member_fits])


def rival_pairs(s: Setting, rnd: Round, named: str, pair: CandidateResult) -> list:
    """Before ``pair`` names its member ``named``: the pairs that keep its partner and swap
    ``named`` for another finished single at least as strong alone as the partner (so it could
    be that pair's first name too) and behind ``named`` alone by less than the pair gains over
    it, not finished yet (at most ``max_refits``, the strongest alone first), each finished from
    ``pair``'s GPI and partner with the swapped-in member's own fit. Their names."""
    singles = rnd.refitted
    partner = next((n for n in pair.effects if n != named), None)
    if partner is None or named not in singles or partner not in singles:
        return []
    bar = max(singles[partner].delta_bic, 2.0 * singles[named].delta_bic - pair.delta_bic)
    done = {frozenset(n.split("+")) for n in rnd.pairs}
    rivals = sorted(
        (c for n, c in singles.items() if n not in pair.effects and c.delta_bic >= bar and c.fit is not None),
        key=lambda c: -c.delta_bic,
    )
    member_fits = _member_fits(s, rnd)
    finished, jobs = [], []
    for c in rivals:
        key = next((k for k in rnd.pair_shorts if set(k.split("+")) == {c.effect, partner}), None)
        if key is None or frozenset((c.effect, partner)) in done or len(finished) >= s.thresholds.max_refits:
            continue
        s.say(f"before '{pair.effect}' names '{named}': the pair '{key}' from its GPI")
        start = _swap_start(pair, c, rnd.pair_shorts[key])
        jobs.append(_pair_job(s, rnd, key, start, member_fits))
        finished.append(key)
    _finish_pairs(s, rnd, jobs)
    if finished:
        shared_basin(s, rnd, rnd.pairs, lambda name: [member_fits[n] for n in name.split("+") if n in member_fits])
    return finished


def _swap_start(pair: CandidateResult, single: CandidateResult, short: Short):
    """A swapped pair's start: ``pair``'s fit for every parameter the two pairs share (its GPI, the
    baseline's effects, the partner they keep) and the swapped-in member's own fit for its
    parameters; its short refit where the fits pin other threshold signs or the point is out of
    bounds. A pair's own refit can leave the partner in a worse basin than the best pair has."""
    model_pair = short.model
    if not (same_threshold_sign(pair.fit.model, single.fit.model) and same_threshold_sign(pair.fit.model, model_pair)):
        return short
    kept = embed(pair.fit.model, pair.fit.theta, model_pair, drop_extra=True)
    point = with_values(model_pair, kept, effect_values(single.fit.model, single.fit.theta, single.effect))
    return Point(model_pair, point) if model_pair.in_bounds(point)[0] else short
