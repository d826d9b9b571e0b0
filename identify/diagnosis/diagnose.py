"""Which physical effect is missing? The diagnosis as evidence, a decision and an explanation.

:func:`diagnose` reads as its steps:

1. **Baseline**: the model fitted in each threshold sign (:mod:`identify.diagnosis.baseline`),
   its residual's noise tests against the quiet start (:mod:`identify.diagnosis.adequacy`).
2. **Search**: every library effect screened and refitted from its start strategies, the
   promising ones finished on the whole record (:mod:`identify.diagnosis.search`); on a residual
   that is not noise, pairs too (:mod:`identify.diagnosis.pairs`); on one that is, the candidates
   whose targeted score promises a significant gain.
3. **Evidence**: every finished explanation's fit, adequacy and the gaps between them with
   their noise (:mod:`identify.diagnosis.evidence`).
4. **Decision**: a pure function of the evidence, one rule table
   (:mod:`identify.diagnosis.decision`); before a name is given, the rivals the search has not
   finished are finished and the decision is taken again.
5. **Explanation**: the decision in sentences (:mod:`identify.diagnosis.explanation`).

Four verdicts (:data:`STATUSES`): ``adequate`` (the residual is the sensor's noise),
``missing_effect`` (add the named effect), ``tied`` (several explanations repair the model and
the data do not separate them: another record can) and ``unexplained`` (structure no
candidate or pair explains). Everything runs on least squares from one explicit
:class:`numpy.random.Generator`.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from model import get_effect

from ..data.reversals import find_reversals
from ..fitting.joint import check_records
from ..fitting.lsq import FitResult
from ..fitting.noise import NoiseModel, quiet_segment
from ..fitting.threads import results_side_by_side
from ..logs import progress_function
from .adequacy import Adequacy, Thresholds, rms_change_and_size
from .baseline import best_baseline, fit_baselines, known_noise, model_and_candidates, noise_reference
from .candidates import CandidateResult, explained_fraction, unrefitted_candidate
from .decision import STATUSES, Decision, decide
from .evidence import Evidence, gaps_among
from .explanation import explain, where_text
from .fits import attempt, effect_values, working_copy
from .joint import JointDiagnosis, diagnose_records
from .mimic import mimic_start
from .pairs import rival_pairs, search_pairs
from .reparametrisation import exact_reparametrisation
from .residuals import ResidualProfile
from .search import Round, Setting, Short, finish_candidates, own_values, refit_short, search, worth_finishing

__all__ = ["STATUSES", "Diagnosis", "diagnose"]


@dataclass
class Diagnosis:
    """The diagnosis of one fit.

    Attributes
    ----------
    effects : tuple of str
        The effects of the diagnosed model.
    noise_sigma, rms, max_error_pct : float
        The noise sigma and the baseline's residual RMS [output units] and max error [% of range].
    status : str
        One of :data:`STATUSES`.
    missing : str or None
        The effect to add (``missing_effect``).
    tied : tuple of str
        The explanations the data do not separate (``tied``), best first.
    rule : str
        The decision's rule (:data:`identify.diagnosis.decision.RULES`).
    reason : str
        The explanation in sentences.
    adequacy : Adequacy
        The baseline residual's noise tests.
    ranking : list of CandidateResult
        The single candidates: finished ones by delta BIC, then the others (working copy), the
        not identifiable ones and the failed ones.
    pair : CandidateResult or None
        The pair the decision rests on, else the best pair.
    pairs_tried : list of CandidateResult
        Every pair finished on the whole record, best first.
    fit : FitResult
        The baseline fit.
    profile : ResidualProfile
        The baseline residual's profile.
    thresholds : Thresholds
    seconds : float
    first_loading_share : float or None
        For a named effect: its share of its part of the fit in the first loading.
    gaps : list of dict
        ``better``, ``other``, ``gap``, ``noise_sd`` between every two finished explanations.
    decision : Decision
    evidence : Evidence
    """

    effects: tuple
    noise_sigma: float
    rms: float
    max_error_pct: float
    status: str
    missing: str | None
    reason: str
    adequacy: Adequacy
    ranking: list
    pair: CandidateResult | None
    fit: FitResult
    profile: ResidualProfile
    thresholds: Thresholds
    seconds: float
    pairs_tried: list = field(default_factory=list)
    first_loading_share: float | None = None
    gaps: list = field(default_factory=list)
    tied: tuple = ()
    rule: str = ""
    decision: Decision | None = None
    evidence: Evidence | None = None

    @property
    def best(self) -> CandidateResult | None:
        """The named (or else the top-ranked refitted) candidate, for before/after views."""
        for c in self.ranking:
            if c.effect == self.missing:
                return c
        return next((c for c in self.ranking if c.refitted), None)

    def to_dict(self) -> dict:
        """JSON-ready: the verdict, the ranking, the pairs, the gaps, the evidence and the fit."""
        return {
            "effects": list(self.effects),
            "noise_sigma": float(self.noise_sigma),
            "rms": float(self.rms),
            "max_error_pct": float(self.max_error_pct),
            "status": self.status,
            "missing": self.missing,
            "tied": list(self.tied),
            "rule": self.rule,
            "reason": self.reason,
            "statistic": "delta_bic",
            "ranking": [c.to_dict() for c in self.ranking],
            "pair": None if self.pair is None else self.pair.to_dict() | self.pair.details(),
            "pairs_tried": [p.to_dict() for p in self.pairs_tried],
            "details": {c.effect: c.details() for c in self.ranking},
            "gaps": [dict(g) for g in self.gaps],
            "decision": None if self.decision is None else self.decision.to_dict(),
            "evidence": None if self.evidence is None else self.evidence.to_dict(),
            "adequacy": self.adequacy.to_dict(),
            "where": self.profile.to_dict(),
            "fit": {
                "model": self.fit.model.to_dict(),
                "theta": {n: float(v) for n, v in zip(self.fit.model.names, self.fit.theta)},
                "rms": float(self.fit.rms),
                "max_error_pct": float(self.fit.max_error_pct),
                "reduced_chi2": float(self.fit.reduced_chi2),
                "noise": self.fit.noise.to_dict(),
                "seconds": float(self.fit.seconds),
            },
            "thresholds": self.thresholds.to_dict(),
            "seconds": float(self.seconds),
            "first_loading_share": self.first_loading_share,
        }

    def verdict_text(self) -> str:
        """The verdict in one line: ``missing_effect -> add 'thermal'``, ``tied: creep | thermal``."""
        if self.status == "missing_effect":
            return f"missing_effect -> add '{self.missing}'"
        if self.status == "tied":
            return "tied: " + " | ".join(self.tied)
        return self.status

    def summary(self) -> str:
        """A short human summary (a few lines)."""
        unit = "um"
        lines = [
            f"model: GPI{''.join(' + ' + e for e in self.effects)}",
            f"noise sigma {self.noise_sigma:.4g} {unit}; residual RMS {self.rms:.4g} {unit} "
            f"({self.rms / self.noise_sigma:.3f} sigma), max error {self.max_error_pct:.3g} % of range",
            f"verdict: {self.verdict_text()}",
            self.reason,
        ]
        for title, items in (
            ("candidates (refitted):", [c for c in self.ranking if c.refitted]),
            ("pairs refitted together:", self.pairs_tried),
        ):
            if items:
                lines.append(title)
                width = max(len(c.effect) for c in items)
                for c in items:
                    lines.append(
                        f"  {c.effect:<{width}}  RMS after {c.rms_after:<7.4g} {unit}, delta BIC {c.delta_bic:9.1f}, "
                        f"explains {100 * c.explained:5.1f} % of the excess"
                        + (", adequate after" if c.adequate_after else "")
                    )
        unidentifiable = [c.effect for c in self.ranking if c.note.startswith("not identifiable")]
        if unidentifiable:
            lines.append("not identifiable (exact reparametrisations of the model): " + ", ".join(unidentifiable))
        others = [c for c in self.ranking if not c.refitted and not c.note]
        if others:
            lines.append(
                "other candidates (working copy only): "
                + ", ".join(f"{c.effect} ({100 * c.explained:.0f} %)" for c in others)
            )
        return "\n".join(lines)


def _unrefitted(rnd: Round) -> list:
    """Ranking entries of the candidates neither finished nor failed, by falling delta BIC on the
    working copy (their short refit, or their screening when there was none)."""
    entries = []
    for name, one in rnd.screened.items():
        if name in rnd.refitted or name in rnd.failed:
            continue
        short = rnd.short.get(name)
        chi2, model_e, theta = (
            (one.chi2_after, rnd.fit.model + name, one.start)
            if short is None
            else (short.chi2, short.model, short.theta)
        )
        chi2 = min(max(chi2, 1e-300), rnd.chi2_small)
        gain = rnd.working_gain(chi2, get_effect(name).n_varying())
        drop = rnd.chi2_small - chi2
        entry = unrefitted_candidate(
            name,
            one,
            rnd.fit,
            effect_values(model_e, theta, name),
            gain,
            explained_fraction(rnd.excess_small, rnd.excess_small - drop) if rnd.excess_small > 0 else 0.0,
            rnd.n_eff_small,
        )
        entry.rms_after = float(rnd.fit.rms * math.sqrt(chi2 / rnd.chi2_small))
        entries.append(entry)
    return sorted(entries, key=lambda c: -c.delta_bic)


def _not_identifiable(redundant, rnd: Round) -> list:
    """Ranking entries of the exact reparametrisations: no gain, the reason in the note."""
    entries = []
    for name in redundant:
        k = get_effect(name).n_varying()
        entries.append(
            CandidateResult(
                name,
                None,
                False,
                float(rnd.fit.rms),
                None,
                float(-k * math.log(rnd.n_eff_small)),
                float(rnd.n_eff_small),
                0.0,
                None,
                note="not identifiable: an exact reparametrisation of the fitted model (adding it changes nothing "
                "the model's own parameters cannot; identify.diagnosis.reparametrisation)",
            )
        )
    return entries


def _targeted(s: Setting, rnd: Round, names) -> None:
    """Candidates ``names`` refitted from their screening and finished on the whole record (on a
    residual that passes the noise tests, a score aimed at one effect's signature has more power
    than the omnibus tests)."""
    names = list(names)
    for name in names:
        s.say(f"targeted check: refitting with '{name}'")
    shorts = results_side_by_side([partial(refit_short, s, rnd, name, rnd.fit.model + name, rnd.fit) for name in names])
    jobs = [(name, short, ()) for name, short in zip(names, shorts)]
    for name, result in zip(names, finish_candidates(s, rnd, jobs)):
        if result is not None:
            rnd.refitted[name] = result


def _pairs_worth(s: Setting, rnd: Round) -> bool:
    """Pairs are searched on a residual that is not noise when the best single is needed and
    either reaches the noise with a practical size (a pair may still be needed beside it) or
    explains at least ``explained_minor`` without reaching it."""
    ranked = rnd.ranked()
    if not (s.thresholds.try_pairs and ranked) or rnd.adequacy.adequate:
        return False
    best = ranked[0]
    if best.delta_bic <= s.thresholds.bic_significant:
        return False
    if best.adequate_after:
        change, size = rms_change_and_size(rnd.fit.rms, best.rms_after, rnd.fit.noise.sigma)
        return change >= s.thresholds.practical_rms_change and size >= s.thresholds.structure_floor
    return best.explained >= s.thresholds.explained_minor


def gather_evidence(rnd: Round) -> Evidence:
    """The evidence of a round: every finished single and pair, the gaps between them, the
    singles' strength alone (finished, else their working-copy gain)."""
    finished = [c for c in [*rnd.refitted.values(), *rnd.pairs.values()] if c.fit is not None and c.chi2 is not None]
    explanations = [c.explanation() for c in finished]
    gaps = gaps_among(explanations, [c.whitened for c in finished])
    strength = {c.effect: c.delta_bic for c in _unrefitted(rnd)} | {
        c.effect: c.delta_bic for c in rnd.refitted.values()
    }
    return Evidence(
        sigma=float(rnd.fit.noise.sigma),
        baseline_rms=float(rnd.fit.rms),
        baseline=rnd.adequacy,
        explanations=tuple(explanations),
        gaps=gaps,
        strength=strength,
        first_cycle=tuple(e.name for e in rnd.fit.model.effects if e.first_cycle),
        targeted=bool(rnd.adequacy.adequate),
    )


