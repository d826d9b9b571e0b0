"""The least squares' solver runs: the settings of :func:`scipy.optimize.least_squares` (methods,
evaluation caps, tolerances), the stall rule (:class:`StallStop`, :func:`solver_verdict`) and
one bounded run (:func:`bounded_solve`), shared by the fit and the diagnosis' refits.

How the fit uses them (screening, polishing, the alternate method) is in
:mod:`identify.fitting.lsq`'s docstring, "Starts".
"""

from __future__ import annotations

import contextlib
import math
from contextvars import ContextVar

import numpy as np
from scipy.optimize import least_squares

from .lapack import release_the_gil_in_least_squares
from .lsq_residuals import WhitenedResiduals

__all__ = [
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
    "StallStop",
    "out_of_reach",
    "beyond_a_tie",
    "reach_rule",
    "tie_rule",
    "within_reach_of_best",
    "START_OUT_OF_REACH_Z",
    "separation_bound",
    "solver_verdict",
    "stalling_solve",
    "bounded_solve",
    "on_a_bound",
    "solve_within_box",
]

#: Solver evaluations each start gets in the screening phase.
SCREEN_EVALUATIONS = 20
#: How many of the best screened starts are run to convergence. Twenty evaluations rank the
#: starts only roughly: on an independent clean record (every second sample) the start that
#: reaches the global optimum was ranked third after screening (chi-square 3529 from the two
#: best, 3431 with four), and on the SMA record 1 of 5 seeds missed the best basin with 2
#: polished starts and none with 4.
N_POLISH = 4
#: How many of the best starts after a screening with :data:`ALTERNATE_METHOD` are run to
#: convergence too (from that screening's end, with :data:`SOLVER_METHOD`; a start among
#: dogbox's best as well is then polished from both ends). Dogbox's large first steps can
#: throw a start that lies in the global optimum's basin into a degenerate region, where it
#: ranks last: on an independent clean record at 1 kHz the Table-1 start did, and from trf's
#: screening it reached the global optimum.
N_POLISH_ALTERNATE = 2
#: :func:`scipy.optimize.least_squares` method. "dogbox" rather than "trf": on the bundled
#: record (plain GPI fitted to data with a hidden thermal effect, a curved valley) dogbox
#: reached the optimum in 44 evaluations (0.7 s) where trf crawled for 750 evaluations
#: (16 s) and stopped 25 higher in chi-square; on clean records both agree.
SOLVER_METHOD = "dogbox"
#: Second method for starts whose dogbox optimum put a GPI parameter on a box bound: the
#: trust-region-reflective method stays inside the box and reached the global optimum where
#: dogbox ended in such a degenerate limit (an independent clean record with crossing operator
#: bounds: chi-square 11655 against the truth's 7158; trf 7136 from the same start).
ALTERNATE_METHOD = "trf"
#: Cap on the solver evaluations of each polished start (a misspecified model can crawl
#: along a flat valley for thousands of steps; the result then says "not converged").
POLISH_EVALUATIONS = 400
#: Relative tolerances of the solver (ftol, xtol, gtol): a chi-square change of 1e-8
#: relative is far below 1, the statistically meaningful scale.
TOLERANCE = 1e-8
#: A solver run stops as stalled when its last :data:`STALL_ITERATIONS` iterations together
#: lowered the chi-square by less than :data:`STALL_CHI2` (an absolute amount of the whitened
#: chi-square, the same for every record size: a likelihood ratio of exp(0.05)). The relative
#: tolerances cannot see this: in a curved valley each step gains more than ``ftol`` of the
#: chi-square, so a misspecified model crawls on to the evaluation cap. Measured (diagnoses of
#: a 1 kHz record and of the worst-case bench record, every solver run's chi-square per
#: iteration): a dogbox run gained 3 in chi-square in 370 evaluations (62 s at 70001
#: samples), and the rule's chi-square at the stop was at most 1.8 above the run's end in
#: all but one of 550 runs (a plateau that dropped by 18 after 190 iterations, in a
#: baseline of the sign that lost by 9,300).
STALL_ITERATIONS = 10
#: See :data:`STALL_ITERATIONS`.
STALL_CHI2 = 0.1
#: Solver status of a run stopped as stalled (:class:`StallStop`; scipy's status of a callback's stop).
STALLED = -2


