r"""Weighted nonlinear least squares of the GPI (+ effects) on one record, with multi-start.

Objective
---------
The residuals ``e = displacement - model(theta)`` over the whole record (the quiet start
included: the model predicts the rest level there) are whitened by the noise model
(:func:`identify.fitting.noise.whiten`: divided by sigma, AR(1) filtered when the noise is
correlated), and :func:`scipy.optimize.least_squares` (dogleg with box bounds,
:data:`SOLVER_METHOD`) minimises half their sum of squares within each parameter's bounds. Pinned parameters
(``Parameter.vary = False``, e.g. the normalisation of :mod:`identify.fitting.identifiability`)
stay at their values. The GPI is defined for every parameter set (:mod:`model.gpi`, "The
whole domain"); a parameter set for which an effect gives a non-finite output gets a
constant residual of :data:`DOMAIN_PENALTY` per sample, far above any fit, so the solver
backs off.

Jacobian
--------
Forward differences, computed in ONE batched model call: ``theta`` and its ``P``
perturbed copies are evaluated as a ``(P + 1, P_full)`` batch (the forward model is
vectorised over parameter sets). Step ``h_j = sqrt(eps) * max(|theta_j|, 0.01)``,
taken downwards when it would leave the bounds. The covariance at the
optimum uses central differences (one ``(2P + 1)``-row batch, step
:data:`CENTRAL_STEP_POWER`) for accuracy.

Starts
------
``start`` (if given), then

``table1``
    Table 1 of the paper with every effect off, when the record is in A and um;
``data_scaled``
    Table 1 rescaled to the record: the slopes ``a1, b1, c1, d1`` divided by the input
    scale ``max|input| / 5`` (the paper's drive peaks at 5 A), then the output gain and
    offset fitted by linear least squares of the data on the rescaled prediction (gain
    on ``rho, c0, c3, d0, d3``, offset on ``c3, d3``); this is exact for a record that
    is a scaled copy of the paper's transducer;
``classical``
    for a model whose ``alpha`` is positive (classical-PI-like thresholds, see below):
    identical, mildly saturating envelopes ``3 tanh(0.5 v / max|v|)`` for both branches,
    ``rho = 1``, ``tau = 0.5``, a gently sloped Omega, then the output gain and offset
    fitted by linear least squares as for ``data_scaled``;
``perturbed-k``
    the best of the above with each free GPI parameter multiplied by
    ``exp(0.15 z)``, ``z ~ N(0, 1)`` from ``rng``; effect parameters measured in seconds
    (time constants) spread log-uniformly over their bounds, other effect parameters
    at their off value plus 1 % of their range times ``z``.

Every start first gets :data:`SCREEN_EVALUATIONS` solver evaluations of each method
(:data:`SOLVER_METHOD` and :data:`ALTERNATE_METHOD`); the ``n_polish`` best after dogbox's
screening, and the :data:`N_POLISH_ALTERNATE` best after trf's, then run on
from there to convergence with :data:`SOLVER_METHOD` (at most :data:`POLISH_EVALUATIONS`
evaluations, tolerances :data:`TOLERANCE`, and every run stopped once it has stalled:
:class:`StallStop`) and the best of those wins. The polished set
contains dogbox's alone, so the search only adds ends to what dogbox's ranking polishes.
Only the lowest end is kept, so a polish (and the later phases' runs) stops once it cannot
come near the lowest chi-square a start has reached
(:func:`identify.fitting.lsq_solver.within_reach_of_best`): its verdict then says so, and the
fit's optimum is the one the full runs reach.

Table-1-shaped starts (``table1``, ``data_scaled``, ``classical``) are made for Table 1's
12 operators; for ``N`` operators they are rescaled so the operators keep the same
threshold range and total weight (``alpha`` and ``rho`` times ``12/N``, then the exact
scaling restores a pinned ``alpha``; :func:`identify.fitting.lsq_starts._rescaled_to_operators`).

Starts "agree" when their final chi-square is within 1 of the best (statistically indistinguishable
fits); a start screened out counts as not agreeing, so ``n_agree`` is a lower bound.
BLAS runs single-threaded during the fit (see :func:`identify.fitting.threads.single_threaded_blas`).

Sign of the thresholds
----------------------
The normalisation (:mod:`identify.fitting.identifiability`) pins ``|alpha|``; its sign is a
model choice the scaling cannot change. ``alpha < 0`` is the paper's Table 1 (the gap
between the envelopes makes the loop), ``alpha > 0``
the classical PI's positive thresholds (near-identical envelopes: thin loop tips, e.g.
a piezo actuator). With ``threshold_sign="auto"`` (default) and no ``start``,
:func:`fit_least_squares` fits both and keeps the lower chi-square (within
:data:`AGREE_CHI2` of each other, statistically indistinguishable, the paper's ``alpha < 0``);
its ``message`` says what the other sign reached. A given ``start`` decides the sign itself.

Covariance
----------
``sigma^2 (J^T J)^+`` on the whitened residuals (equivalently ``(J^T J)^+`` with the
residuals already divided by sigma), over the free parameters only (pinned rows and
columns are zero, their standard errors NaN). With a free sigma, sigma is estimated as
``sqrt(sum w^2 / (T - P_free))`` (residual RMS with degrees-of-freedom correction).
"""

