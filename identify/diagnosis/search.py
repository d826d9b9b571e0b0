"""The search: every candidate effect screened, refitted from its start strategies, and the
promising ones finished on the whole record, so that the decision compares fits the optimiser
has done its best on.

One round against one baseline:

1. **Screening** of every candidate (:mod:`identify.diagnosis.screening`).
2. **Short refits** on the working copy (:func:`identify.diagnosis.fits.short_refit`), each from
   the groups of its start strategies (:mod:`identify.diagnosis.starts`): carried and near the
   baseline, data-driven, the screening's step. A short refit that ends above the screening's
   linearised promise, where that promise is a significant gain, has stayed in the baseline's
   basin: the candidate is fitted from scratch in both threshold signs too; such a fit serves
   only where it ends below that short refit, so its runs stop once out of reach of it.
3. **The other threshold sign**, where the data do not choose it (the plain model's two signs
   fit alike): every candidate is short-refitted from the other sign's baseline as well.
4. **Finishes** on the whole record: the :attr:`~identify.diagnosis.adequacy.Thresholds.max_refits`
   best short refits and every further one that gains significantly; a candidate's fit of the
   other sign is finished where it starts lower on the whole record than its own.
5. When the best candidate still leaves structure, it is fitted from scratch in the other sign,
   and so is every candidate leaving structure whose fit the data do not separate from it (every
   one of the ``max_refits`` best where none repairs the model); where that fits one better, the
   next candidates are refitted there from its GPI. Such a fit serves only where it starts
   lower than the candidate's own short refit, so its runs stop once out of reach of that.
6. **One basin**: every finished candidate is refitted from the GPI of the best one of its sign
   where that promises to matter, so that effects are ranked on the same GPI basin and no
   effect loses to a rival for its GPI's sake.
7. **Baseline challenge**: the model without the candidates refitted from their GPIs and through
   the exact reparametrisations; a better baseline repeats the round, each candidate also
   starting from what the round before reached with it.

Pairs are searched by :mod:`identify.diagnosis.pairs`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from model import Model, get_effect

from ..fitting.lsq import FitResult
from ..fitting.lsq_solver import out_of_reach
from ..fitting.threads import single_threaded_blas
from ..logs import ordinal
from .adequacy import Adequacy, Thresholds, assess_adequacy
from .baseline import challenge_baseline, reparametrisation_paths, tied_sign
from .candidates import CandidateResult, Reference, evaluate, failed_candidate
from .decision import separated
from .evidence import gap_between
from .fits import (
    Point,
    Working,
    attempt,
    attempt_each,
    effect_values,
    embed,
    n_eff,
    plain_of,
    profile_of,
    same_threshold_sign,
    short_refit,
    threshold_sign_variants,
    whitened,
    whitened_at,
    whole_record_chi2,
    with_values,
)
from .residuals import ARNoise, ResidualProfile
from .screening import ScreeningResult, screen_one
from .starts import carried, data_driven, from_scratch, near, screening_step, working_chi2

__all__ = [
    "Setting",
    "Round",
    "Short",
    "search",
    "start_round",
    "fresh_fits",
    "worth_finishing",
    "MAX_BASELINE_CHALLENGES",
    "SHARED_BASIN_GAIN",
    "OUT_OF_REACH_Z",
]

#: How often a candidate's GPI may replace the baseline before the verdict.
MAX_BASELINE_CHALLENGES = 1
#: A start beats a candidate's own fit when it is lower by more than this in chi-square (one
#: evaluation on the whole record); less is the rounding of two polished optima.
SHARED_BASIN_GAIN = 1.0
#: A finish stops once it cannot come within this many noise standard deviations of the gap
#: of the lowest chi-square the round holds (:func:`identify.fitting.lsq_solver.out_of_reach`):
#: four times the decision's ``gap_z``, so a run that would have sped up again still ends far
#: beyond anything the decision compares. On a long record a candidate that leaves a share of
#: structure behind crawls for hundreds of evaluations without ever coming near.
OUT_OF_REACH_Z = 4.0 * Thresholds().gap_z


@dataclass
class Setting:
    """What stays fixed through one diagnosis: the record, its working copy, the noise
    reference, the options, the candidates (``redundant``: the exact reparametrisations of the
    model, never refitted) and the baseline fitted in each threshold sign; ``fresh``: the fits
    from scratch made so far (:func:`fresh_fits`), each with the reference it was stopped by."""

    record: object
    work: Working
    quiet: slice | None
    noise_ref: ARNoise
    thresholds: Thresholds
    n_starts: int
    rng: np.random.Generator
    say: Callable[[str], None]
    candidates: list
    redundant: list
    sign_baselines: list = field(default_factory=list)
    fresh: dict = field(default_factory=dict)


def _fresh_key(model_e: Model, sign: str | None) -> tuple:
    """What a fit from scratch of ``model_e`` in ``sign`` depends on: the model's structure, its
    bounds and its pinned values (its free values are not starts, :func:`from_scratch`)."""
    columns = tuple((p.name, p.vary, p.lower, p.upper, None if p.vary else p.value) for p in model_e.parameters)
    return model_e.effect_names, model_e.n_operators, model_e.reading, columns, sign


def fresh_fits(s: Setting, models, signs=None, references=None) -> list:
    """:func:`~identify.diagnosis.starts.from_scratch` of every model of ``models`` (each in its
    sign of ``signs``, default None: the better of both) on the working copy, side by side, each
    from its own generator spawned in order from the diagnosis's one; once per diagnosis: a fit
    from scratch does not depend on the round's baseline, so a later round takes the earlier
    one's (said so) where that was stopped by no lower reference. One entry per model, None where
    the fit fails (said).

    ``references``: for each model, a working-copy chi-square its fit is of use only below
    (default none): such a fit never enters the decision with its own chi-square, it only
    replaces a fit that holds ``reference`` where it ends lower, so its solver runs stop once
    out of reach of it by the decision's ``gap_z`` (the margin for a run that would have sped
    up again), not by :data:`OUT_OF_REACH_Z`, whose wider margin protects the chi-squares the
    decision compares."""
    signs = [None] * len(models) if signs is None else list(signs)
    references = [math.inf] * len(models) if references is None else list(references)
    keys = [_fresh_key(model_e, sign) for model_e, sign in zip(models, signs)]
    todo = [k for k, key in enumerate(keys) if key not in s.fresh or s.fresh[key][1] < references[k]]
    if len(todo) < len(keys):
        s.say("  (fits from scratch of the round before taken again: they do not depend on the baseline)")
    rngs = s.rng.spawn(len(todo)) if todo else []
    fitted = attempt_each(
        [
            partial(
                _within,
                references[k],
                s.thresholds.gap_z,
                from_scratch,
                s.work,
                models[k],
                rng,
                signs[k],
                s.n_starts,
            )
            for k, rng in zip(todo, rngs)
        ],
        s.say,
        ["not possible"] * len(todo),
    )
    for k, fresh in zip(todo, fitted):
        if fresh:
            s.fresh[keys[k]] = (fresh, references[k])
    return [s.fresh[key][0] if key in s.fresh else None for key in keys]


@dataclass(frozen=True)
class Short:
    """A short refit on the working copy: its chi-square there, the model (its threshold sign)
    and the full vector reached."""

    chi2: float
    model: Model
    theta: np.ndarray


@dataclass
class Round:
    """One pass of the search against one baseline (module docstring).

    ``short``: the best short refit of each single candidate in the baseline's threshold sign;
    ``other``: in the other sign, where one was made and ended lower; ``refitted``: the single
    candidates finished on the whole record (the better sign kept); ``replaced``: their finish in
    the baseline's sign where the other sign's replaced it (pairs of the baseline's sign start
    from it); ``pairs`` and ``pair_shorts``: the pairs (:mod:`identify.diagnosis.pairs`);
    ``failed``: candidates whose screening or refit failed; ``carried``: what the round before
    reached with each candidate; ``mimicked``: the ``(rival, named)`` pairs whose rival was
    started where it reproduces the named explanation."""

    ref: Reference
    profile: ResidualProfile
    chi2_small: float
    n_eff_small: float
    excess_small: float
    screened: dict = field(default_factory=dict)
    short: dict = field(default_factory=dict)
    other: dict = field(default_factory=dict)
    refitted: dict = field(default_factory=dict)
    replaced: dict = field(default_factory=dict)
    pairs: dict = field(default_factory=dict)
    pair_shorts: dict = field(default_factory=dict)
    pair_pool: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)
    reparametrised: list = field(default_factory=list)
    carried: dict = field(default_factory=dict)
    tied_sign: FitResult | None = None
    mimicked: set = field(default_factory=set)

    @property
    def fit(self) -> FitResult:
        return self.ref.fit

    @property
    def adequacy(self) -> Adequacy:
        return self.ref.adequacy

    def ranked(self) -> list:
        """The finished single candidates, by falling delta BIC."""
        return sorted(self.refitted.values(), key=lambda c: -c.delta_bic)

    def working_gain(self, chi2: float, k: int) -> float:
        """Delta BIC on the working copy of a model with ``k`` more free parameters reaching
        ``chi2`` there: ``n ln(chi2_0 / chi2) - k ln n``, ``n`` the baseline's effective sample
        count on the working copy."""
        n = self.n_eff_small
        return n * math.log(self.chi2_small / max(chi2, 1e-300)) - k * math.log(n)


def start_round(s: Setting, fit: FitResult, carried_history: dict | None = None) -> Round:
    """The baseline's residual profile, adequacy and chi-squares (whole record and working copy)."""
    profile = profile_of(s.record, fit, s.quiet, s.noise_ref)
    adequacy = assess_adequacy(profile, s.thresholds)
    chi2_0 = float(np.sum(whitened(s.record, fit) ** 2))
    w_small = whitened_at(s.work.record, fit.model, s.work.noise, fit.theta)
    chi2_small = float(w_small @ w_small)
    ref = Reference(s.record, fit, chi2_0, adequacy, s.quiet, s.noise_ref, s.thresholds, s.rng)
    rnd = Round(ref, profile, chi2_small, n_eff(w_small), chi2_small - w_small.size)
    rnd.carried = dict(carried_history or {})
    return rnd


