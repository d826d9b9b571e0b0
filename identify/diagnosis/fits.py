"""The fitting steps the diagnosis is built of: the working copy, vectors between nested
models, short refits and finishes.

Every candidate the diagnosis compares is fitted in two stages. A *short refit* runs a few
solver steps from the most promising starts of several groups on the *working copy*, the
record decimated to about :data:`SCREENING_SAMPLES` samples with every input reversal kept, so
that its cost does not grow with the sampling rate; a *finish* polishes the best point on the
whole record, where every figure of the verdict is computed. The models of the diagnosis pin
the threshold sign (the scaling degeneracy of the GPI: :mod:`identify.fitting.parametrisation`),
so a vector moves between two models only when they pin the same sign
(:func:`same_threshold_sign`; :func:`embed` refuses otherwise).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import replace as _replace

import numpy as np

from model import Model, get_effect

from ..data.records import Record, thinning_indices
from ..fitting.lsq import FitResult, WhitenedResiduals, bounded_solve, fit_least_squares
from ..fitting.noise import NoiseModel
from ..fitting.parametrisation import with_threshold_sign
from ..fitting.threads import side_by_side, single_threaded_blas
from .residuals import ARNoise, ResidualProfile, autocorrelation, residual_profile

__all__ = [
    "SCREENING_SAMPLES",
    "REVERSAL_WINDOW",
    "Working",
    "working_copy",
    "threshold_sign_variants",
    "same_threshold_sign",
    "plain_of",
    "embed",
    "with_values",
    "effect_values",
    "whitened",
    "whitened_at",
    "Point",
    "n_eff",
    "profile_of",
    "short_refit",
    "finish",
    "whole_record_chi2",
    "attempt",
    "CANDIDATE_ERRORS",
]

#: Samples the screening and the short refits work on: longer records are decimated to
#: about this many (the GPI is rate independent and the effects are integrated with the
#: actual time steps, so a decimated record keeps every signature that matters for
#: ranking; every reversal sample is kept). Final fits and tests use the whole record.
SCREENING_SAMPLES = 4000


@dataclass(frozen=True)
class Working:
    """The record (possibly decimated) and noise model the screening and short refits use."""

    record: object
    noise: NoiseModel
    step: int


#: Time [s] on each side of every input reversal that the working copy keeps at the full
#: rate. The GPI is rate independent, so keeping the reversals makes a decimated record
#: exact for it; a drive that lags the current (``lag``: a time constant, a dead time)
#: reverses later, between the kept samples, where its flat peak is computed from fewer
#: samples than on the whole record, and the direction-dependent term (eq. 13) switches at
#: another sample: an error of the jump between its branches (about 3 um with Table 1).
#: Measured with the true model on the paper's input (12 reversals, every 2nd sample at
#: 100 Hz, every 18th at 1 kHz): a lag of 12.7 ms put 177 (100 Hz) and 207 (1 kHz) into the
#: chi-square of the working copy; with 50 ms kept on each side of every reversal, 0 and
#: 0, and a lag of 5 ms plus a dead time of 20 ms 0 (72 and 185 without). A drive delayed by
#: more than the window still switches within a decimated step. Lags of tens of
#: milliseconds are the eddy-current and amplifier time constants of such rigs. At most
#: half of :data:`SCREENING_SAMPLES` are spent on the windows (narrower when the input
#: reverses often).
REVERSAL_WINDOW = 0.05


def working_copy(record, noise: NoiseModel, reversal_index) -> Working:
    """``record`` decimated to about :data:`SCREENING_SAMPLES` samples, reversals kept with
    :data:`REVERSAL_WINDOW` on each side at the full rate; the noise model whitens each
    step of the copy with its own correlation (``rho ** (step / dt)``: ``rho ** every`` on
    the decimated stretches, ``rho`` in the windows kept at the full rate; see
    :meth:`identify.fitting.noise.NoiseModel.step_correlations`)."""
    n = len(record)
    step = max(1, int(math.ceil(n / SCREENING_SAMPLES)))
    if step == 1:
        return Working(record, noise, 1)
    around = int(round(REVERSAL_WINDOW / float(np.median(np.diff(record.time)))))
    around = min(around, SCREENING_SAMPLES // (4 * max(1, len(reversal_index))))
    keep = thinning_indices(record.current, step, reversal_index, around=around)
    small = Record(
        record.time[keep],
        record.current[keep],
        record.displacement[keep],
        source=f"{record.source} (every {step}th sample, for screening)",
        sha256="",
        input_unit=record.input_unit,
        output_unit=record.output_unit,
    )
    quiet = None
    if noise.quiet is not None:
        quiet = slice(0, int(np.searchsorted(keep, noise.quiet.indices(n)[1])))
    dt = noise.dt
    if dt is None and noise.kind == "ar1":  # a noise model from before its step was kept: the record's
        dt = float(np.median(np.diff(record.time)))
    small_noise = _replace(noise, quiet=quiet, n_quiet=0 if quiet is None else quiet.stop, dt=dt)
    return Working(small, small_noise, step)


def threshold_sign_variants(model: Model):
    """``[(model, sign option)]`` to fit: both signs of a pinned alpha (swapped reading), else the model as is."""
    alpha = model.parameters["alpha"]
    if alpha.vary or model.reading != "swapped":
        return [(model, None)]
    return [(with_threshold_sign(model, -1), "negative"), (with_threshold_sign(model, 1), "positive")]


def same_threshold_sign(model_a: Model, model_b: Model) -> bool:
    """Do the two models pin (or free) ``alpha`` alike, with the same sign?"""
    a, b = model_a.parameters["alpha"], model_b.parameters["alpha"]
    return a.vary == b.vary and (a.vary or np.sign(a.value) == np.sign(b.value))


def plain_of(model_e: Model, base: Model) -> Model:
    """``base`` (effects and all) with ``model_e``'s threshold sign (``base`` when alpha is free)."""
    alpha = model_e.parameters["alpha"]
    return base if alpha.vary else with_threshold_sign(base, 1 if alpha.value > 0 else -1)