def _check_rivals(s: Setting, rnd: Round, decision: Decision) -> bool:
    """Before a name (or a tie) stands, the rivals the search has not finished are finished:
    on a residual that passes the noise tests, every candidate whose screening shows a gain; for
    a name taken from a pair, the pairs that swap it for another candidate. Whether any was."""
    if decision.status not in ("missing_effect", "tied") and decision.rule != "first_loading_only":
        return False
    if rnd.adequacy.adequate:
        pending = [c.effect for c in _unrefitted(rnd) if c.delta_bic > 0.0]
        _targeted(s, rnd, pending)
        return bool(pending)
    finished = []
    while decision.status == "missing_effect":
        more = _rivals_from_the_name(s, rnd, decision)
        if not more:
            break
        finished += more
        decision = decide(gather_evidence(rnd), s.thresholds)
    if decision.rule == "named_from_pair" and decision.best in rnd.pairs:
        finished += rival_pairs(s, rnd, decision.missing, rnd.pairs[decision.best])
    return bool(finished)


def _rivals_from_the_name(s: Setting, rnd: Round, decision: Decision) -> list:
    """Before a name stands, its rivals are started where they reproduce the named
    explanation's output (:mod:`identify.diagnosis.mimic`), once per rival and name: every
    candidate the search did not finish (a screening is no evidence that a rival cannot explain
    what the name explains), and every finished one that repairs the model too (that it lost
    may be the basin its finish ended in, not the data: the fit from the new start is kept
    where its chi-square is lower). An unfinished one is finished where its short refit from
    there is worth it as any candidate's beyond the best few (it beats the baseline on the
    working copy and gains significantly there). The names whose fit was finished or improved."""
    named = rnd.pairs.get(decision.best) or rnd.refitted.get(decision.best)
    if named is None or named.fit is None:
        return []
    inside = set(named.effect.split("+"))
    unfinished = [n for n in rnd.screened if n not in rnd.refitted and n not in rnd.failed]
    repairing = [n for n, c in rnd.refitted.items() if c.adequate_after]
    pending = [n for n in [*unfinished, *repairing] if n not in inside and (n, named.effect) not in rnd.mimicked]
    rnd.mimicked.update((n, named.effect) for n in pending)
    for name in pending:
        s.say(f"before naming '{decision.missing}': '{name}' started where it mimics '{named.effect}'")
    jobs = []  # the short refits from where each mimics the name side by side, then their finishes
    beyond_the_best = s.thresholds.max_refits
    for name, (lines, short) in zip(
        pending, results_side_by_side([partial(_from_mimic, s, rnd, named, n) for n in pending])
    ):
        for line in lines:
            s.say(line)
        if short is None:
            continue
        if name in rnd.refitted or worth_finishing(s, rnd, name, short.chi2, beyond_the_best):
            jobs.append((name, short, ()))
        else:
            s.say(f"'{name}' from there gains nothing significant on the working copy: not finished")
    changed = []
    for (name, _, _), result in zip(jobs, finish_candidates(s, rnd, jobs)):
        before = rnd.refitted.get(name)
        if result is not None and (before is None or result.chi2 < before.chi2):
            rnd.refitted[name] = result
            changed.append(name)
    return changed