def _on_failure(rnd: Round, name: str, screening, stage: str):
    def record(exc):
        rnd.failed[name] = failed_candidate(name, screening, rnd.fit, rnd.n_eff_small, stage, exc)

    return record


def _screen(s: Setting, rnd: Round) -> None:
    """Step 1: every candidate screened on the working copy, by falling chi-square drop."""
    steps = f" (on every {ordinal(s.work.step)} sample)" if s.work.step > 1 else ""
    s.say(f"screening {len(s.candidates)} candidate effects{steps}")
    found = []
    for name in s.candidates:
        one = attempt(
            lambda: _screen_blas(s, rnd, name),
            s.say,
            f"screening of '{name}' failed",
            _on_failure(rnd, name, None, "screening"),
        )
        if one is not None:
            found.append(one)
    rnd.screened = {one.effect: one for one in sorted(found, key=lambda r: -r.chi2_drop)}


def _screen_blas(s: Setting, rnd: Round, name: str) -> ScreeningResult:
    with single_threaded_blas():  # small dense algebra: threads only compete with the model
        return screen_one(s.work.record, rnd.fit.model, rnd.fit.theta, s.work.noise, name)


def own_values(rnd: Round, name: str, model_e: Model) -> list:
    """The candidate's own parameter values to start from: its short refit, its screening start,
    then its screening grid."""
    values = []
    if name in rnd.short:
        values.append(effect_values(rnd.short[name].model, rnd.short[name].theta, name))
    one = rnd.screened.get(name)
    if one is not None:
        values.append(effect_values(rnd.fit.model + name, one.start, name))
        values += list(one.grid)
    return values