def embed(model_from: Model, theta_from, model_to: Model, drop_extra=False) -> np.ndarray:
    """``theta_from`` copied by name into ``model_to``'s vector (new effects off; with
    ``drop_extra`` parameters ``model_to`` lacks are dropped, else they are an error).

    Both models must pin ``alpha`` with the same sign when both pin it: the pinned value is
    the model's, not the vector's, so a vector of the other threshold sign would silently
    become a different model (:func:`plain_of` gives the model of that sign); that is a
    ``ValueError`` ("not nested")."""
    a, b = model_from.parameters["alpha"], model_to.parameters["alpha"]
    if not (a.vary or b.vary) and not same_threshold_sign(model_from, model_to):
        raise ValueError(
            f"not nested: {model_from!r} pins alpha = {a.value:.4g}, {model_to!r} pins alpha = {b.value:.4g} "
            "(the other threshold sign)"
        )
    theta = model_to.default_theta()
    for name, value in zip(model_from.names, theta_from):
        if name in model_to.names:
            theta[model_to.names.index(name)] = value
        elif not drop_extra:
            raise ValueError(f"parameter {name!r} of {model_from!r} is not in {model_to!r}")
    return theta


def with_values(model_e: Model, theta, values: dict) -> np.ndarray:
    """A copy of the full vector ``theta`` of ``model_e`` with ``{parameter: value}`` set."""
    theta = np.array(theta, dtype=float)
    for name, value in values.items():
        theta[model_e.names.index(name)] = value
    return theta


def effect_values(model_e: Model, theta, name: str) -> dict:
    """``{parameter: value}`` of effect ``name``'s own parameters in ``theta``, a full vector of ``model_e``."""
    return {n: float(theta[model_e.names.index(n)]) for n in get_effect(name).parameters.names}


@dataclass(frozen=True)
class Point:
    """A point to start refits from: a model (its threshold sign) and a full vector of it."""

    model: Model
    theta: np.ndarray


def whitened_at(record, model: Model, noise: NoiseModel, theta) -> np.ndarray:
    """The whitened residual of ``model`` at full vector ``theta`` on ``record``, shape (T,)."""
    residuals = WhitenedResiduals(record, model, noise)
    return residuals(np.asarray(theta, dtype=float)[residuals.free])


def whitened(record, fit: FitResult) -> np.ndarray:
    residuals = WhitenedResiduals(record, fit.model, fit.noise)
    return residuals(fit.theta[residuals.free])


def n_eff(whitened) -> float:
    rho = float(autocorrelation(whitened, 1)[1])
    rho = min(max(rho, 0.0), 0.99)
    return whitened.size * (1.0 - rho) / (1.0 + rho)


def profile_of(record, fit: FitResult, quiet: slice, noise_ref: ARNoise) -> ResidualProfile:
    return residual_profile(
        record.time,
        record.current,
        fit.residual,
        quiet,
        output_range=float(np.ptp(record.displacement)),
        noise=noise_ref,
        n_fitted=int(fit.vary.sum()),
        level=record.displacement - fit.residual,
    )


#: Refit starts kept (lowest chi-square) for the short first run.
REFIT_STARTS = 3


#: Solver evaluations each kept refit start gets before the best one is polished.
REFIT_SCREEN_EVALUATIONS = 20


#: Cap on the solver evaluations of the polish (see :func:`polish`).
POLISH_EVALUATIONS = 200


def solve(residuals, x0, method, max_nfev, tolerance=1e-10):
    """:func:`identify.fitting.lsq.bounded_solve` with tighter tolerances and single-threaded BLAS
    (the diagnosis is the same whatever the thread count)."""
    with single_threaded_blas():
        return bounded_solve(residuals, x0, max_nfev, method=method, tolerance=tolerance)