from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import dataclass, replace
from functools import partial

import numba
import numpy as np

from model import THETA_NAMES, Model

from .coordinates import GPICoordinates
from .lsq_residuals import CENTRAL_STEP_POWER, DOMAIN_PENALTY, WhitenedResiduals, difference_columns
from .lsq_result import FitResult, StartOutcome, StoredModelError, parameter_units
from .lsq_solver import (
    ALTERNATE_METHOD,
    N_POLISH,
    N_POLISH_ALTERNATE,
    POLISH_EVALUATIONS,
    SCREEN_EVALUATIONS,
    SOLVER_METHOD,
    STALL_CHI2,
    STALL_ITERATIONS,
    STALLED,
    TOLERANCE,
    StallStop,
    bounded_solve,
    on_a_bound,
    solver_verdict,
    stalling_solve,
    within_reach_of_best,
)
from .lsq_starts import PAPER_PEAK_INPUT, TABLE1_N_OPERATORS, candidate_starts
from .noise import NoiseModel, energised_mask, estimate_noise
from .parametrisation import in_record_units, with_threshold_sign
from .threads import fastest_thread_count, results_side_by_side, single_threaded_blas

_log = logging.getLogger(__name__)  # a child of the "identify" logger (identify.logs)

#: The fit's public face; the names from :mod:`identify.fitting.lsq_result`,
#: :mod:`~identify.fitting.lsq_residuals`, :mod:`~identify.fitting.lsq_starts` and
#: :mod:`~identify.fitting.lsq_solver` are re-exported here, where they were before the split.
__all__ = [
    "FitResult",
    "StartOutcome",
    "StoredModelError",
    "fit_least_squares",
    "candidate_starts",
    "WhitenedResiduals",
    "difference_columns",
    "DOMAIN_PENALTY",
    "CENTRAL_STEP_POWER",
    "TABLE1_N_OPERATORS",
    "PAPER_PEAK_INPUT",
    "THRESHOLD_SIGNS",
    "AGREE_CHI2",
    "parameter_units",
    "StallStop",
    "solver_verdict",
    "bounded_solve",
    "SCREEN_EVALUATIONS",
    "N_POLISH",
    "N_POLISH_ALTERNATE",
    "SOLVER_METHOD",
    "ALTERNATE_METHOD",
    "POLISH_EVALUATIONS",
    "TOLERANCE",
    "STALL_ITERATIONS",
    "STALL_CHI2",
    "STALLED",
]

#: Starts whose chi-square is within this of the best count as agreeing.
AGREE_CHI2 = 1.0
#: ``threshold_sign`` option -> the signs of ``alpha`` fitted.
THRESHOLD_SIGNS = {"auto": (-1, 1), "negative": (-1,), "positive": (1,)}


def _converged(residuals: WhitenedResiduals, sol, note: str = "") -> _PolishedStart:
    """``sol`` run on to convergence with :data:`SOLVER_METHOD` when it stopped at its
    evaluation cap (status 0), as a :class:`_PolishedStart` (``note`` appended to the message)."""
    if sol.status == 0:
        sol = bounded_solve(residuals, sol.x, POLISH_EVALUATIONS)
    success, message = solver_verdict(sol)
    return _PolishedStart(np.asarray(sol.x, dtype=float), 2.0 * float(sol.cost), success, f"{message}{note}")