def refit_short(s: Setting, rnd: Round, name: str, model_e: Model, donor, extra=()) -> Short:
    """The search's one refit routine for a single candidate: a short refit of ``model_e`` on the
    working copy from the groups of its start strategies, around ``donor`` (a baseline or
    another candidate's fit, a :class:`~identify.diagnosis.fits.Point`, of ``model_e``'s
    threshold sign): near ``donor`` (with
    ``extra`` and what earlier rounds reached), data-driven, and the screening's step."""
    values = own_values(rnd, name, model_e)
    groups = [
        near(donor, model_e, values, extra=[*extra, *carried(rnd.carried.get(name, ()), model_e)]),
        data_driven(s.work, model_e, values),
        screening_step(rnd.screened.get(name), model_e) if same_threshold_sign(rnd.fit.model, model_e) else [],
    ]
    chi2, theta = short_refit(s.work.record, model_e, s.work.noise, groups)
    return Short(chi2, model_e, theta)


def short_of_promise(promised_gain: float, n_eff: float, promise: float, short: float, significant: float) -> bool:
    """Did a short refit ending at chi-square ``short`` fall short of a significant screening
    promise (all on the working copy, ``n_eff`` its effective sample count)?

    The promise (the screening's linearised chi-square ``promise``) gains significantly over the
    baseline (``promised_gain``, its delta BIC :meth:`Round.working_gain`, above ``significant``:
    a promise that would not matter if kept is no reason to search further), and the short refit
    ends above it by more than ``significant`` in BIC units (``n ln(short / promise)``).
    """
    if promised_gain <= significant:
        return False
    return n_eff * math.log(short / max(promise, 1e-300)) > significant