def polish(residuals: WhitenedResiduals, x0) -> np.ndarray:
    """Trust-region-reflective least squares from free vector ``x0`` (at most
    :data:`POLISH_EVALUATIONS` evaluations, single-threaded BLAS so the diagnosis is the same
    whatever the thread count); the end point, or ``x0`` when that is no worse."""
    x0 = np.asarray(x0, dtype=float)
    sol = solve(residuals, x0, "trf", POLISH_EVALUATIONS)
    w, valid = residuals.batch(np.vstack([sol.x, x0]))
    chi2 = np.where(valid, np.sum(w**2, axis=1), np.inf)
    return sol.x if chi2[0] <= chi2[1] else x0


def finish(record, model_e: Model, noise: NoiseModel, x, rng, fit: FitResult | None = None) -> FitResult:
    """Polish free vector ``x`` (:func:`polish`) and return the :class:`FitResult` there
    (``fit`` itself when that is no worse)."""
    residuals = WhitenedResiduals(record, model_e, noise)
    x = polish(residuals, x)
    if fit is not None:
        w = residuals(x)
        if float(w @ w) > fit.chi2 - 0.1:
            return fit
    return fit_least_squares(record, model_e, noise=noise, start=residuals.full(x), n_starts=1, rng=rng)


def short_refit(record, model_e: Model, noise: NoiseModel, start_groups) -> tuple[float, np.ndarray]:
    """Short solver runs from the most promising starts of each group.

    Parameters
    ----------
    start_groups : sequence of sequences of ndarray
        Full vectors of ``model_e``, in groups (e.g. starts near the baseline optimum,
        starts from the data-driven GPI); from each group the :data:`REFIT_STARTS`
        distinct starts of lowest chi-square get :data:`REFIT_SCREEN_EVALUATIONS`
        solver evaluations (grouping keeps a distant basin in play even when its
        starts look worse than the baseline's compromise at first).

    Returns
    -------
    chi2 : float
        Whitened chi-square at the best point reached.
    theta : ndarray, shape (P_e,)
        That point (full vector).

    Raises
    ------
    ValueError
        No start gives a finite model output.
    """
    residuals = inner = WhitenedResiduals(record, model_e, noise)
    best_chi2, best_x = np.inf, None
    for group in start_groups:
        if not len(group):
            continue
        xs = np.unique(
            np.array([np.clip(np.asarray(s, dtype=float)[inner.free], inner.lower, inner.upper) for s in group]), axis=0
        )
        w, valid = inner.batch(xs)
        chi2 = np.where(valid, np.sum(w**2, axis=1), np.inf)
        for i in [int(i) for i in np.argsort(chi2, kind="stable")[:REFIT_STARTS] if np.isfinite(chi2[i])]:
            if chi2[i] < best_chi2:
                best_chi2, best_x = float(chi2[i]), xs[i]
            sol = solve(residuals, xs[i], "trf", REFIT_SCREEN_EVALUATIONS)
            x = sol.x
            wx, ok = inner.batch(x[None, :])
            if ok[0] and float(wx[0] @ wx[0]) < best_chi2:
                best_chi2, best_x = float(wx[0] @ wx[0]), x
    if best_x is None:
        raise ValueError(f"no refit start of {model_e!r} gives a finite model output")
    return best_chi2, inner.full(best_x)


#: What a candidate's refit may raise without stopping the diagnosis (the candidate is then
#: listed with the reason; see :func:`failed_candidate`).
CANDIDATE_ERRORS = (ValueError, ArithmeticError)


def concurrently(actions: list[Callable[[], object]]) -> list[tuple[object, Exception | None]]:
    """``[(result, None) or (None, exception)]`` of independent fits ``actions`` in order, run side
    by side (:func:`identify.fitting.threads.side_by_side`: each computes what it would alone);
    an exception of :data:`CANDIDATE_ERRORS` is returned in its action's place, any other raised."""
    return side_by_side(actions, catch=CANDIDATE_ERRORS)


def attempt_each(actions, say: Callable[[str], None], whats, on_failures=None) -> list:
    """:func:`attempt` of every action of ``actions``, run side by side (:func:`concurrently`);
    the results in order, each failure said as ``"  {what}: {exc}"`` and handed to its
    ``on_failures`` entry (when given and not None) in order."""
    results = []
    for k, (result, exc) in enumerate(concurrently(list(actions))):
        if exc is not None:
            say(f"  {whats[k]}: {exc}")
            if on_failures is not None and on_failures[k] is not None:
                on_failures[k](exc)
        results.append(result)
    return results


def attempt(action: Callable[[], object], say: Callable[[str], None], what: str, on_failure=None):
    """``action()``, or ``None`` when it raises one of :data:`CANDIDATE_ERRORS`.

    One candidate's failing screening or refit never stops the diagnosis: the failure is said
    as ``"  {what}: {exc}"`` and handed to ``on_failure(exc)`` when given (the search lists the
    candidate with the reason).
    """
    try:
        return action()
    except CANDIDATE_ERRORS as exc:
        say(f"  {what}: {exc}")
        if on_failure is not None:
            on_failure(exc)
        return None


def whole_record_chi2(record, model_e: Model, noise: NoiseModel, theta) -> float:
    """Whitened chi-square of ``model_e`` at full vector ``theta`` on ``record`` (one evaluation)."""
    w = whitened_at(record, model_e, noise, theta)
    return float(w @ w)