def _gpi_at_bound(residuals: WhitenedResiduals, x) -> list[str]:
    """Names of the free GPI parameters of free vector ``x`` that sit on a box bound."""
    bound = on_a_bound(x, residuals.lower, residuals.upper)
    n_gpi = len(THETA_NAMES)
    return [residuals.model.names[column] for j, column in enumerate(residuals.free) if column < n_gpi and bound[j]]


@dataclass(frozen=True)
class _PolishedStart:
    """End of one polished start: free vector, exact chi-square, solver verdict."""

    x: np.ndarray
    chi2: float
    success: bool
    message: str


def fit_least_squares(
    record,
    model: Model,
    *,
    noise=None,
    start=None,
    n_starts=8,
    rng=None,
    verbose=False,
    n_polish=N_POLISH,
    threshold_sign="auto",
) -> FitResult:
    """Least-squares fit of ``model`` to ``record`` (method in the module docstring).

    Parameters are those of :func:`_fit_one_sign`, plus

    threshold_sign : {"auto", "negative", "positive"}, default "auto"
        Sign of the pinned ``alpha`` (module docstring, "Sign of the thresholds"). Applies
        when ``alpha`` is pinned and the reading is "swapped"; "auto" fits both signs
        unless ``start`` is given (its ``alpha`` decides). Ignored when ``alpha`` is free.

    Returns
    -------
    FitResult
        The better fit; ``fit.model`` carries the chosen sign.
    """
    if threshold_sign not in THRESHOLD_SIGNS:
        raise ValueError(f"threshold_sign must be one of {sorted(THRESHOLD_SIGNS)}, got {threshold_sign!r}")
    options = dict(noise=noise, start=start, n_starts=n_starts, rng=rng, verbose=verbose, n_polish=n_polish)
    alpha = model.parameters["alpha"]
    if alpha.vary or model.reading != "swapped":
        return _fit_one_sign(record, model, **options)
    if start is not None:
        start_alpha = float(np.asarray(start, dtype=float)[model.names.index("alpha")])
        signs = (1 if start_alpha > 0 else -1,)
    else:
        signs = THRESHOLD_SIGNS[threshold_sign]
    fits, failures = [], []
    for sign in signs:
        try:
            fits.append(_fit_one_sign(record, with_threshold_sign(model, sign), **options))
        except ValueError as exc:
            if "no valid least-squares start" not in str(exc):
                raise
            failures.append(f"alpha {'>' if sign > 0 else '<'} 0: {exc}")
    if not fits:
        raise ValueError("; ".join(failures))

    # Compare the whitened chi-square in the caller's noise units: with a free sigma each
    # fit's reduced chi-square is 1 by construction, so rescale by its own sigma estimate.
    def mean_square(f):
        return f.reduced_chi2 * f.noise.sigma**2

    best = min(fits, key=mean_square)
    # Within AGREE_CHI2 of each other the two signs fit equally well (e.g. on the paper's own
    # transducer both signs can reach the same chi-square): keep the paper's sign then.
    dof = best.residual.size - int(best.vary.sum())
    tied = [f for f in fits if (mean_square(f) - mean_square(best)) * dof / best.noise.sigma**2 <= AGREE_CHI2]
    tie_note = ""
    if len(tied) > 1:
        best = min(tied, key=lambda f: f.model.parameters["alpha"].value)
        tie_note = f"; the signs agree within chi-square {AGREE_CHI2:g}, so the paper's (alpha < 0) is kept"
    if len(signs) > 1:
        notes = [
            f"alpha {'>' if f.model.parameters['alpha'].value > 0 else '<'} 0 reached reduced chi-square "
            f"{f.reduced_chi2:.4g}, residual RMS {f.rms:.4g}"
            for f in fits
        ] + failures
        chosen = "positive" if best.model.parameters["alpha"].value > 0 else "negative"
        best = replace(best, message=f"{best.message}; threshold sign {chosen} chosen ({'; '.join(notes)}){tie_note}")
    return best