def _short_of_screening(s: Setting, rnd: Round, name: str, one: ScreeningResult, chi2: float) -> bool:
    """:func:`short_of_promise` of candidate ``name``'s short refit at ``chi2`` in round ``rnd``."""
    gain = rnd.working_gain(one.chi2_after, get_effect(name).n_varying())
    return short_of_promise(gain, rnd.n_eff_small, one.chi2_after, chi2, s.thresholds.bic_significant)


def _short_refits(s: Setting, rnd: Round) -> None:
    """Step 2: a short refit of every screened candidate in the baseline's sign; one that stays
    above its screening's significant promise is also fitted from scratch in both signs (the better of a
    sign replaces the short refit of that sign where it is lower)."""
    names = list(rnd.screened)
    for name in names:
        s.say(f"short refit with '{name}'")
    shorts = attempt_each(
        [partial(refit_short, s, rnd, name, rnd.fit.model + name, rnd.fit) for name in names],
        s.say,
        [f"'{name}' not possible" for name in names],
        [_on_failure(rnd, name, rnd.screened[name], "short refit") for name in names],
    )
    fresh = []
    for name, short in zip(names, shorts):
        if short is None:
            continue
        rnd.short[name] = short
        if _short_of_screening(s, rnd, name, rnd.screened[name], short.chi2):
            s.say(f"fitting '{name}' from scratch (its short refit stayed above the screening's prediction)")
            fresh.append(name)
    models = [rnd.fit.model + name for name in fresh]
    # a fit from scratch serves only where it ends below the candidate's short refit: in the
    # baseline's sign it replaces it there, in the other it is finished only where it starts lower
    # (_starts_lower); its runs stop once out of reach of that
    references = [rnd.short[name].chi2 for name in fresh]
    for name, fitted in zip(fresh, fresh_fits(s, models, references=references)):
        for model_f, theta in fitted or ():
            _keep_short(rnd, name, Short(working_chi2(s.work, model_f, theta), model_f, theta))