def _from_mimic(s: Setting, rnd: Round, named: CandidateResult, name: str) -> tuple[list, Short | None]:
    """``(lines to say, short refit)`` of candidate ``name`` from where it mimics ``named``
    (besides its usual starts); None where the short refit failed."""
    lines = []
    model_e = rnd.fit.model + name
    work = s.work.record
    mimic = attempt(
        lambda: mimic_start(
            named.fit.model, named.fit.theta, model_e, name, work.time, work.current, own_values(rnd, name, model_e)
        ),
        lines.append,
        "no start",
    )
    extra = [] if mimic is None else [mimic]
    return lines, attempt(
        lambda: refit_short(s, rnd, name, model_e, rnd.fit, extra=extra), lines.append, "not possible"
    )


def diagnose(
    record,
    model=None,
    *,
    noise: NoiseModel | None = None,
    fit: FitResult | None = None,
    thresholds: Thresholds | None = None,
    n_starts: int = 6,
    rng: np.random.Generator | None = None,
    candidates=None,
    progress: Callable[[str], None] | bool | None = None,
) -> Diagnosis | JointDiagnosis:
    """Least squares plus the diagnosis (module docstring).

    Parameters
    ----------
    record : identify.data.records.Record or sequence of Record
        ``time`` [s], ``current`` [A], ``displacement`` [um], shape (T,), with an unenergised
        start (the noise reference, at least 20 samples) unless ``noise`` gives a sigma.
        Several records of one transducer are diagnosed together, each from its own quiet start
        (:func:`identify.diagnosis.joint.diagnose_records`): a :class:`JointDiagnosis`.
    model : Model or sequence of str, optional
        The model to diagnose; effect names give the normalised GPI plus those effects
        (:func:`identify.fitting.parametrisation.normalised_model`); default the plain GPI.
    noise : NoiseModel, optional
        Default :func:`identify.fitting.noise.estimate_noise` of the record.
    fit : FitResult, optional
        A baseline fit of ``model`` to ``record`` to reuse (skips the baseline least squares).
    thresholds : Thresholds, optional
    n_starts : int, default 6
        Starts of the baseline least squares per threshold sign.
    rng : numpy.random.Generator, optional
        Default ``numpy.random.default_rng(0)``.
    candidates : sequence of str, optional
        Effects to consider; default every library effect not in the model.
    progress : callable(str) or bool, optional
        Called with a short message at each stage. Default (None): the messages are shown
        on stderr (a terminal, a notebook's cell) unless :mod:`logging` is configured
        (:func:`identify.logs.progress_function`); False: none.

    Returns
    -------
    Diagnosis or JointDiagnosis

    Raises
    ------
    ValueError
        A record without a quiet segment of >= 20 samples (unless the noise sigma is user-given),
        a free noise sigma, an unknown effect, or a ``fit`` of another model.
    """
    progress = progress_function(progress, "diagnosis: ")  # lines on stderr by default, False: none
    if isinstance(record, (list, tuple)):
        record = check_records(record)
        if len(record) > 1:
            return _diagnose_several(record, model, noise, fit, candidates, thresholds, n_starts, rng, progress)
        record = record[0]
    t_start = _time.perf_counter()
    thresholds = Thresholds() if thresholds is None else thresholds
    rng = np.random.default_rng(0) if rng is None else rng
    say = progress
    model, candidates = model_and_candidates(model, fit, candidates)
    noise = known_noise(record, noise, fit)
    quiet = noise.quiet if noise.quiet is not None else quiet_segment(record.current)
    work = working_copy(record, noise, find_reversals(record.current).index)
    sign_baselines = []
    if fit is None:
        sign_baselines = fit_baselines(
            record, model, noise, n_starts=n_starts, rng=rng, progress=say, tie_bic=thresholds.bic_significant
        )
        fit = best_baseline(record, sign_baselines)
    redundant = [name for name in candidates if exact_reparametrisation(record, fit.model, fit.theta, name)]
    candidates = [name for name in candidates if name not in redundant]
    quiet, noise_ref = noise_reference(record, fit, noise, quiet)
    s = Setting(record, work, quiet, noise_ref, thresholds, n_starts, rng, say, candidates, redundant, sign_baselines)
    rnd = search(s, fit)
    decision, evidence = _finish(s, rnd)
    return _diagnosis(rnd, decision, evidence, s.redundant, t_start)