def _fit_one_sign(
    record, model: Model, *, noise=None, start=None, n_starts=8, rng=None, verbose=False, n_polish=N_POLISH
) -> FitResult:
    """Least-squares fit of ``model`` as given (its pinned parameters, alpha's sign included).

    The steps: the checks (:func:`_checked_residuals`), the starts
    (:func:`candidate_starts`), the search from them (:func:`_run_starts`: screen, polish,
    the alternate method at a bound) and the fit's statistics (:func:`_fit_result`).

    Parameters
    ----------
    record : identify.data.records.Record
        ``time`` [s], ``current`` [input unit], ``displacement`` [output unit], shape (T,).
    model : model.Model
        The model; parameters with ``vary=False`` stay pinned.
    noise : NoiseModel, optional
        Default :func:`identify.fitting.noise.estimate_noise` ``(record)`` (raises when the
        record has no quiet start: pass a user or free noise model then).
    start : array_like, shape (P,), optional
        Extra start, tried first.
    n_starts : int, default 8
        Number of starts (see :func:`candidate_starts`).
    rng : numpy.random.Generator, optional
        For the perturbed starts; default ``numpy.random.default_rng(0)``.
    verbose : bool, default False
        One line per start logged at INFO (``identify.fitting.lsq``); at DEBUG when False (shown by ``-v``).
    n_polish : int, default :data:`N_POLISH`
        How many of the best screened starts are run to convergence.

    Returns
    -------
    FitResult
    """
    model = in_record_units(model, record)  # default bounds in the record's unit prefixes
    t0 = _time.perf_counter()
    noise, residuals = _checked_residuals(record, model, noise)
    starts = candidate_starts(record, model, n_starts=n_starts, rng=rng, start=start)
    best, outcomes = _run_starts(residuals, starts, n_polish, verbose)
    return _fit_result(record, model, residuals, noise, best, outcomes, len(starts), t0)


def _checked_residuals(record, model: Model, noise) -> tuple[NoiseModel, WhitenedResiduals]:
    """``(noise, whitened residuals)``, refusing a fit with nothing free or too few samples."""
    noise = estimate_noise(record) if noise is None else noise
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise must be a NoiseModel, got {type(noise).__name__}")
    residuals = WhitenedResiduals(record, model, noise)
    free = residuals.free
    if free.size == 0:
        raise ValueError("every parameter is pinned: nothing to fit")
    n_samples = residuals.data.size
    if n_samples <= free.size:
        raise ValueError(f"{n_samples} samples cannot determine {free.size} free parameters")
    return noise, residuals


class _StartLog:
    """The outcome of every start, in order, and the best polished end so far."""

    def __init__(self, verbose: bool):
        self.level = logging.INFO if verbose else logging.DEBUG
        self.outcomes: list[StartOutcome] = []
        self.ends: list[tuple[str, _PolishedStart]] = []
        self.best = None

    def screened_out(self, label, sol, n_eval):
        message = f"screened out after {SCREEN_EVALUATIONS} evaluations (not run to convergence)"
        self.outcomes.append(StartOutcome(label, 2.0 * float(sol.cost), n_eval, solver_verdict(sol)[0], message))

    def keep(self, label, end: _PolishedStart, n_eval):
        self.outcomes.append(StartOutcome(label, end.chi2, n_eval, end.success, end.message))
        self.ends.append((label, end))
        _log.log(self.level, f"  polish {label:<14} chi2 = {end.chi2:.6g}  ({end.message})")
        if self.best is None or end.chi2 < self.best.chi2:
            self.best = end


