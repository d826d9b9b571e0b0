"""One candidate measured: an effect (or a pair of effects) added to the baseline, refitted on
the whole record, and what that refit shows.

:func:`evaluate` finishes a candidate from a start on the whole record, never ending above a
model it contains (the baseline; for a pair, each member alone), and measures it against the
baseline: the delta BIC of its best form (the nested question whether the effect is needed,
its optional terms charged only where the record pays for them), the fraction of the
baseline's excess it explains, its residual's adequacy, and the share of its part of the fit
that lies in the first loading. :class:`CandidateResult` holds it all; the evidence of the
diagnosis is a list of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from model import Model, get_effect

from ..data.reversals import find_reversals
from ..fitting.lsq import FitResult, WhitenedResiduals
from ..fitting.terms import best_form
from .adequacy import Adequacy, Thresholds, assess_adequacy
from .evidence import Explanation
from .fits import embed, finish, n_eff, plain_of, profile_of, same_threshold_sign, whitened
from .residuals import ARNoise, ResidualProfile
from .screening import ScreeningResult

__all__ = [
    "CandidateResult",
    "Reference",
    "evaluate",
    "failed_candidate",
    "unrefitted_candidate",
    "explained_fraction",
    "first_loading_share",
    "MEMBER_SHORTFALL_BIC",
]

#: A pair's refit that ends above one of its members alone by more than this in BIC is finished
#: again from that member's fit (:func:`evaluate`): most pairs end at their better member's
#: optimum with the other effect nearly off, where a smaller shortfall decides nothing.
MEMBER_SHORTFALL_BIC = 1.0


@dataclass
class CandidateResult:
    """One candidate effect (or pair ``"a+b"``), screened and possibly refitted.

    Attributes
    ----------
    effect : str
        Effect name (``"a+b"`` for a pair).
    screening : ScreeningResult or None
    refitted : bool
        True: least squares run to convergence on the whole record. False: the numbers are
        from the short refit on the working copy (an upper bound on the chi-square, so
        ``delta_bic`` and ``explained`` are lower bounds) or from the screening.
    rms_after : float
        Residual RMS over the energised part with the effect added [output units].
    max_error_pct_after : float or None
        Max |residual| as % of the output range (None when not refitted).
    delta_bic : float
        :math:`\\Delta\\mathrm{BIC}` of adding the effect to the baseline (positive favours
        it): whether the effect is needed, its parameters charged.
    n_eff : float
        The effective sample size used, :math:`n (1-\\rho)/(1+\\rho)`.
    explained : float
        Fraction of the baseline's excess (in its measure) the effect removes, in [0, 1].
    adequate_after : bool or None
        Whether the residual with the effect passes the adequacy rule (None when not refitted).
    z_after : dict
        Tests' standardised excess after the refit (empty when not refitted).
    parameters, parameter_stderr : dict
        The added effects' fitted parameters ``{name: value}`` and standard errors.
    fit : FitResult or None
    profile : ResidualProfile or None
    note : str
        Why the candidate was not screened or refitted; empty otherwise.
    uncharged_terms : list of str
        The optional terms (``"effect.term"``) the record does not pay for, not charged.
    chi2 : float or None
        Whitened chi-square on the whole record (None when not refitted).
    first_loading_share : float or None
        Share (in squares) of its part of the fit that lies in the first loading
        (:func:`first_loading_share`).
    whitened : ndarray or None
        Its whitened residual on the whole record (for the gaps between candidates; not saved).
    """

    effect: str
    screening: ScreeningResult | None
    refitted: bool
    rms_after: float
    max_error_pct_after: float | None
    delta_bic: float
    n_eff: float
    explained: float
    adequate_after: bool | None
    z_after: dict = field(default_factory=dict)
    parameters: dict = field(default_factory=dict)
    parameter_stderr: dict = field(default_factory=dict)
    fit: FitResult | None = None
    profile: ResidualProfile | None = None
    note: str = ""
    uncharged_terms: list = field(default_factory=list)
    chi2: float | None = None
    first_loading_share: float | None = None
    whitened: np.ndarray | None = field(default=None, repr=False)

    @property
    def effects(self) -> tuple[str, ...]:
        """The effects this candidate adds (one, or two for a pair)."""
        return tuple(self.effect.split("+"))

    def explanation(self) -> Explanation:
        """This finished candidate as the decision sees it (its ``chi2`` must be set)."""
        return Explanation(
            self.effect,
            float(self.chi2),
            float(self.n_eff),
            float(self.delta_bic),
            bool(self.adequate_after),
            float(self.rms_after),
            float(self.explained),
            self.first_loading_share,
        )

    def to_dict(self) -> dict:
        """The ranking entry: flat numbers (a table row) plus the fitted ``parameters``."""
        return {
            "effect": self.effect,
            "rms_after": float(self.rms_after),
            "max_error_pct_after": None if self.max_error_pct_after is None else float(self.max_error_pct_after),
            "delta_bic": float(self.delta_bic),
            "explained_fraction": float(self.explained),
            "adequate_after": self.adequate_after,
            "refitted": bool(self.refitted),
            "parameters": {k: float(v) for k, v in self.parameters.items()},
        } | ({"note": self.note} if self.note else {})

    def details(self) -> dict:
        """The rest: effective sample size, tests after, standard errors, screening."""
        return {
            "n_eff": float(self.n_eff),
            "chi2": None if self.chi2 is None else float(self.chi2),
            "z_after": {k: float(v) for k, v in self.z_after.items()},
            "parameter_stderr": {
                k: (None if not np.isfinite(v) else float(v)) for k, v in self.parameter_stderr.items()
            },
            "screening": None if self.screening is None else self.screening.to_dict(),
            "uncharged_terms": list(self.uncharged_terms),
            "first_loading_share": self.first_loading_share,
        }


@dataclass(frozen=True)
class Reference:
    """What a candidate is measured against: the record, the baseline fit (its whitened
    chi-square and adequacy), the noise reference of the quiet start, the thresholds and the
    random generator of the diagnosis."""

    record: object
    fit: FitResult
    chi2: float
    adequacy: Adequacy
    quiet: slice | None
    noise_ref: ARNoise
    thresholds: Thresholds
    rng: np.random.Generator


def explained_fraction(before: float, after: float) -> float:
    """``1 - after / before`` clipped to [0, 1] (0 when there was nothing to explain)."""
    if not before > 0:
        return 0.0
    return float(min(max(1.0 - after / before, 0.0), 1.0))


def _nested_start(fit_ref: FitResult, model_e: Model) -> tuple[Model, np.ndarray] | None:
    """``(model, full vector)``: the nested fit ``fit_ref`` as a start of ``model_e`` (its other
    effects off), in ``fit_ref``'s threshold sign; None when it does not nest or lies outside
    the bounds."""
    target = model_e
    if not same_threshold_sign(fit_ref.model, model_e):
        target = plain_of(fit_ref.model, model_e)
        if not same_threshold_sign(fit_ref.model, target):  # alpha free on one side only
            return None
    try:
        nested = embed(fit_ref.model, fit_ref.theta, target)
    except ValueError:  # not nested after all
        return None
    return (target, nested) if target.in_bounds(nested)[0] else None


def _finish_no_worse_than_nested(ref: Reference, model_e: Model, start, members=()):
    """``(fit, whitened residual, chi-square)`` of ``model_e`` finished from ``start``; when that
    ends above a model it contains, finished again from that model's fit and the lower kept.

    A refit from a candidate's own start can stop in a worse basin than a model it contains
    (the GPI's least squares has several), and a candidate must never be charged for the
    optimiser's shortfall. The nested models: the baseline (any shortfall counts) and, for a
    pair, its members alone (``members``: ``(chi2, fit)``; a shortfall counts above
    :data:`MEMBER_SHORTFALL_BIC` in BIC). A member fitted with the other threshold sign nests
    in ``model_e`` of that sign, so the pair is finished there from it."""
    record, noise = ref.record, ref.fit.noise
    free = WhitenedResiduals(record, model_e, noise).free
    fit_e = finish(record, model_e, noise, np.asarray(start, dtype=float)[free], ref.rng)
    w = whitened(record, fit_e)
    chi2_e = float(w @ w)
    references = [(ref.chi2, ref.fit)] if chi2_e > ref.chi2 else []
    for chi2_m, fit_m in members:
        if 0 < chi2_m < chi2_e and n_eff(w) * math.log(chi2_e / chi2_m) > MEMBER_SHORTFALL_BIC:
            references.append((chi2_m, fit_m))
    for _, fit_ref in sorted(references, key=lambda r: r[0]):
        nested = _nested_start(fit_ref, model_e)
        if nested is not None:
            target, theta = nested
            free_n = WhitenedResiduals(record, target, noise).free
            fit_n = finish(record, target, noise, theta[free_n], ref.rng)
            w_n = whitened(record, fit_n)
            if float(w_n @ w_n) < chi2_e:
                fit_e, w, chi2_e = fit_n, w_n, float(w_n @ w_n)
            break
    return fit_e, w, chi2_e


def _delta_bic(ref: Reference, fit_e: FitResult, chi2_e: float, n: float) -> tuple[float, list]:
    r"""``(delta BIC, uncharged terms)`` of a refitted candidate against the baseline, in its best
    form (:func:`identify.fitting.terms.best_form`: each optional term of the added effects
    switched off exactly and the rest re-optimised to first order):

    :math:`\Delta\mathrm{BIC} = n_\mathrm{eff} \ln(\chi^2_0 / (\chi^2_1 + W)) - (k - k_S) \ln n_\mathrm{eff}`,
    :math:`k` the parameters the candidate frees, :math:`k_S` those of its unused terms and
    :math:`W` the rise of pinning them off. A general form nests simpler ones, and a record of
    the simpler physics must not make its effect pay for terms it does not use."""
    k = int(fit_e.vary.sum() - ref.fit.vary.sum())
    if not chi2_e > 0:
        return math.inf, []
    new = [e.name for e in fit_e.model.effects if e.name not in ref.fit.model.effect_names]
    form = best_form(ref.record, fit_e, new, n) if new else {"terms": [], "parameters": 0, "delta_chi2": 0.0}
    gain = n * math.log(ref.chi2 / (chi2_e + form["delta_chi2"]))
    return float(gain - (k - form["parameters"]) * math.log(n)), [f"{e}.{t}" for e, t in form["terms"]]


def evaluate(ref: Reference, name: str, model_e: Model, start, screening=None, members=()) -> CandidateResult:
    """Candidate ``name`` (``model_e`` = the baseline's model plus its effects, in some threshold
    sign) finished on the whole record from the full vector ``start`` and measured against the
    baseline (module docstring)."""
    fit_e, w, chi2_e = _finish_no_worse_than_nested(ref, model_e, start, members)
    n = n_eff(w)
    delta_bic, uncharged = _delta_bic(ref, fit_e, chi2_e, n)
    profile_e = profile_of(ref.record, fit_e, ref.quiet, ref.noise_ref)
    adequacy_e = assess_adequacy(profile_e, ref.thresholds, excess_kind=ref.adequacy.excess_kind)
    new_names = [p for p in model_e.names if p not in ref.fit.model.names]
    columns = {p: fit_e.model.names.index(p) for p in new_names}
    return CandidateResult(
        name,
        screening,
        True,
        fit_e.rms,
        fit_e.max_error_pct,
        float(delta_bic),
        float(n),
        explained_fraction(ref.adequacy.excess, adequacy_e.excess),
        adequacy_e.adequate,
        adequacy_e.z,
        {p: float(fit_e.theta[i]) for p, i in columns.items()},
        {p: float(fit_e.stderr[i]) for p, i in columns.items()},
        fit_e,
        profile_e,
        uncharged_terms=uncharged,
        chi2=chi2_e,
        first_loading_share=first_loading_share(ref.record, fit_e, name.split("+")),
        whitened=w,
    )


def failed_candidate(name: str, screening, fit: FitResult, n: float, stage: str, exc: Exception) -> CandidateResult:
    """A ranking entry for a candidate whose refit could not start or failed: no gain (delta BIC
    = -k ln n_eff, the cost of its parameters), the reason in ``note``."""
    k = sum(get_effect(e).n_varying() for e in name.split("+"))
    return CandidateResult(
        name,
        screening,
        False,
        float(fit.rms),
        None,
        float(-k * math.log(n)),
        float(n),
        0.0,
        None,
        note=f"{stage} failed: {exc}",
    )


def unrefitted_candidate(name, screening, fit: FitResult, values: dict, gain: float, explained: float, n: float):
    """A ranking entry for a candidate only short-refitted or screened on the working copy: its
    delta BIC ``gain`` there (a lower bound) and the RMS it reached, scaled from the baseline's."""
    return CandidateResult(
        name, screening, False, float(fit.rms), None, float(gain), float(n), explained, None, parameters=dict(values)
    )


def first_loading_share(record, fit: FitResult, effect_names) -> float | None:
    """Share (in squares) of the part of ``fit`` that ``effect_names`` make which lies in the
    record's first loading: from the start to the drive's first reversal after it has moved.

    The part of the fit is the model at the fit minus the same with those effects off
    (:attr:`model.Effect.off`). ``None`` when the part is zero or the drive never reverses.
    An effect that acts on the first loading alone leaves nothing later on to tell it from
    other physics that acts there alone: the record has one first loading.
    """
    current = np.asarray(record.current, dtype=float)
    moved = np.flatnonzero(np.abs(current - current[0]) > 0.0)
    reversals = np.asarray(find_reversals(current).index)
    if moved.size == 0:
        return None
    later = reversals[reversals > moved[0]]
    if later.size == 0:
        return None
    theta_off = np.array(fit.theta, dtype=float)
    for name in effect_names:
        for parameter, value in get_effect(name).off.items():
            theta_off[fit.model.names.index(parameter)] = value
    y, valid = fit.model.evaluate(np.vstack([fit.theta, theta_off]), record.time, current)
    if not valid.all():
        return None
    part = y[0] - y[1]
    total = float(part @ part)
    if not total > 0.0:
        return None
    first = part[: int(later[0]) + 1]
    return float(first @ first) / total