def _keep_short(rnd: Round, name: str, short: Short, gain: float = 0.0) -> bool:
    """Keep ``short`` as candidate ``name``'s short refit of its sign where it is lower than the
    one there by more than ``gain``; whether it was kept."""
    table = rnd.short if same_threshold_sign(short.model, rnd.fit.model) else rnd.other
    own = table.get(name)
    if own is not None and short.chi2 >= own.chi2 - gain:
        return False
    table[name] = short
    return True


def _other_sign_shorts(s: Setting, rnd: Round) -> None:
    """Step 3: where the plain model's two threshold signs fit alike, every candidate is also
    short-refitted from the other sign's baseline; kept where it ends lower there than its short
    refit in the baseline's sign."""
    tied = rnd.tied_sign
    sign = "positive" if tied.model.parameters["alpha"].value > 0 else "negative"
    s.say(f"the plain model's two threshold signs fit alike; the candidates are refitted with alpha {sign} too")
    names = list(rnd.short)
    shorts = attempt_each(
        [partial(refit_short, s, rnd, name, tied.model + name, tied) for name in names],
        s.say,
        [f"'{name}' not possible" for name in names],
    )
    for name, short in zip(names, shorts):
        if short is not None and short.chi2 < rnd.short[name].chi2 - SHARED_BASIN_GAIN:
            _keep_short(rnd, name, short)


def worth_finishing(s: Setting, rnd: Round, name: str, chi2: float, rank: int) -> bool:
    """Is candidate ``name``, whose best short refit ends at ``chi2`` (``rank``-th lowest, from 0),
    finished on the whole record? When it beats the baseline on the working copy and is among
    the ``max_refits`` best, or beyond them gains significantly (a short refit only bounds a
    candidate's gain from below)."""
    if chi2 >= rnd.chi2_small:
        return False
    k = get_effect(name).n_varying()
    return rank < s.thresholds.max_refits or rnd.working_gain(chi2, k) > s.thresholds.bic_significant


def _starts_lower(s: Setting, rnd: Round, name: str, short: Short) -> bool:
    """Is a fit of the other threshold sign worth finishing? Only where it starts lower on the
    whole record, by more than :data:`SHARED_BASIN_GAIN`, than the candidate's own short refit
    in the baseline's sign (one evaluation each): the working copy's chi-square is no such
    measure where structure from outside the library is left at a high sampling rate, and a
    finish at tens of thousands of samples costs tens of seconds."""
    own = rnd.short.get(name)
    if own is None:
        return True
    noise = rnd.fit.noise
    return whole_record_chi2(s.record, short.model, noise, short.theta) < (
        whole_record_chi2(s.record, own.model, noise, own.theta) - SHARED_BASIN_GAIN
    )


def finish_candidate(s: Setting, rnd: Round, name: str, start, members=()) -> CandidateResult | None:
    """Candidate ``name`` finished on the whole record from ``start`` (a :class:`Short` or any
    point with ``model`` and ``theta``) and measured
    (:func:`identify.diagnosis.candidates.evaluate`); None when that fails."""
    return finish_candidates(s, rnd, [(name, start, members)])[0]


def finish_candidates(s: Setting, rnd: Round, jobs) -> list[CandidateResult | None]:
    """:func:`finish_candidate` of every ``(name, start, members)`` of ``jobs``, run side by side
    (:func:`identify.diagnosis.fits.concurrently`: each finish reads the round and writes nothing
    shared, so each is what it would be alone); in order, None where one failed (said, and
    listed with the reason, in order). Each finish stops once it is out of reach
    (:data:`OUT_OF_REACH_Z`) of the lowest chi-square among the jobs' starts and the round's
    finished explanations."""
    reference = _lowest_chi2(s, rnd, jobs)
    return attempt_each(
        [
            partial(
                _within_reach,
                reference,
                evaluate,
                rnd.ref,
                name,
                start.model,
                start.theta,
                rnd.screened.get(name),
                members,
            )
            for name, start, members in jobs
        ],
        s.say,
        [f"refit with '{name}' failed" for name, _, _ in jobs],
        [_on_failure(rnd, name, rnd.screened.get(name), "refit") for name, _, _ in jobs],
    )