def _run_starts(residuals, starts, n_polish: int, verbose: bool) -> tuple[_PolishedStart, list]:
    """``(best end, outcomes)`` of the search from ``starts``, with numba's fastest thread count
    and single-threaded BLAS: phase 1 screens every start with a few steps of each solver
    method, phase 2 runs the most promising to convergence (module docstring), phase 3
    (:func:`_polish_at_bound`), phase 4 (:func:`_polish_in_coordinates`)."""
    free = residuals.free
    threads_before = numba.get_num_threads()
    x_probe = np.repeat(np.clip(starts[0][1][free], residuals.lower, residuals.upper)[None, :], free.size + 1, axis=0)
    fastest_thread_count(residuals.batch, x_probe)
    log = _StartLog(verbose)
    try:
        with single_threaded_blas():
            # Phase 1: screen every start with a few steps of each method. Phases 1 and 2 run
            # their starts side by side, each on its own copy of the residuals.
            origins = [np.clip(theta0[free], residuals.lower, residuals.upper) for _, theta0 in starts]
            runs = _side_by_side(residuals, [partial(_screen_start, x0=x0) for x0 in origins])
            screened, alternate = [], []
            for (label, _), ((sol, sol_alternate), n_eval) in zip(starts, runs):
                screened.append((label, sol, n_eval))
                alternate.append(sol_alternate)
                _log.log(
                    log.level,
                    f"  screen {label:<14} chi2 = {2 * sol.cost:.6g} ({SOLVER_METHOD}), "
                    f"{2 * sol_alternate.cost:.6g} ({ALTERNATE_METHOD})",
                )
            # Phase 2: run the most promising ends to convergence: the n_polish best after
            # dogbox's screening, and the N_POLISH_ALTERNATE best after trf's.
            order = sorted(range(len(screened)), key=lambda k: screened[k][1].cost)
            polish = set(order[:n_polish])
            order_alternate = sorted(range(len(screened)), key=lambda k: alternate[k].cost)
            polish_alternate = set(order_alternate[:N_POLISH_ALTERNATE]) if n_polish > 0 else set()
            note = f" (run on from {ALTERNATE_METHOD}'s screening)"
            tasks = [(k, False) for k in sorted(polish)] + [(k, True) for k in sorted(polish_alternate)]
            # a chi-square some start has reached: a polish that cannot come near it cannot end lowest
            reached = min(2.0 * float(sol.cost) for sol in [*alternate, *(sol for _, sol, _ in screened)])
            runs = [
                _within_reach_of(reached, partial(_converged, sol=alternate[k], note=note))
                if alt
                else _within_reach_of(reached, partial(_converged, sol=screened[k][1]))
                for k, alt in tasks
            ]
            ends = dict(zip(tasks, _side_by_side(residuals, runs)))
            for k, (label, sol, n_eval) in enumerate(screened):
                if k not in polish | polish_alternate:
                    log.screened_out(label, sol, n_eval)
                    continue
                if k in polish:
                    end, used = ends[(k, False)]
                    log.keep(label, end, n_eval + used)
                if k in polish_alternate:
                    end, used = ends[(k, True)]
                    screening = 0 if k in polish else n_eval  # the screening's evaluations, counted once
                    log.keep(f"{label} ({ALTERNATE_METHOD} screening)", end, screening + used)
            _polish_at_bound(residuals, screened, origins, polish, log)
            _polish_in_coordinates(residuals, log)
    finally:
        numba.set_num_threads(threads_before)
    return log.best, log.outcomes


def _within_reach_of(best_chi2: float, task):
    """``task(residuals)`` with its solver runs stopped once out of reach of ``best_chi2``
    (:func:`identify.fitting.lsq_solver.within_reach_of_best`, set in the thread that runs it)."""

    def run(residuals):
        with within_reach_of_best(best_chi2):
            return task(residuals)

    return run


def _screen_start(residuals: WhitenedResiduals, x0):
    """Phase 1 for one start: a few steps of each solver method from ``x0``."""
    sol = bounded_solve(residuals, x0, SCREEN_EVALUATIONS)
    return sol, bounded_solve(residuals, x0, SCREEN_EVALUATIONS, method=ALTERNATE_METHOD)


def _side_by_side(residuals: WhitenedResiduals, tasks) -> list:
    """``[(result, evaluations)]`` of ``tasks`` (each called with its own copy of ``residuals``),
    run side by side (:func:`identify.fitting.threads.results_side_by_side`: each computes what it
    would alone); their evaluations are added to ``residuals``'s count."""
    copies = [residuals.copy() for _ in tasks]
    results = results_side_by_side([partial(task, twin) for task, twin in zip(tasks, copies)])
    residuals.n_evaluations += sum(twin.n_evaluations for twin in copies)
    return [(result, twin.n_evaluations) for result, twin in zip(results, copies)]