#: The rule of :func:`out_of_reach` in force in this thread: ``(reference chi-square, z)`` or None.
_OUT_OF_REACH: ContextVar[tuple[float, float] | None] = ContextVar("out_of_reach", default=None)
#: The rule of :func:`beyond_a_tie` in force in this thread: ``(reference chi-square, bic, n_eff)`` or None.
_BEYOND_A_TIE: ContextVar[tuple[float, float, float] | None] = ContextVar("beyond_a_tie", default=None)


def separation_bound(chi2: float, reference: float, n_samples: int) -> float:
    r"""A lower bound on how many noise standard deviations separate a fit of whitened
    chi-square ``chi2`` from any fit of ``reference`` or less, on ``n_samples`` samples.

    The likelihood gap of two fits is :math:`n_\mathrm{eff} \ln \rho`, :math:`\rho` the ratio of
    their chi-squares, and the noise gives it the standard deviation
    :math:`2 \sigma_w \lVert d \rVert n_\mathrm{eff} / \chi^2_a`
    (:func:`identify.diagnosis.evidence.gap_noise_sd`; :math:`d` the difference of the whitened
    residuals, :math:`\sigma_w^2 = \chi^2_a / T`). With :math:`\lVert d \rVert \le \sqrt{\chi^2_a} +
    \sqrt{\chi^2_b}` the effective size cancels and

    .. math::  z \ge \frac{\sqrt{T}\,\ln \rho}{2\,(1 + \sqrt{\rho})},

    whatever the two residuals are; it grows with the record, so a fit a fixed share of the
    chi-square behind is hopelessly behind on a long record. 0 when ``chi2 <= reference``.
    """
    if not (chi2 > reference > 0.0):
        return 0.0
    ratio = chi2 / reference
    return math.sqrt(n_samples) * math.log(ratio) / (2.0 * (1.0 + math.sqrt(ratio)))


#: A start of a multi-start fit stops once out of reach, by this many noise standard deviations of
#: the gap, of the lowest chi-square some start has reached (:func:`within_reach_of_best`): such
#: a start cannot end lowest, the only end the fit keeps. Generous, so a run that would have
#: sped up again still ends far behind.
START_OUT_OF_REACH_Z = 10.0


def reach_rule() -> tuple[float, float] | None:
    """The rule of :func:`out_of_reach` in force in this thread: ``(reference chi-square, z)``, or None."""
    return _OUT_OF_REACH.get()


def tie_rule() -> tuple[float, float, float] | None:
    """The rule of :func:`beyond_a_tie` in force in this thread: ``(reference chi-square, bic, n_eff)``, or None."""
    return _BEYOND_A_TIE.get()


@contextlib.contextmanager
def within_reach_of_best(best_chi2: float):
    """:func:`out_of_reach` of ``best_chi2`` with :data:`START_OUT_OF_REACH_Z`, unless a rule in
    force already stops runs behind a lower chi-square (whose own ``z`` is kept)."""
    rule = _OUT_OF_REACH.get()
    if rule is not None and rule[0] <= best_chi2 or not math.isfinite(best_chi2):
        yield
        return
    with out_of_reach(best_chi2, START_OUT_OF_REACH_Z):
        yield


@contextlib.contextmanager
def out_of_reach(reference_chi2: float, z: float):
    """Within the block (in this thread), every solver run stops once it cannot come near
    ``reference_chi2``: its chi-square, less what it would still gain at its last
    :data:`STALL_ITERATIONS` iterations' pace over every evaluation it has left, stays at least
    ``z`` noise standard deviations of the gap behind a fit of ``reference_chi2``
    (:func:`separation_bound`). A fit that far behind is told apart from the reference's by
    the data whatever it would end at, so the evaluations it would spend crawling decide
    nothing. ``reference_chi2`` must be a chi-square some fit reaches (e.g. a start's)."""
    token = _OUT_OF_REACH.set((float(reference_chi2), float(z)))
    try:
        yield
    finally:
        _OUT_OF_REACH.reset(token)


