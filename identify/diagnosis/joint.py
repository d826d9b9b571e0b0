"""The diagnosis of several records of one transducer: one verdict from joint fits.

The physics of the transducer is the same in every record, and records on different drives
separate effects that one record leaves tied (a hold, a quiet end, an amplitude that rises
again). The joint diagnosis:

1. diagnoses each record alone (:func:`identify.diagnosis.diagnose`): its baseline, its
   candidates and pairs, each searched with every start strategy;
2. takes the explanations any record found worth finishing (those that repair it, and the best
   few by their gain), and the effects the joint baseline's residual asks for (each effect screened
   on every record's residual of the joint baseline, then refitted briefly on the records
   together, the best few by that gain: the records together can show what none shows alone),
   and fits each on all records together
   (:class:`identify.fitting.joint.JointResiduals`: the transducer's parameters shared, each
   record's run parameters and sensor zero its own), from each record's own fit of it, from
   the joint baseline with the effect off (and with each record started warm, where the effect
   has a state earlier runs leave), and from the joint baseline with the effect where a
   record's screening puts it; before a member of the best joint pair may be
   named, the pairs that would name another effect (:func:`rival_pair_names`) are fitted
   jointly too;
3. measures each joint fit as one candidate: its chi-square summed over the records, its delta
   BIC against the joint baseline, and whether it repairs *every* record (each record's residual
   against its own quiet start);
4. decides with the same pure rule table (:func:`identify.diagnosis.decide`) and explains.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from model import EFFECTS, Model

from ..fitting.joint import (
    JointFit,
    JointModel,
    JointResiduals,
    earlier_run_state,
    fit_joint,
    joint_fit_at,
    joint_start,
    warm_value,
    with_earlier_runs,
)
from ..fitting.lsq import POLISH_EVALUATIONS
from ..fitting.lsq_solver import solve_within_box
from ..fitting.noise import energised_mask
from ..fitting.threads import results_side_by_side, single_threaded_blas
from .adequacy import Adequacy, Thresholds, assess_adequacy
from .candidates import CandidateResult, explained_fraction, first_loading_share
from .decision import Decision, decide
from .evidence import Evidence, gaps_among
from .explanation import explain, where_text
from .fits import REFIT_SCREEN_EVALUATIONS, n_eff, profile_of, same_threshold_sign
from .joint_choices import explanations_worth_finishing, rival_pair_names, short_ends_to_finish, tie_member_pairs
from .screening import screen_candidates

__all__ = [
    "JointDiagnosis",
    "diagnose_records",
    "explanations_worth_finishing",
    "joint_fit_with_earlier_runs",
    "rival_pair_names",
    "short_ends_to_finish",
    "started_warm",
    "tie_member_pairs",
]


@dataclass
class JointDiagnosis:
    """The joint diagnosis of several records (module docstring).

    Attributes
    ----------
    status, missing, tied, rule, reason
        As :class:`~identify.diagnosis.Diagnosis`.
    effects : tuple of str
    records : list of dict
        Per record: ``source``, ``samples``, ``noise_sigma``, ``rms`` (the joint baseline's),
        ``adequate`` and ``failed`` tests of the joint baseline, and the record's own verdict
        alone (``alone``).
    ranking : list of CandidateResult
        The explanations fitted jointly, by falling delta BIC (``adequate_after``: every record).
    adequate_by_record : dict
        ``{explanation: [adequate on record 1, ...]}``.
    alone : list of Diagnosis
        Each record's own diagnosis.
    baseline : JointFit
    decision, evidence, thresholds, seconds
    pairs_tried : list of CandidateResult
        The pairs fitted jointly.
    joint_fits : dict
        ``{explanation: JointFit}``.
    """

    status: str
    missing: str | None
    tied: tuple
    rule: str
    reason: str
    effects: tuple
    records: list
    ranking: list
    adequate_by_record: dict
    alone: list
    baseline: JointFit
    decision: Decision
    evidence: Evidence
    thresholds: Thresholds
    seconds: float = 0.0
    pairs_tried: list = field(default_factory=list)
    joint_fits: dict = field(default_factory=dict)

    def verdict_text(self) -> str:
        if self.status == "missing_effect":
            return f"missing_effect -> add '{self.missing}'"
        if self.status == "tied":
            return "tied: " + " | ".join(self.tied)
        return self.status

    def to_dict(self) -> dict:
        return {
            "n_records": len(self.records),
            "effects": list(self.effects),
            "status": self.status,
            "missing": self.missing,
            "tied": list(self.tied),
            "rule": self.rule,
            "reason": self.reason,
            "records": [dict(r) for r in self.records],
            "ranking": [
                c.to_dict() | {"adequate_by_record": self.adequate_by_record.get(c.effect)} for c in self.ranking
            ],
            "decision": self.decision.to_dict(),
            "evidence": self.evidence.to_dict(),
            "baseline": self.baseline.to_dict(),
            "alone": [d.to_dict() for d in self.alone],
            "thresholds": self.thresholds.to_dict(),
            "seconds": float(self.seconds),
        }

    def summary(self) -> str:
        lines = [
            f"model: GPI{''.join(' + ' + e for e in self.effects)}, {len(self.records)} records diagnosed together",
            f"verdict: {self.verdict_text()}",
            self.reason,
            "records:",
        ]
        for r in self.records:
            lines.append(
                f"  {r['source']}: {r['samples']} samples, RMS {r['rms']:.4g} um ({r['rms'] / r['noise_sigma']:.3f} "
                f"sigma), {'noise' if r['adequate'] else 'not noise'}; alone: {r['alone']}"
            )
        if self.ranking:
            lines.append("explanations fitted on every record together:")
            width = max(len(c.effect) for c in self.ranking)
            for c in self.ranking:
                by_record = self.adequate_by_record.get(c.effect) or []
                marks = "".join("+" if ok else "-" for ok in by_record)
                lines.append(f"  {c.effect:<{width}}  delta BIC {c.delta_bic:9.1f}, noise on each record [{marks}]")
        return "\n".join(lines)


def _pooled(values, weights) -> float:
    return float(math.sqrt(sum(w * v * v for v, w in zip(values, weights)) / max(sum(weights), 1)))


class _Joint:
    """What the joint candidates are measured against: the records, their noise references and
    the joint baseline."""

    def __init__(self, records, alone, baseline: JointFit, thresholds: Thresholds, rng):
        self.records, self.alone, self.baseline, self.th, self.rng = records, alone, baseline, thresholds, rng
        self.noises = [d.fit.noise for d in alone]
        self.quiet = [d.profile.noise for d in alone]  # each record's AR noise reference
        self.slices = [d.fit.noise.quiet for d in alone]
        self.profiles = [self._profile(r, f) for r, f in enumerate(baseline.fits)]
        self.adequacies = [assess_adequacy(p, thresholds) for p in self.profiles]
        self.chi2 = baseline.chi2
        self.energised = [int(np.sum(energised_mask(rec, f.noise))) for rec, f in zip(records, baseline.fits)]

    def _profile(self, r, fit, kind=None):
        quiet = self.slices[r] if self.slices[r] is not None else slice(0, 0)
        return profile_of(self.records[r], fit, quiet if quiet.stop else None, self.quiet[r])

    def with_effects(self, name: str) -> JointModel:
        """The joint baseline's layout with the effects of explanation ``name`` added."""
        return self.layout(self.baseline.joint.model + name.split("+"))

    def layout(self, model) -> JointModel:
        """``model`` laid out for the records as the baseline is (:func:`_freed_layout`)."""
        return _freed_layout(model, self.baseline.joint)

    def n_eff(self, w: np.ndarray) -> float:
        """The records' effective sample count of a concatenated whitened residual ``w``."""
        return float(sum(n_eff(part) for part in np.split(w, np.cumsum([len(r.time) for r in self.records])[:-1])))

    def delta_bic(self, chi2: float, joint: JointModel, n: float, theta=None) -> float:
        """Delta BIC against the joint baseline of ``joint`` reaching ``chi2`` at the joint vector
        ``theta``: ``n ln(chi2_0 / chi2) - k ln n``, ``k`` the free parameters ``joint`` adds, ``n``
        an effective sample count (:meth:`n_eff`). A record's earlier-run state the baseline
        pins is charged only where the fit uses it (off its off value; never where ``theta`` is
        None, a gain predicted without it): at its off value the fit is the one with it pinned."""
        k = int(joint.parameters.vary.sum() - self.baseline.joint.parameters.vary.sum())
        base = self.baseline.joint.parameters
        for column, off in _earlier_run_columns(joint):
            p = joint.parameters[column]
            if p.vary and not (p.name in base.names and base[p.name].vary):
                k -= int(theta is None or abs(theta[column] - off) <= 1e-9 * (p.upper - p.lower))
        return n * math.log(self.chi2 / chi2) - k * math.log(n) if chi2 > 0 else math.inf

    def measure(self, name: str, jf: JointFit, w: np.ndarray) -> tuple[CandidateResult, list]:
        """A joint fit as one candidate: ``(CandidateResult, adequate on each record)``."""
        n = self.n_eff(w)
        delta_bic = self.delta_bic(jf.chi2, jf.joint, n, jf.theta)
        adequate, before, after = [], 0.0, 0.0
        for r, fit in enumerate(jf.fits):
            base = self.adequacies[r]
            a = assess_adequacy(self._profile(r, fit), self.th, excess_kind=base.excess_kind)
            adequate.append(bool(a.adequate))
            before += base.excess
            after += a.excess
        rms = _pooled([f.rms for f in jf.fits], self.energised)
        shares = [first_loading_share(rec, f, name.split("+")) for rec, f in zip(self.records, jf.fits)]
        shares = [s for s in shares if s is not None]
        candidate = CandidateResult(
            name,
            None,
            True,
            rms,
            max(f.max_error_pct for f in jf.fits),
            float(delta_bic),
            n,
            explained_fraction(before, after),
            all(adequate),
            parameters={p: float(v) for p, v in jf.theta_dict().items() if p not in self.baseline.joint.names},
            fit=jf.fits[0],
            chi2=float(jf.chi2),
            first_loading_share=max(shares) if shares else None,
            whitened=w,
        )
        return candidate, adequate


def _earlier_run_columns(joint: JointModel) -> list[tuple[int, float]]:
    """``[(column, off value)]`` of ``joint``'s vector holding a record's earlier-run state
    (:func:`identify.fitting.joint.earlier_run_state`), every record's."""
    return [(column, off) for n, off in earlier_run_state(joint.model) for column in joint.columns_of(n)]


def _screened(ctx: _Joint, taken, say) -> tuple[list, dict]:
    """``(effects, short ends)``: the effects the joint baseline's residual asks for, beyond
    ``taken`` (those the records alone found worth finishing), and ``{effect: [(chi2, joint
    vector)]}``, where each effect's short refit on the records together ended, for every effect
    it lowered below the joint baseline, taken or not.

    Each library effect the model lacks is screened (:func:`identify.diagnosis.screening.screen_candidates`)
    on every record at the joint baseline's fit of it, and its predicted chi-square drops are
    summed: shared parameters that fit each record alone can fail to fit them together, and then
    no record alone asks for the effect that repairs them. Each effect with a predicted drop is
    then refitted briefly on the records together from the joint starts the screenings give
    (:func:`_short_joint_refit`): a record's screening is linearised about its own part of the
    residual and cannot see how the effect frees the shared parameters, which is where a misfit
    of the records together lies, so it is no ranking of the effects for it; a short joint refit
    is a lower bound on what each explains, as one record's short refits are. Then the rule of
    a record's own search on those drops: where some record's joint residual is not noise, the
    ``max_refits`` effects of largest drop; where every one is, with targeted refits, those whose
    drop beats their parameters' charge by ``bic_significant`` (the joint candidates' delta BIC,
    the run parameters charged once per record). Each of those not in ``taken`` is finished from
    its short refit's end; an effect in ``taken`` is finished from it too where its other starts
    end above it (:func:`_fit_candidate`): a fit never ends above a short run of itself already
    made, and a record's own fit of a slow effect starts the records together in that record's
    basin, which the records together need not share."""
    th = ctx.th
    inadequate = not all(a.adequate for a in ctx.adequacies)
    model = ctx.baseline.joint.model
    candidates = [name for name in EFFECTS if name not in model.effect_names]
    if not candidates or not (inadequate or th.targeted_refits):
        return [], {}
    say("screening the candidate effects on every record's part of the joint baseline")
    by_record = [
        {r.effect: r for r in screen_candidates(record, fit, candidates)}
        for record, fit in zip(ctx.records, ctx.baseline.fits)
    ]
    drop = {name: sum(screened[name].chi2_drop for screened in by_record) for name in candidates}
    promising = [name for name in candidates if drop[name] > 0.0]
    if not promising:
        return [], {}
    say(f"short refits on every record together: {', '.join(promising)}")
    jobs = [
        partial(_short_joint_refit, ctx, name, _screened_starts(ctx, name, [s[name] for s in by_record]))
        for name in promising
    ]
    short = dict(zip(promising, results_side_by_side(jobs)))
    ranked = sorted(promising, key=lambda name: short[name][0])
    ranked = [name for name in ranked if short[name][0] < ctx.chi2]
    if inadequate:
        chosen = ranked[: th.max_refits]
    else:  # the gain shown, in the units of the joint candidates' own (_Joint.delta_bic)
        residuals = JointResiduals(ctx.records, ctx.baseline.joint, ctx.noises)
        n = ctx.n_eff(residuals(ctx.baseline.theta[residuals.free]))
        promised = {name: ctx.delta_bic(short[name][0], ctx.with_effects(name), n) for name in ranked}
        chosen = [name for name in ranked if promised[name] > th.bic_significant][: th.max_refits]
    return [name for name in chosen if name not in taken], {name: [short[name]] for name in ranked}


def _short_joint_refit(ctx: _Joint, name: str, starts) -> tuple[float, np.ndarray]:
    """``(chi2, full joint vector)`` of the best of short solver runs
    (:data:`identify.diagnosis.fits.REFIT_SCREEN_EVALUATIONS` evaluations each) of explanation
    ``name`` on every record together, one from each joint start of ``starts``."""
    residuals = JointResiduals(ctx.records, ctx.with_effects(name), ctx.noises)
    runs = [_solve_from(residuals, start, REFIT_SCREEN_EVALUATIONS) for start in starts]
    chi2, _, x = min(runs, key=lambda run: run[0])
    return chi2, residuals.full(x)


def _screened_starts(ctx: _Joint, name: str, screened) -> list:
    """The joint baseline with effect ``name`` where each record's screening (``screened``, one
    :class:`~identify.diagnosis.screening.ScreeningResult` per record) puts it: one start per
    record, the effect's shared parameters from that record's screening, its run parameters from
    each record's own."""
    joint = ctx.with_effects(name)
    model_e = joint.model
    base = _embedded(ctx.baseline, joint)
    records = range(1, joint.n_records + 1)
    zeros = [float(joint.record_rows(base, r)[1][0]) for r in records]
    columns = np.arange(model_e.n_parameters)[model_e.effect_slice(name)]
    shared = np.array([c for c in columns if model_e.names[c] not in joint.per_record], dtype=int)
    thetas = [joint.record_theta(base, r) for r in records]
    for theta, result in zip(thetas, screened):
        theta[columns] = result.start[columns]  # each record's run parameters its own screening's
    starts = []
    for source in sorted(screened, key=lambda r: -r.chi2_drop):
        first = thetas[0].copy()
        first[shared] = source.start[shared]  # joint_theta takes the shared values from record 1's
        theta = np.clip(joint.joint_theta([first, *thetas[1:]], zeros), joint.parameters.lower, joint.parameters.upper)
        if not any(np.array_equal(theta, other) for other in starts):
            starts.append(theta)
    return starts


def _own_fits(alone, name: str) -> list:
    """Each record's own fit of explanation ``name`` (None where it has none)."""
    fits = []
    for d in alone:
        found = next(
            (c for c in [*d.ranking, *d.pairs_tried] if _same_explanation(c.effect, name) and c.fit is not None), None
        )
        fits.append(None if found is None else found.fit)
    return fits


def _same_explanation(one: str, other: str) -> bool:
    """Do two explanation names (``"a"``, ``"a+b"``) hold the same effects, in any order?"""
    return set(one.split("+")) == set(other.split("+"))


def _fit_candidate(ctx: _Joint, name: str, members=(), swap=None, screened=()):
    """Explanation ``name`` fitted on every record together from each record's own fit of it,
    from the joint baseline with it off (cold and warm: :func:`started_warm`) and from the ends
    of its short joint refits ``screened`` (``[(chi2, joint vector)]``, :func:`_screened`) that
    lie below where the other starts end: ``(JointFit, whitened residual)`` of the lowest
    chi-square.

    A pair never ends above one of its members fitted jointly (``members``: their
    :class:`JointFit`): where it would, it is fitted again from that member's joint fit with the
    partner off, as a model never ends above one it contains. ``swap``: ``(pair, single)`` joint
    fits of a pair that keeps this pair's partner and of the member swapped in: also started from
    the pair's fit with the single's own parameters (the partner in the pair's basin)."""
    own = _own_fits(ctx.alone, name)
    donors = [f for f in own if f is not None]
    base_model = ctx.baseline.joint.model
    runs, embedded = [], False
    if swap is not None and same_threshold_sign(swap[0].joint.model, base_model):
        runs.append(_swap_run(ctx, name, *swap))
    for donor in donors:
        model_e = donor.model
        joint = ctx.layout(model_e)
        # each donor's transducer parameters for every record (a record on another drive may
        # see the physics better than the first), each record's run parameters its own
        starts = [joint_start(joint, donor, [donor if f is None else f for f in own], ctx.records)]
        if not embedded and same_threshold_sign(model_e, base_model):  # the same start for every donor
            starts.append(_embedded(ctx.baseline, joint))
            warm = started_warm(joint, starts[-1])
            if warm is not None:
                starts.append(warm)
            embedded = True
        residuals = JointResiduals(ctx.records, joint, ctx.noises)
        runs += [_solve_from(residuals, start) for start in starts]
    finish = short_ends_to_finish(min((run[0] for run in runs), default=None), screened)
    if finish:
        residuals = JointResiduals(ctx.records, ctx.with_effects(name), ctx.noises)
        runs += [_solve_from(residuals, start) for start in finish]
    best = min(runs, key=lambda run: run[0], default=None)
    for member in sorted(members, key=lambda m: m.chi2):
        if best is not None and best[0] <= member.chi2:
            break
        partner = [e for e in name.split("+") if e not in {x.name for x in member.joint.model.effects}]
        joint = ctx.layout(member.joint.model + partner[0])
        run = _solve_from(JointResiduals(ctx.records, joint, ctx.noises), _embedded(member, joint))
        if best is None or run[0] < best[0]:
            best = run
    if best is None:
        return None
    _, residuals, x = best
    jf = joint_fit_at(residuals, x, ctx.baseline.fits)
    return jf, residuals(x)


def started_warm(joint: JointModel, theta) -> np.ndarray | None:
    """``theta`` with every record's earlier-run state (:func:`_earlier_run_columns`) at its
    :func:`~identify.fitting.joint.warm_value`, halfway from its off value to its farther bound,
    or None where ``joint`` has no such state.

    Records of one transducer each start where the earlier runs left them, and the joint fits
    free that state; but every other start holds it at its off value (a record's own fit pins
    it), so the solver meets it from the cold side only. A start inside the state's range, the
    effect's shape at its defaults, is the neutral way into a run that starts warm and cools."""
    columns = _earlier_run_columns(joint)
    if not columns:
        return None
    theta = np.array(theta, dtype=float)
    for column, off in columns:
        theta[column] = warm_value(joint.parameters[column], off)
    return theta


def _swap_run(ctx: _Joint, name: str, pair: JointFit, single: JointFit):
    """One solver run of pair ``name`` from ``pair``'s joint fit for every parameter the two pairs
    share and ``single``'s for the swapped-in member's own."""
    joint = ctx.with_effects(name)
    theta = _embedded(pair, joint)
    own = set(single.joint.names) - set(ctx.baseline.joint.names)
    for parameter, value in zip(single.joint.names, single.theta):
        if parameter in own and parameter in joint.names:
            theta[joint.names.index(parameter)] = value
    return _solve_from(JointResiduals(ctx.records, joint, ctx.noises), theta)


def _solve_from(
    residuals: JointResiduals, start, max_nfev: int = POLISH_EVALUATIONS
) -> tuple[float, JointResiduals, np.ndarray]:
    """``(chi2, residuals, free vector)`` of one bounded solver run on ``residuals`` from the full
    joint vector ``start`` (clipped into the bounds), at most ``max_nfev`` evaluations; where it
    ends on a bound, the interior method from that end and from the start too
    (:func:`identify.fitting.lsq_solver.solve_within_box`)."""
    x0 = np.clip(np.asarray(start)[residuals.free], residuals.lower, residuals.upper)
    with single_threaded_blas():
        sol = solve_within_box(residuals, x0, max_nfev)
    return 2.0 * float(sol.cost), residuals, sol.x


def _fit_candidates(ctx: _Joint, names, say, earlier=None, swaps=None, screened=None) -> tuple[list, dict, dict]:
    """``(ranking, adequate by record, joint fits)`` of every explanation of ``names`` fitted on
    every record together, side by side (each reads ``ctx`` alone); the ranking by delta BIC.
    ``earlier``: joint fits already made (``{name: JointFit}``), a pair's members among them;
    ``swaps``: ``{name: (pair, single)}`` and ``screened``: ``{name: [(chi2, joint vector)]}`` of
    :func:`_fit_candidate`."""
    swaps, screened = swaps or {}, screened or {}
    ranking, adequate_by_record, joint_fits = [], {}, dict(earlier or {})
    for name in names:
        say(f"'{name}' on every record together")
    singles = [n for n in names if "+" not in n]
    pairs = [n for n in names if "+" in n]
    for group in (singles, pairs):  # the pairs after the singles: a pair never ends above a member
        jobs = [
            partial(
                _fit_candidate,
                ctx,
                name,
                [joint_fits[m] for m in name.split("+") if m in joint_fits],
                swaps.get(name),
                screened.get(name, ()),
            )
            for name in group
        ]
        for name, fitted in zip(group, results_side_by_side(jobs)):
            if fitted is None:
                continue
            joint_fits[name] = fitted[0]
            candidate, adequate = ctx.measure(name, *fitted)
            ranking.append(candidate)
            adequate_by_record[name] = adequate
    ranking.sort(key=lambda c: -c.delta_bic)
    return ranking, adequate_by_record, joint_fits


@dataclass
class _Fitted:
    """The joint fits made so far: the ranking by delta BIC, each fit's adequacy on every record
    and the fits by name."""

    ranking: list
    adequate_by_record: dict
    joint_fits: dict

    def strength(self) -> dict:
        return {c.effect: c.delta_bic for c in self.ranking}

    def add(self, ctx: _Joint, names, swaps: dict, say) -> None:
        """Fit the pairs ``names`` (``swaps``: ``{name: (pair, single)}`` names of fits made)."""
        starts = {name: (self.joint_fits[pair], self.joint_fits[single]) for name, (pair, single) in swaps.items()}
        more, adequate, self.joint_fits = _fit_candidates(ctx, names, say, self.joint_fits, starts)
        self.ranking = sorted(self.ranking + more, key=lambda c: -c.delta_bic)
        self.adequate_by_record.update(adequate)


def _fit_rival_pairs(ctx: _Joint, fitted: _Fitted, say) -> None:
    """Fit the pairs that would name another effect than the best pair's member
    (:func:`rival_pair_names`), where any is not fitted yet."""
    rivals = rival_pair_names(fitted.strength(), ctx.th.max_refits)
    if rivals:
        say("before a member of the best pair is named, the pairs that swap it for a single as strong:")
        fitted.add(ctx, [name for name, _, _ in rivals], {name: (best, single) for name, best, single in rivals}, say)


def _freed_layout(model, like: JointModel) -> JointModel:
    """``model`` laid out for ``like``'s records and sensor-zero bound, the state earlier runs
    left free in each (:func:`identify.fitting.joint.with_earlier_runs`): every joint fit of the
    diagnosis, its baseline's too."""
    return JointModel(with_earlier_runs(model), like.n_records, like.zero_bound)


def joint_fit_with_earlier_runs(jf: JointFit) -> JointFit:
    """A joint fit in the layout the joint diagnosis fits its candidates in, the state earlier
    runs left free on every record (:func:`identify.fitting.joint.with_earlier_runs`), refitted
    from it, cold and warm (:func:`started_warm`), where that frees a parameter (never higher:
    where the records start at rest it is the same fit)."""
    joint = _freed_layout(jf.joint.model, jf.joint)
    if int(joint.parameters.vary.sum()) == int(jf.joint.parameters.vary.sum()):
        return jf
    residuals = JointResiduals(jf.records, joint, jf.noises)
    starts = [_embedded(jf, joint)]
    warm = started_warm(joint, starts[0])
    if warm is not None:
        starts.append(warm)
    chi2, _, x = min((_solve_from(residuals, start) for start in starts), key=lambda run: run[0])
    if not chi2 < jf.chi2:  # the records start at rest: the same fit in the freed layout
        x = np.clip(_embedded(jf, joint)[residuals.free], residuals.lower, residuals.upper)
    return joint_fit_at(residuals, x, jf.separate)


def _embedded(baseline: JointFit, joint: JointModel) -> np.ndarray:
    """The joint baseline's vector in ``joint`` (its new effects off)."""
    theta = joint.default_theta()
    for name, value in zip(baseline.joint.names, baseline.theta):
        if name in joint.names:
            theta[joint.names.index(name)] = value
    return theta


def diagnose_records(
    records,
    model=None,
    *,
    diagnose_one,
    thresholds: Thresholds | None = None,
    n_starts: int = 6,
    rng=None,
    progress=None,
) -> JointDiagnosis:
    """The joint diagnosis of several records of one transducer (module docstring).

    Parameters
    ----------
    records : sequence of Record
        Two or more records, in the same units, each with its unenergised start.
    model : Model or sequence of str, optional
        As :func:`identify.diagnosis.diagnose`.
    diagnose_one : callable
        The diagnosis of one record (:func:`identify.diagnosis.diagnose`).
    thresholds : Thresholds, optional
    n_starts : int, default 6
    rng : numpy.random.Generator, optional
    progress : callable(str), optional

    Returns
    -------
    JointDiagnosis
    """
    t0 = _time.perf_counter()
    thresholds = Thresholds() if thresholds is None else thresholds
    say = progress or (lambda message: None)
    rng = np.random.default_rng(0) if rng is None else rng
    records = list(records)
    alone = []
    for r, record in enumerate(records, start=1):
        say(f"record {r} of {len(records)} alone: {record.source}")
        alone.append(diagnose_one(record, model, thresholds=thresholds, n_starts=n_starts, rng=rng, progress=say))
    base_model = alone[0].fit.model
    say("the baseline on every record together")
    separate = [d.fit if same_threshold_sign(d.fit.model, base_model) else alone[0].fit for d in alone]
    baseline = fit_joint(records, base_model, [d.fit.noise for d in alone], separate=separate, rng=rng)
    baseline = joint_fit_with_earlier_runs(baseline)
    ctx = _Joint(records, alone, baseline, thresholds, rng)
    names = explanations_worth_finishing(alone, thresholds)
    more, short_ends = _screened(ctx, names, say)
    ranking, adequate_by_record, joint_fits = _fit_candidates(ctx, names + more, say, screened=short_ends)
    fitted = _Fitted(ranking, adequate_by_record, joint_fits)
    _fit_rival_pairs(ctx, fitted, say)
    evidence = _evidence(ctx, fitted.ranking)
    decision = decide(evidence, thresholds)
    closure = tie_member_pairs(decision.tied, fitted.strength())
    if decision.status == "tied" and closure:
        say("before the tie is the verdict, the pairs of its members not fitted yet:")
        fitted.add(ctx, [n for n, _ in closure], {n: w for n, w in closure if w}, say)
        _fit_rival_pairs(ctx, fitted, say)  # a new best pair: its rivals before a member is named
        evidence = _evidence(ctx, fitted.ranking)
        decision = decide(evidence, thresholds)
    ranking, adequate_by_record, joint_fits = fitted.ranking, fitted.adequate_by_record, fitted.joint_fits
    reason = explain(decision, evidence, thresholds, where_text(ctx.profiles[_worst(ctx)], thresholds.z_critical))
    rows = _record_rows(records, baseline, ctx, alone)
    return JointDiagnosis(
        decision.status,
        decision.missing,
        tuple(decision.tied) if decision.status == "tied" else (),
        decision.rule,
        reason,
        tuple(base_model.effect_names),
        rows,
        [c for c in ranking if "+" not in c.effect],
        adequate_by_record,
        alone,
        baseline,
        decision,
        evidence,
        thresholds,
        _time.perf_counter() - t0,
        [c for c in ranking if "+" in c.effect],
        joint_fits,
    )


def _record_rows(records, baseline, ctx, alone) -> list[dict]:
    return [
        {
            "source": rec.source,
            "samples": len(rec.time),
            "noise_sigma": float(f.noise.sigma),
            "rms": float(f.rms),
            "adequate": bool(a.adequate),
            "failed": list(a.failed),
            "alone": d.verdict_text(),
        }
        for rec, f, a, d in zip(records, baseline.fits, ctx.adequacies, alone)
    ]


def _worst(ctx: _Joint) -> int:
    return int(np.argmax([a.size_ratio for a in ctx.adequacies]))


def _evidence(ctx: _Joint, ranking) -> Evidence:
    """The joint evidence: the joint baseline (inadequate when any record is), every joint
    explanation and the gaps between them on the concatenated residual."""
    explanations = [c.explanation() for c in ranking]
    gaps = gaps_among(explanations, [c.whitened for c in ranking])
    worst = ctx.adequacies[_worst(ctx)]
    adequate = all(a.adequate for a in ctx.adequacies)
    baseline = worst if adequate == worst.adequate else Adequacy(adequate, *list(worst.__dict__.values())[1:])
    strength = {}
    for d in ctx.alone:
        for c in d.ranking:
            strength[c.effect] = strength.get(c.effect, 0.0) + c.delta_bic
    sigma = _pooled([f.noise.sigma for f in ctx.baseline.fits], ctx.energised)
    rms = _pooled([f.rms for f in ctx.baseline.fits], ctx.energised)
    model: Model = ctx.baseline.joint.model
    return Evidence(
        sigma,
        rms,
        baseline,
        tuple(explanations),
        gaps,
        strength,
        tuple(e.name for e in model.effects if e.first_cycle),
        bool(adequate),
    )