def _lowest_chi2(s: Setting, rnd: Round, jobs) -> float:
    """The lowest whole-record chi-square some fit of the round reaches: the jobs' starts (one
    evaluation each) and the singles and pairs finished so far."""
    noise = rnd.fit.noise
    values = [whole_record_chi2(s.record, start.model, noise, start.theta) for _, start, _ in jobs]
    values += [c.chi2 for c in (*rnd.refitted.values(), *rnd.pairs.values()) if c is not None and c.chi2]
    finite = [v for v in values if math.isfinite(v) and v > 0.0]
    return min(finite) if finite else math.inf


def _within_reach(reference: float, function, *args):
    """``function(*args)`` with every solver run stopped once out of reach of ``reference``
    (:data:`OUT_OF_REACH_Z`)."""
    return _within(reference, OUT_OF_REACH_Z, function, *args)


def _within(reference: float, z: float, function, *args):
    """``function(*args)`` with every solver run stopped once ``z`` noise sd out of reach of ``reference``."""
    if not math.isfinite(reference):
        return function(*args)
    with out_of_reach(reference, z):
        return function(*args)


def _keep_better(rnd: Round, result: CandidateResult | None) -> None:
    """``result`` as its candidate's finish where its delta BIC is higher than the one there; a
    finish in the baseline's sign that one of the other sign replaces is kept in ``replaced``."""
    if result is None:
        return
    own = rnd.refitted.get(result.effect)
    if own is not None and result.delta_bic <= own.delta_bic:
        return
    if own is not None and same_threshold_sign(own.fit.model, rnd.fit.model):
        rnd.replaced[result.effect] = own
    rnd.refitted[result.effect] = result


def _finish_best(s: Setting, rnd: Round) -> None:
    """Step 4: the short refits worth it finished on the whole record, in the baseline's sign and,
    where a lower short refit of the other sign starts lower on the whole record, in that one."""
    best = {n: min(rnd.short[n].chi2, rnd.other[n].chi2 if n in rnd.other else math.inf) for n in rnd.short}
    jobs = []
    for rank, name in enumerate(sorted(best, key=best.get)):
        if not worth_finishing(s, rnd, name, best[name], rank):
            continue
        s.say(f"refitting with '{name}'")
        jobs.append((name, rnd.short[name], ()))
        other = rnd.other.get(name)
        if other is not None and _starts_lower(s, rnd, name, other):
            s.say(f"refitting with '{name}' in the other threshold sign")
            jobs.append((name, other, ()))
    for result in finish_candidates(s, rnd, jobs):
        _keep_better(rnd, result)


def _unseparated(best: CandidateResult, other: CandidateResult, th: Thresholds) -> bool:
    """Do the data leave ``other``'s fit as good as ``best``'s: not separated by the decision's
    margins (:func:`identify.diagnosis.decision.separated`; no charge for parameters)?"""
    if best.chi2 is None or other.chi2 is None or best.whitened is None or other.whitened is None:
        return False
    g = gap_between(best.explanation(), best.whitened, other.explanation(), other.whitened)
    return not separated(g, best.effect, th)