def _polish_at_bound(residuals, screened, origins, polish, log: _StartLog) -> None:
    """Phase 3: an optimum with a GPI parameter on its box bound is a degenerate limit (e.g.
    an Omega branch whose tanh is stretched into a line: c0 at -1000, c1 -> 0), into which
    dogbox's large steps can fall; the same starts are then polished from their origin with
    the interior, reflective method (trf) too, finished by dogbox (side by side, each on its
    own copy of the residuals)."""
    gpi_at_bound = _gpi_at_bound(residuals, log.best.x)
    if not gpi_at_bound:
        return
    note = f" ({ALTERNATE_METHOD} from the start: the {SOLVER_METHOD} optimum had {', '.join(gpi_at_bound)} on a bound)"
    ks = sorted(polish)
    tasks = [_within_reach_of(log.best.chi2, partial(_interior_end, x0=origins[k], note=note)) for k in ks]
    for k, (end, used) in zip(ks, _side_by_side(residuals, tasks)):
        log.keep(f"{screened[k][0]} ({ALTERNATE_METHOD})", end, used)


def _interior_end(residuals: WhitenedResiduals, x0, note: str) -> _PolishedStart:
    """A start run to convergence with :data:`ALTERNATE_METHOD`, finished by :func:`_converged`."""
    return _converged(residuals, bounded_solve(residuals, x0, POLISH_EVALUATIONS, method=ALTERNATE_METHOD), note)


class _ResidualsInCoordinates:
    """The whitened residuals as a function of the sampler coordinates ``u``
    (:mod:`identify.fitting.coordinates`), for an unbounded solver: a ``u`` whose parameters
    leave their box (or the map's range) gets :data:`DOMAIN_PENALTY`, so the step is refused."""

    def __init__(self, residuals: WhitenedResiduals, coordinates):
        self.residuals = residuals
        self.coordinates = coordinates

    def parameters(self, u_rows) -> tuple[np.ndarray, np.ndarray]:
        """Free vectors ``(B, P_free)`` of coordinate rows ``(B, P_free)`` and whether each is usable."""
        x = self.coordinates.inverse(np.atleast_2d(u_rows))
        res = self.residuals
        inside = np.isfinite(x).all(axis=1) & (x >= res.lower).all(axis=1) & (x <= res.upper).all(axis=1)
        return np.where(inside[:, None], x, np.clip(np.nan_to_num(x), res.lower, res.upper)), inside

    def __call__(self, u) -> np.ndarray:
        x, inside = self.parameters(u)
        return self.residuals(x[0]) if inside[0] else np.full(self.residuals.data.size, DOMAIN_PENALTY)

    def jacobian(self, u) -> np.ndarray:
        """Forward differences in ``u`` from one batch (a column whose step leaves the box: zero)."""
        u = np.asarray(u, dtype=float)
        steps = np.finfo(float).eps ** 0.5 * np.maximum(np.abs(u), 0.01)
        rows = np.repeat(u[None, :], u.size + 1, axis=0)
        rows[1:][np.arange(u.size), np.arange(u.size)] += steps
        x, inside = self.parameters(rows)
        w, valid = self.residuals.batch(x)
        usable = inside & valid
        jac = np.zeros((self.residuals.data.size, u.size))
        if usable[0]:
            difference_columns(w, w[0], steps, np.flatnonzero(usable[1:]), jac)
        return jac


def _polish_in_coordinates(residuals: WhitenedResiduals, log: _StartLog) -> None:
    """Phase 4: every polished end once more, in the sampler coordinates
    (:class:`identify.fitting.coordinates.GPICoordinates`: total weight and threshold moment,
    the envelopes' values at three inputs, their amplitudes' logarithms, Omega's centres), kept
    where it lowers the chi-square.

    In the parameters the GPI's valleys are curved (the weights trade against the
    envelopes' amplitudes along products, a tanh's slope against its offset along a ratio);
    a solver following one takes many short steps and can stop at its evaluation cap far
    from the floor. In the sampler coordinates those valleys are nearly straight: on the
    SMA record (``docs/realdata.md``) the ends that had stopped at the cap reached lower
    optima in 25-40 steps. The solver is trf without bounds in ``u``; a step whose
    parameters leave their box is refused through :data:`DOMAIN_PENALTY`. The ends are
    polished side by side, each on its own copy of the residuals.
    """
    ends = list(log.ends)
    model, time, current = residuals.model, residuals.time, residuals.current
    each = [GPICoordinates.for_model(model, time, current, reference=end.x) for _, end in ends]
    if not any(getattr(coordinates, "blocks", ()) for coordinates in each):
        return
    tasks = [
        _within_reach_of(log.best.chi2, partial(_polish_end_in_coordinates, coordinates=coordinates, x=end.x))
        for coordinates, (_, end) in zip(each, ends)
    ]
    for (label, end), (polished, used) in zip(ends, _side_by_side(residuals, tasks)):
        if polished is not None and polished.chi2 < end.chi2:
            log.keep(f"{label} (coordinates)", polished, used)