@contextlib.contextmanager
def beyond_a_tie(reference_chi2: float, bic: float, n_eff: float):
    """Within the block (in this thread), every solver run stops once it can neither end below
    ``reference_chi2`` nor tie with it: its chi-square, less what it would still gain at its last
    :data:`STALL_ITERATIONS` iterations' pace over every evaluation it has left, stays above it by
    more than ``bic`` in BIC units, ``n_eff ln(chi2 / reference_chi2)`` (two fits with the same
    free parameters; ``n_eff`` the effective sample size of the residuals where the fit starts).
    For a fit that serves only where it is the lower of two or ties with the lower one (a
    model's other threshold sign): beyond that it serves neither way. ``reference_chi2`` must be
    a chi-square some fit reaches."""
    token = _BEYOND_A_TIE.set((float(reference_chi2), float(bic), float(n_eff)))
    try:
        yield
    finally:
        _BEYOND_A_TIE.reset(token)


class StallStop:
    """Callback of :func:`scipy.optimize.least_squares` that stops a stalled run.

    After every iteration it records the chi-square ``sum(fun**2)`` at the accepted point
    (``fun``: the whitened residuals) and raises :class:`StopIteration` once the last
    ``window`` iterations together lowered it by less than ``chi2`` (the solver then returns
    status :data:`STALLED`; :func:`solver_verdict` reads that as converged).

    Within :func:`out_of_reach`, it also stops a run that cannot come near the rule's
    reference, and within :func:`beyond_a_tie` one that can neither end below its reference nor
    tie with it (``reason`` says which rule stopped it).

    Parameters
    ----------
    window : int, default :data:`STALL_ITERATIONS`
    chi2 : float, default :data:`STALL_CHI2`
        Absolute chi-square (whitened residuals).
    max_nfev : int, optional
        The run's evaluation cap (the iterations it has left bound the gain still to come);
        without it neither :func:`out_of_reach` nor :func:`beyond_a_tie` applies.
    """

    def __init__(self, window: int = STALL_ITERATIONS, chi2: float = STALL_CHI2, max_nfev: int | None = None):
        self.window, self.chi2 = int(window), float(chi2)
        self.max_nfev = max_nfev
        self.history: list[float] = []
        self.reason = ""

    def __call__(self, intermediate_result) -> None:
        f = np.asarray(intermediate_result.fun, dtype=float)
        self.history.append(float(f @ f))
        if len(self.history) <= self.window:
            return
        recent = self.history[-1 - self.window] - self.history[-1]
        if recent < self.chi2:
            self.reason = "stalled"
            raise StopIteration
        if self.max_nfev is None:
            return
        left = max(self.max_nfev - len(self.history), 0)
        lowest = self.history[-1] - max(recent, 0.0) * left / self.window
        rule = _OUT_OF_REACH.get()
        if rule is not None and separation_bound(lowest, rule[0], f.size) >= rule[1]:
            self.reason = "out_of_reach"
            raise StopIteration
        tie = _BEYOND_A_TIE.get()
        if tie is not None and lowest > tie[0] and tie[2] * math.log(lowest / tie[0]) > tie[1]:
            self.reason = "beyond_a_tie"
            raise StopIteration


def solver_verdict(sol, stall: StallStop | None = None) -> tuple[bool, str]:
    """``(success, message)`` of a :func:`scipy.optimize.least_squares` result, a stall
    counting as converged with its own message, which states the rule of ``stall`` (the
    :class:`StallStop` the run was given; default the default rule)."""
    if sol.status == STALLED:
        stall = getattr(sol, "stall", None) if stall is None else stall
        stall = StallStop() if stall is None else stall
        if stall.reason == "out_of_reach":
            return True, "stopped: too far behind the best fit to matter, at the pace it was gaining"
        if stall.reason == "beyond_a_tie":
            return True, "stopped: it could neither end lowest nor tie, at the pace it was gaining"
        return True, (
            f"stalled: the chi-square fell by less than {stall.chi2:g} over the last {stall.window} iterations"
        )
    return bool(sol.success), str(sol.message)