def _other_sign_from_best(s: Setting, rnd: Round) -> None:
    """Step 5 (the best candidate leaves structure and the signs do not tie): the best candidate
    fitted from scratch in the other sign, and so is every other candidate leaving structure
    whose fit the data do not separate from the best's (which of two such candidates is "best"
    is the noise's choice, or their parameter counts'); where no candidate repairs the model,
    every one of the ``max_refits`` best is (before the verdict says no library effect repairs
    it, each leading candidate has had every start). Where that fits one better, the next
    candidates that leave structure are refitted in that sign from its GPI. A misspecified
    plain GPI can settle on the other sign, a different model, and refits from its basin stay
    there."""
    variants = threshold_sign_variants(rnd.fit.model)
    if len(variants) == 1:
        return
    ranked = rnd.ranked()
    best = ranked[0]
    none_repairs = not any(c.adequate_after for c in ranked)
    contenders = [best] + [
        c
        for c in ranked[1 : s.thresholds.max_refits]
        if not c.adequate_after and (none_repairs or _unseparated(best, c, s.thresholds))
    ]
    other = "positive" if rnd.fit.model.parameters["alpha"].value < 0 else "negative"
    for c in contenders:
        s.say(f"refitting with '{c.effect}' from scratch with the other threshold sign (alpha {other})")
    models = [rnd.fit.model + c.effect for c in contenders]
    # a fit of the other sign is used only where it starts lower than the candidate's own short
    # refit (_starts_lower): a run that cannot come near that chi-square is stopped
    references = [rnd.short[c.effect].chi2 if c.effect in rnd.short else math.inf for c in contenders]
    fitted = fresh_fits(s, models, [other] * len(contenders), references)
    jobs = []  # their finishes side by side
    for c, fresh in zip(contenders, fitted):
        if not fresh:
            continue
        model_f, theta = fresh[0]
        short = Short(working_chi2(s.work, model_f, theta), model_f, theta)
        if not _starts_lower(s, rnd, c.effect, short):
            s.say(f"with alpha {other} '{c.effect}' starts no lower on the whole record; not refitted there")
            continue
        jobs.append((c, (c.effect, short, ())))
    improved = None
    for (c, _), anchor in zip(jobs, finish_candidates(s, rnd, [job for _, job in jobs])):
        _keep_better(rnd, anchor)
        if anchor is not None and anchor.delta_bic > c.delta_bic and improved is None:
            improved = (c.effect, anchor)
    if improved is None:
        return
    name, anchor = improved
    plain = plain_of(anchor.fit.model, rnd.fit.model)
    donor = Point(plain, embed(anchor.fit.model, anchor.fit.theta, plain, drop_extra=True))
    done = {c.effect for c in contenders}
    rest = [c for c in ranked[1 : s.thresholds.max_refits] if not (c.adequate_after or c.effect in done)]
    for c in rest:
        s.say(f"refitting with '{c.effect}' with the other threshold sign, from the GPI of '{name}' there")
    shorts = attempt_each(
        [partial(refit_short, s, rnd, c.effect, plain + c.effect, donor) for c in rest],
        s.say,
        ["not possible"] * len(rest),
    )
    jobs = [(c.effect, short, ()) for c, short in zip(rest, shorts) if short is not None]
    jobs = [job for job in jobs if _starts_lower(s, rnd, job[0], job[1])]
    for result in finish_candidates(s, rnd, jobs):
        _keep_better(rnd, result)