def _polish_end_in_coordinates(residuals: WhitenedResiduals, coordinates, x) -> _PolishedStart | None:
    """One end ``x`` polished in the sampler coordinates (:func:`_polish_in_coordinates`); None
    where it has no coordinates or the solver ended outside the box."""
    try:
        u0 = coordinates.forward(x[None, :])[0]
    except (ValueError, FloatingPointError):
        return None
    if not np.isfinite(u0).all():
        return None
    in_u = _ResidualsInCoordinates(residuals, coordinates)
    sol = stalling_solve(in_u, u0, in_u.jacobian, POLISH_EVALUATIONS, method=ALTERNATE_METHOD)
    polished, inside = in_u.parameters(sol.x)
    if not inside[0]:
        return None
    chi2 = 2.0 * float(sol.cost)  # the residual at sol.x is the parameters' (inside the box), as in _converged
    success, message = solver_verdict(sol)
    return _PolishedStart(polished[0], chi2, success, f"{message} (again in the sampler coordinates)")


def _canonical(residuals: WhitenedResiduals, x) -> np.ndarray:
    """Free vector ``x`` in the model's canonical labelling (:meth:`model.Model.canonical_theta`,
    e.g. a two-node ``thermal`` with the faster node first): the same output, so the same
    optimum, in the half of the parameter space the posterior samples."""
    theta = residuals.full(x)
    canonical = residuals.model.canonical_theta(theta)
    if np.array_equal(canonical, theta):
        return x
    mapped = canonical[residuals.free]
    return mapped if np.isfinite(residuals(mapped)).all() else x


def _fit_result(
    record, model: Model, residuals, noise: NoiseModel, best: _PolishedStart, outcomes, n_starts: int, t0: float
) -> FitResult:
    """The :class:`FitResult` at ``best``: a free sigma estimated from the chi-square, the
    covariance from the central Jacobian, the residual, RMS and maximum error on the energised part."""
    free = residuals.free
    n_samples = residuals.data.size
    x_best = _canonical(residuals, best.x)
    w = residuals(x_best)
    chi2 = float(w @ w)
    dof = n_samples - free.size
    if noise.is_free:
        sigma_hat = math.sqrt(chi2 / dof)
        noise = noise.with_sigma(sigma_hat)
        scale2 = sigma_hat**2
    else:
        scale2 = 1.0
    with single_threaded_blas():
        jac = residuals.central_jacobian(x_best)
    cov_free = scale2 * np.linalg.pinv(jac.T @ jac, rcond=1e-15, hermitian=True)
    n_par = model.n_parameters
    covariance = np.zeros((n_par, n_par))
    covariance[np.ix_(free, free)] = cov_free
    stderr = np.full(n_par, np.nan)
    stderr[free] = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))

    theta = residuals.full(x_best)
    y = model(theta, record.time, record.current)
    residual = np.asarray(record.displacement, dtype=float) - y
    energised = energised_mask(record, noise)
    span = float(np.ptp(record.displacement))
    rms = float(np.sqrt(np.mean(residual[energised] ** 2)))
    max_error_pct = float(100.0 * np.max(np.abs(residual[energised])) / span) if span > 0 else math.inf
    reduced_chi2 = chi2 / scale2 / dof
    # a start polished again (phases 3 and 4 label it "<start> (<how>)") is still one start
    n_agree = len({o.label.split(" (")[0] for o in outcomes if (o.chi2 - best.chi2) / scale2 <= AGREE_CHI2})
    return FitResult(
        model=model,
        theta=theta,
        stderr=stderr,
        covariance=covariance,
        vary=model.parameters.vary.copy(),
        residual=residual,
        rms=rms,
        max_error_pct=max_error_pct,
        reduced_chi2=float(reduced_chi2),
        noise=noise,
        n_starts=n_starts,
        success=bool(best.success),
        message=str(best.message),
        seconds=_time.perf_counter() - t0,
        n_agree=int(n_agree),
        starts=outcomes,
    )