def _finish(s: Setting, rnd: Round) -> tuple[Decision, Evidence]:
    """The targeted refits or the pairs the first round calls for, then the evidence and the decision."""
    thresholds = s.thresholds
    if rnd.adequacy.adequate and thresholds.targeted_refits:
        promising = [c.effect for c in _unrefitted(rnd) if c.delta_bic > thresholds.bic_significant]
        _targeted(s, rnd, promising[: thresholds.max_refits])
    elif _pairs_worth(s, rnd):
        search_pairs(s, rnd)
    evidence = gather_evidence(rnd)
    decision = decide(evidence, thresholds)
    if _check_rivals(s, rnd, decision):
        evidence = gather_evidence(rnd)
        decision = decide(evidence, thresholds)
    return decision, evidence


def _diagnose_several(records, model, noise, fit, candidates, thresholds, n_starts, rng, progress):
    if noise is not None or fit is not None or candidates is not None:
        raise ValueError(
            "several records are diagnosed each from its own quiet start: noise, fit and candidates apply to one record"
        )
    return diagnose_records(
        records, model, diagnose_one=diagnose, thresholds=thresholds, n_starts=n_starts, rng=rng, progress=progress
    )


def _diagnosis(rnd: Round, decision: Decision, evidence: Evidence, redundant, t_start: float) -> Diagnosis:
    fit, thresholds = rnd.fit, rnd.ref.thresholds
    reason = explain(decision, evidence, thresholds, where_text(rnd.profile, thresholds.z_critical))
    ranking = rnd.ranked() + _unrefitted(rnd) + _not_identifiable(redundant, rnd) + list(rnd.failed.values())
    pairs = sorted(rnd.pairs.values(), key=lambda c: -c.delta_bic)
    pair = rnd.pairs.get(decision.best) or (pairs[0] if pairs else None)
    named = decision.status == "missing_effect"
    return Diagnosis(
        effects=tuple(fit.model.effect_names),
        noise_sigma=float(fit.noise.sigma),
        rms=float(fit.rms),
        max_error_pct=float(fit.max_error_pct),
        status=decision.status,
        missing=decision.missing,
        reason=reason,
        adequacy=rnd.adequacy,
        ranking=ranking,
        pair=pair,
        fit=fit,
        profile=rnd.profile,
        thresholds=thresholds,
        seconds=_time.perf_counter() - t_start,
        pairs_tried=pairs,
        first_loading_share=decision.numbers.get("first_loading_share") if named else None,
        gaps=[g.to_dict() for g in evidence.gaps],
        tied=tuple(decision.tied) if decision.status == "tied" else (),
        rule=decision.rule,
        decision=decision,
        evidence=evidence,
    )