def shared_basin(s: Setting, rnd: Round, candidates: dict, members_of=None) -> None:
    """Step 6: every finished candidate of ``candidates`` (``{name: CandidateResult}``, singles or
    pairs) again from the GPI of the one of lowest chi-square of its threshold sign, its own
    effects' parameters kept; the better of its two finishes kept in ``candidates``.

    The slow effects are small beside the hysteresis, so the GPI basin one of them found serves
    the others too; each candidate's own refit starts from its short refit and can end in a
    worse basin, and would then lose to a rival for its GPI's sake. A short refit from the
    shared start on the working copy is bounded on the whole record by one evaluation; the
    finish runs only where that beats the candidate's own fit by more than
    :data:`SHARED_BASIN_GAIN` and could bring it within ``bic_significant`` of the best."""
    fitted = [c for c in candidates.values() if c.fit is not None]
    if len(fitted) < 2:
        return
    best_bic = max(c.delta_bic for c in fitted)
    starts = []  # (candidate, donor, start) of each candidate a GPI of its sign could move
    for c in fitted:
        same = [d for d in fitted if same_threshold_sign(d.fit.model, c.fit.model)]
        donor = min(same, key=lambda d: d.fit.chi2)
        if donor is c:
            continue
        shared = {p: float(donor.fit.theta[donor.fit.model.names.index(p)]) for p in rnd.fit.model.names}
        start = with_values(c.fit.model, c.fit.theta, shared)
        if c.fit.model.in_bounds(start)[0]:
            starts.append((c, donor, start))
    smalls = attempt_each(
        [partial(short_refit, s.work.record, c.fit.model, s.work.noise, [[start]]) for c, _, start in starts],
        s.say,
        [f"no short refit of '{c.effect}' from the GPI of '{donor.effect}'" for c, donor, _ in starts],
    )
    jobs = []
    for (c, donor, _), small in zip(starts, smalls):
        if small is None:
            continue
        chi2_start = whole_record_chi2(s.record, c.fit.model, rnd.fit.noise, small[1])
        reach = c.delta_bic + c.n_eff * math.log(c.fit.chi2 / chi2_start) if chi2_start > 0 else -math.inf
        if not (chi2_start < c.fit.chi2 - SHARED_BASIN_GAIN and reach > best_bic - s.thresholds.bic_significant):
            continue
        s.say(f"refitting '{c.effect}' from the GPI of '{donor.effect}'")
        members = () if members_of is None else members_of(c.effect)
        jobs.append((c, (c.effect, Point(c.fit.model, small[1]), members)))
    for (c, _), again in zip(jobs, finish_candidates(s, rnd, [job for _, job in jobs])):
        if again is not None and again.fit.chi2 < c.fit.chi2:
            candidates[c.effect] = again


def _carry(rnd: Round) -> dict:
    """What a next round inherits: per candidate, the earlier ``(model, theta)`` plus its short
    refits and its finish in this round (a basin found against the old baseline is kept)."""
    history = {name: list(items) for name, items in rnd.carried.items()}
    for table in (rnd.short, rnd.other):
        for name, short in table.items():
            history.setdefault(name, []).append((short.model, short.theta))
    for name, c in rnd.refitted.items():
        if c.fit is not None:
            history.setdefault(name, []).append((c.fit.model, c.fit.theta))
    return history


def search(s: Setting, fit: FitResult) -> Round:
    """Steps 1-7 (module docstring) against the baseline ``fit``, repeated (at most
    :data:`MAX_BASELINE_CHALLENGES` more times) while the baseline challenge finds a better
    baseline; the last round."""
    history: dict = {}
    for attempt_no in range(MAX_BASELINE_CHALLENGES + 1):
        rnd = start_round(s, fit, history)
        _screen(s, rnd)
        if not rnd.adequacy.adequate:
            _short_refits(s, rnd)
            rnd.tied_sign = tied_sign(s.record, fit, s.sign_baselines, rnd.ref.chi2, s.thresholds.bic_significant)
            if rnd.tied_sign is not None and rnd.short:
                _other_sign_shorts(s, rnd)
            _finish_best(s, rnd)
            ranked = rnd.ranked()
            if rnd.tied_sign is None and ranked and not ranked[0].adequate_after:
                _other_sign_from_best(s, rnd)
            shared_basin(s, rnd, rnd.refitted)
            names = s.candidates + s.redundant
            rnd.reparametrised = reparametrisation_paths(s.work, rnd.fit, names, s.say)
        if attempt_no == MAX_BASELINE_CHALLENGES or not (rnd.refitted or rnd.reparametrised):
            break
        fits = [c.fit for c in rnd.refitted.values() if c.fit is not None]
        challenger = challenge_baseline(
            s.record, s.work, fit, rnd.ref.chi2, rnd.chi2_small, fits, rnd.reparametrised, s.rng, s.say
        )
        if challenger is None:
            break
        s.say(f"the baseline improved (chi-square {rnd.ref.chi2:.6g} -> {challenger.chi2:.6g}); diagnosing again")
        fit, history = challenger, _carry(rnd)
    return rnd
