"""The baseline: the model as given, fitted in each threshold sign, its noise reference, and
the challenges it must survive before a candidate is credited with anything.

The baseline is the model the user asked about (the normalised GPI plus the effects given),
fitted by least squares in each threshold sign the normalisation allows and polished on the
whole record (:func:`fit_baselines`); the sign of lower chi-square is the baseline
(:func:`best_baseline`). When the two signs fit the record alike (:func:`tied_sign`), the data
do not choose the sign, and the search fits every candidate in both. A candidate must not be
credited with the baseline's unfinished optimisation: the baseline is refitted from every
candidate's GPI (:func:`challenge_baseline`) and through the exact reparametrisations
(:func:`reparametrisation_paths`), and a better baseline starts the search again.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from model import EFFECTS, Model, get_effect

from ..data.reversals import find_reversals
from ..fitting.lsq import FitResult, WhitenedResiduals, fit_least_squares
from ..fitting.lsq_solver import beyond_a_tie
from ..fitting.noise import NoiseModel, estimate_noise
from ..fitting.parametrisation import normalised_model
from ..fitting.threads import results_side_by_side
from .evidence import likelihood_gap
from .fits import (
    attempt,
    embed,
    finish,
    n_eff,
    plain_of,
    same_threshold_sign,
    short_refit,
    threshold_sign_variants,
    whitened,
    whitened_at,
    working_copy,
)
from .reparametrisation import GPI_EQUIVALENTS, through_reparametrisation
from .residuals import ARNoise, fit_ar_noise
from .screening import screening_grid
from .starts import data_driven, near

__all__ = [
    "fit_baseline",
    "fit_baselines",
    "best_baseline",
    "model_and_candidates",
    "known_noise",
    "noise_reference",
    "tied_sign",
    "reparametrisation_paths",
    "challenge_baseline",
]


def fit_baselines(
    record,
    model: Model,
    noise: NoiseModel,
    *,
    n_starts: int = 6,
    rng: np.random.Generator | None = None,
    progress: Callable[[str], None] | None = None,
    tie_bic: float | None = None,
) -> list:
    """The model fitted in each threshold sign (one fit when alpha is free or the reading
    literal), each polished on the whole record: ``[FitResult]``. Records longer than the
    working copy are fitted on it and polished on the whole record.

    ``tie_bic`` (the margin of :func:`tied_sign`, default None: no such rule): the sign of the
    higher chi-square serves only where it ends lower than the other or ties with it, so the
    finish of a sign whose start is not the lower on the whole record stops once it can do
    neither (:func:`identify.fitting.lsq_solver.beyond_a_tie` of the lower start)."""
    say = progress or (lambda message: None)
    rng = np.random.default_rng(0) if rng is None else rng
    work = working_copy(record, noise, find_reversals(record.current).index)
    finishes = []  # the fits in order (they draw from the one generator), their finishes side by side
    starts = []  # the point each finish starts from
    for sign_model, sign in threshold_sign_variants(model):
        say(f"least squares of {sign_model!r} ({n_starts} starts{'' if sign is None else ', alpha ' + sign})")
        options = {} if sign is None else {"threshold_sign": sign}
        if work.step == 1:
            one = fit_least_squares(record, sign_model, noise=noise, n_starts=n_starts, rng=rng, **options)
            finishes.append(partial(finish, record, one.model, noise, one.theta[one.vary], rng, fit=one))
            starts.append((one.model, one.theta))
        else:
            small = fit_least_squares(work.record, sign_model, noise=work.noise, n_starts=n_starts, rng=rng, **options)
            say(f"polishing on the whole record ({len(record)} samples)")
            finishes.append(partial(finish, record, small.model, noise, small.theta[small.vary], rng))
            starts.append((small.model, small.theta))
    if tie_bic is not None and len(finishes) > 1:
        finishes = _unless_beyond_a_tie(record, noise, starts, finishes, tie_bic)
    return results_side_by_side(finishes)


def _unless_beyond_a_tie(record, noise: NoiseModel, starts, finishes, bic: float) -> list:
    """``finishes``, each of one whose start is not the lowest on the whole record run within
    :func:`~identify.fitting.lsq_solver.beyond_a_tie` of the lowest start (``bic``; the effective
    sample size of its own start's residuals)."""
    residuals = [whitened_at(record, model_s, noise, theta) for model_s, theta in starts]
    chi2 = [float(w @ w) for w in residuals]
    lowest = min(chi2)
    return [
        action if c <= lowest else partial(_within_a_tie, lowest, bic, n_eff(w), action)
        for action, c, w in zip(finishes, chi2, residuals)
    ]


def _within_a_tie(reference: float, bic: float, n_eff_start: float, action: Callable):
    with beyond_a_tie(reference, bic, n_eff_start):
        return action()


def best_baseline(record, baselines) -> FitResult:
    """The baseline of lowest whitened chi-square on the whole record."""
    return min(baselines, key=lambda f: float(np.sum(whitened(record, f) ** 2)))


def fit_baseline(
    record,
    model: Model,
    noise: NoiseModel,
    *,
    n_starts: int = 6,
    rng: np.random.Generator | None = None,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """The diagnosis' baseline fit: least squares in each threshold sign, polished on the whole
    record, the better sign kept.

    Parameters
    ----------
    record : Record
        ``time`` [s], ``current`` [A], ``displacement`` [um], shape (T,).
    model : Model
        The model to fit (e.g. :func:`identify.fitting.parametrisation.normalised_model`).
    noise : NoiseModel
        Its noise model (a known sigma).
    n_starts : int, default 6
        Starts of the least squares per sign.
    rng : numpy.random.Generator, optional
        Default ``numpy.random.default_rng(0)``.
    progress : callable(str), optional

    Returns
    -------
    FitResult
    """
    return best_baseline(record, fit_baselines(record, model, noise, n_starts=n_starts, rng=rng, progress=progress))


def model_and_candidates(model, fit: FitResult | None, candidates) -> tuple[Model, list]:
    """The model to diagnose (effect names: the normalised GPI with them) and the candidate
    effects (default every library effect not in it), checked against each other and ``fit``."""
    if model is None or not isinstance(model, Model):
        model = normalised_model(Model([] if model is None else list(model)))
    if fit is not None and fit.model.names != model.names:
        raise ValueError(f"the given fit is of {fit.model!r}, not of {model!r}")
    if candidates is None:
        return model, [name for name in EFFECTS if name not in model.effect_names]
    candidates = list(candidates)
    for name in candidates:
        get_effect(name)
        if name in model.effect_names:
            raise ValueError(f"candidate {name!r} is already in the model {model!r}")
    return model, candidates


def known_noise(record, noise: NoiseModel | None, fit: FitResult | None) -> NoiseModel:
    """The noise model (the fit's, the given one, or estimated from the record); a free sigma is refused."""
    noise = fit.noise if fit is not None else (estimate_noise(record) if noise is None else noise)
    if noise.is_free:
        raise ValueError(
            f"{record.source}: the diagnosis compares the residual with a known noise level; a free noise sigma "
            "gives none (use the quiet segment, or a user-given --noise-sigma VALUE)"
        )
    return noise


def noise_reference(record, fit: FitResult, noise: NoiseModel, quiet: slice) -> tuple[slice | None, ARNoise]:
    """``(quiet, noise reference)``: an AR fit of the baseline's residual on the quiet start
    (>= 20 samples), else white noise of a user-given sigma (``quiet`` None)."""
    q_stop = quiet.indices(len(record))[1]
    if q_stop >= 20:
        return quiet, fit_ar_noise(fit.residual[:q_stop])
    if noise.source == "user":  # no quiet segment: white noise of the user's sigma, taken as exactly known
        return None, ARNoise(np.zeros(0), float(noise.sigma), float(noise.sigma), 10**9)
    raise ValueError(
        f"{record.source}: the diagnosis needs an unenergised start (>= 20 samples) as its noise reference, "
        f"or a user-given noise sigma; this record's quiet start has {q_stop} samples"
    )


def tied_sign(record, fit: FitResult, baselines, chi2_0: float, bic_significant: float) -> FitResult | None:
    """The baseline of the other threshold sign when it fits the record as well as ``fit``:
    within ``bic_significant`` in BIC (the same free parameters, so ``n_eff ln(chi2_other /
    chi2_0)``); else None. On a drive that starts with its largest excursion one sign's plain
    GPI is nearly a re-parametrisation of the other's (thresholds of the other sign, the
    envelopes' offsets shifted, the weights rescaled), and an effect on the operators breaks
    the tie: then every candidate is fitted in both signs."""
    for other in baselines:
        if other.model.names != fit.model.names or same_threshold_sign(other.model, fit.model):
            continue
        w = whitened(record, other)
        chi2 = float(w @ w)
        if likelihood_gap(chi2_0, chi2, n_eff(w)) <= bic_significant:
            return other
    return None


def reparametrisation_paths(work, fit: FitResult, names, say) -> list:
    """Baseline starts found through the exact reparametrisations (:data:`GPI_EQUIVALENTS`):
    an exact reparametrisation explains nothing, but its extra direction is a path for the
    baseline's optimiser (a virgin start: the plain GPI must move four offsets together;
    through the initial level it moves one). A short refit through the effect's
    reparametrising parameters alone, mapped back to the model."""
    starts = []
    for name in [n for n in GPI_EQUIVALENTS if n in names]:
        say(f"short refit through '{name}' (an exact reparametrisation: a path for the baseline)")
        model_e = through_reparametrisation(fit.model, name)
        grid = screening_grid(model_e, name, embed(fit.model, fit.theta, model_e), work.record)
        groups = [near(fit, model_e, grid), data_driven(work, model_e, grid)]
        result = attempt(lambda: short_refit(work.record, model_e, work.noise, groups), say, "not possible")
        if result is None:
            continue
        mapped = GPI_EQUIVALENTS[name](model_e, result[1], work.record.time, work.record.current)
        if model_e.in_bounds(mapped)[0]:
            starts.append(embed(model_e, mapped, fit.model, drop_extra=True))
    return starts


def challenge_baseline(record, work, fit: FitResult, chi2_0: float, chi2_0_small: float, fits, extra, rng, say):
    """A better baseline than ``fit``, or None.

    The model without the candidates, started from each candidate's GPI (``fits``: the
    candidates' fits; one of the other threshold sign challenges the plain model of that sign)
    and from ``extra`` (full vectors of ``fit.model``): a refit that won only because it found a
    better GPI basin must not be credited to its effect. The best challenger must beat the
    baseline by more than ``max(1, 1e-4 chi2)`` on the working copy, then on the whole record.
    """
    say("challenging the baseline from the candidates' GPI parameters")
    same = [
        embed(f.model, f.theta, fit.model, drop_extra=True) for f in fits if same_threshold_sign(f.model, fit.model)
    ]
    groups = [(fit.model, same + list(extra))]
    for f in fits:
        if not same_threshold_sign(f.model, fit.model):
            plain = plain_of(f.model, fit.model)
            groups.append((plain, [embed(f.model, f.theta, plain, drop_extra=True)]))
    challenges = []
    for plain, starts in groups:
        if starts:
            result = attempt(lambda: short_refit(work.record, plain, work.noise, [starts]), say, "no challenger")
            if result is not None:
                challenges.append((result, plain))
    if not challenges:
        return None
    (chi2_small, theta), model = min(challenges, key=lambda c: c[0][0])
    if chi2_small >= chi2_0_small - max(1.0, 1e-4 * chi2_0_small):
        return None
    residuals = WhitenedResiduals(record, model, fit.noise)
    challenger = finish(record, model, fit.noise, theta[residuals.free], rng)
    if challenger.chi2 >= chi2_0 - max(1.0, 1e-4 * chi2_0):
        return None
    return challenger