def stalling_solve(fun, x0, jac, max_nfev, method=SOLVER_METHOD, tolerance=TOLERANCE, bounds=(-np.inf, np.inf)):
    """One solver run of ``fun`` from ``x0`` (:func:`scipy.optimize.least_squares`, Jacobian
    ``jac``): ``method`` with Jacobian scaling, relative tolerances ``tolerance``, the stall rule
    (:class:`StallStop`) and ``bounds`` (none by default)."""
    stall = StallStop(max_nfev=max_nfev)
    release_the_gil_in_least_squares()  # fits side by side: the solver's LAPACK calls without the GIL
    sol = least_squares(
        fun,
        x0,
        jac=jac,
        bounds=bounds,
        method=method,
        x_scale="jac",
        ftol=tolerance,
        xtol=tolerance,
        gtol=tolerance,
        max_nfev=max_nfev,
        callback=stall,
    )
    sol.stall = stall  # which rule stopped it (solver_verdict)
    return sol


def bounded_solve(residuals: WhitenedResiduals, x0, max_nfev, method=SOLVER_METHOD, tolerance=TOLERANCE):
    """One bounded solver run on ``residuals`` from free vector ``x0`` (:func:`stalling_solve`
    within the parameters' box). The diagnosis' short refits and polishes run it too."""
    bounds = (residuals.lower, residuals.upper)
    return stalling_solve(residuals, x0, residuals.jacobian, max_nfev, method, tolerance, bounds)


def solve_within_box(residuals, x0, max_nfev, solve=None):
    """A bounded solver run of ``residuals`` from free vector ``x0`` with :data:`SOLVER_METHOD`;
    where it ends on a box bound (:func:`on_a_bound`), :data:`ALTERNATE_METHOD` from that end and
    from ``x0`` as well (once where the two are the same), the lowest cost kept. Each run at most
    ``max_nfev`` evaluations. The single-record fit runs its starts with the interior method from
    their origin for the same reason (:mod:`identify.fitting.lsq`, its third phase).

    A dogbox end on a bound may have stopped short there (its step collapses along the bound's
    face); or its large first steps may have thrown the start out of its basin into a degenerate
    limit (a slow effect's time constant at its bound), which the interior method, started from
    there, does not leave, while started from ``x0`` it stays in the start's basin. ``solve``:
    ``solve(residuals, x, max_nfev, method=...)`` returning a result with ``x`` and ``cost``
    (default :func:`bounded_solve`)."""
    solve = bounded_solve if solve is None else solve
    sol = solve(residuals, x0, max_nfev)
    if on_a_bound(sol.x, residuals.lower, residuals.upper).any():
        # one run where dogbox did not move (a start on a bound it could not leave)
        starts = (sol.x,) if np.array_equal(sol.x, x0) else (sol.x, x0)
        for start in starts:
            onward = solve(residuals, start, max_nfev, method=ALTERNATE_METHOD)
            sol = onward if onward.cost < sol.cost else sol
    return sol


def on_a_bound(x, lower, upper) -> np.ndarray:
    """Boolean per free parameter ``(P_free,)``: whether ``x`` sits on its box bound, within
    1e-9 of the box's width (at least of 1; an infinite side is never reached). Where a
    :data:`SOLVER_METHOD` run ends there it may have stopped short: its step in the box
    collapses along the bound's face, while :data:`ALTERNATE_METHOD`'s interior trust region
    still descends."""
    x, lower, upper = (np.asarray(a, dtype=float) for a in (x, lower, upper))
    span = upper - lower
    near = 1e-9 * np.maximum(1.0, np.where(np.isfinite(span), span, 0.0))
    return (x <= lower + near) | (x >= upper - near)
