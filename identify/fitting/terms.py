"""Pin off the optional terms of the effects that a record does not support: :func:`select_terms`.

An effect's general form has optional terms (:attr:`model.Effect.terms`: the second node of
``thermal``, the settling warm-up and the ambient cycle of ``sensor_drift``, the saturating
and the logarithmic parts of ``creep``). An effect's alternative forms
(:attr:`model.Effect.forms`, creep's two parts) are each optional, but one is always kept
(:func:`keeps_every_effect`).
Where a record has no such part, the term's gains fit to about 0 and its other parameters
(a time constant, an onset) then have no effect at all: the likelihood is flat along them
and, near 0 gain, the gains trade with the rest of the effect (two thermal nodes of equal
time constants are one node). The least squares does not mind; a posterior does: its
chain crawls along the flat and twisted directions (measured: the two-node ``thermal`` on
the bundled record, whose heating is one-pole, did not converge in 60,000 steps for two
of five seeds; with the core node pinned off, 5,500 steps).

So, after the least squares, each optional term with every parameter free is tested by
the Bayesian information criterion: the model with the term pinned off (its parameters
at the effect's ``off`` values, ``vary=False``) is refitted from the full fit
(:meth:`model.Effect.reduced_starts`), and the term is pinned off when the whitened
chi-square rises by no more than :math:`k \\ln N` (``k`` the term's parameters, ``N`` the
samples), the BIC's price of the ``k`` parameters. Terms are tested one at a time, the
one whose removal costs least first, until none can go. The decisions are kept in the
fit (:attr:`identify.fitting.lsq.FitResult.terms`) and shown by the study and its report;
``study(select_terms=False)`` (``--all-terms``) keeps every term.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import replace

import numpy as np

from .lsq import WhitenedResiduals, fit_least_squares
from .noise import whiten

__all__ = ["select_terms", "optional_terms", "term_decision", "best_form", "keeps_every_effect"]


def optional_terms(model, effects=None) -> list[tuple[str, str, tuple[str, ...]]]:
    """``[(effect, term, parameter names)]`` of ``model``'s optional terms whose parameters all vary
    (of the effects named in ``effects`` only, when given)."""
    out = []
    for effect in model.effects:
        if effects is not None and effect.name not in effects:
            continue
        for term, names in type(effect).terms.items():
            if all(model.parameters[n].vary for n in names):
                out.append((effect.name, term, tuple(names)))
    return out


def _off_terms(model, effect) -> set[str]:
    """The terms of ``model``'s effect (class ``effect``) pinned at their off values."""
    parameters = model.parameters
    return {
        term
        for term, names in effect.terms.items()
        if all(not parameters[n].vary and parameters[n].value == effect.off[n] for n in names)
    }


def keeps_every_effect(model, switched_off) -> bool:
    """Does ``model`` keep a form of each effect (:meth:`model.Effect.keeps_a_form`) with the
    terms ``switched_off`` (``[(effect, term)]``) off as well as those pinned off?"""
    by_effect: dict[str, set[str]] = {}
    for effect_name, term in switched_off:
        by_effect.setdefault(effect_name, set()).add(term)
    effects = {e.name: type(e) for e in model.effects}
    return all(
        effects[name].keeps_a_form(terms | _off_terms(model, effects[name])) for name, terms in by_effect.items()
    )


def _whitened_chi2(residual, noise, time) -> float:
    return float(np.sum(whiten(residual, noise, time=time) ** 2))


def _reduced_fit(record, fit, effect_name, term, names, rng):
    """``(fit, chi2)``: the best least-squares fit of ``fit.model`` with ``term`` pinned off,
    from the effect's reduced starts, and its chi-square under ``fit``'s noise model; None
    when no start could be fitted."""
    model = fit.model
    effect = next(e for e in model.effects if e.name == effect_name)
    parameters = model.parameters
    for n in names:
        parameters = parameters.replace(n, value=float(type(effect).off[n]), vary=False)
    reduced = model.with_parameters(parameters)
    values = fit.theta_dict()
    block = {n: values[n] for n in effect.parameters.names}
    best, best_chi2 = None, np.inf
    for start_values in type(effect).reduced_starts(block, term):
        start = fit.theta.copy()
        for n, v in start_values.items():
            p = reduced.parameters[n]
            start[reduced.names.index(n)] = min(max(float(v), p.lower), p.upper)
        try:
            candidate = fit_least_squares(record, reduced, noise=fit.noise, start=start, n_starts=1, rng=rng)
        except ValueError:
            continue  # a start outside the model's reach: the other starts decide
        # one noise model for every comparison (a free sigma is re-estimated per fit)
        chi2 = _whitened_chi2(candidate.residual, fit.noise, record.time)
        if chi2 < best_chi2:
            best, best_chi2 = candidate, chi2
    return None if best is None else (best, best_chi2)


def term_decision(effect, term, names, delta_chi2, n_samples, pinned) -> dict:
    """The JSON-ready record of one test (kept in ``fit.json`` and the summary)."""
    return {
        "effect": effect,
        "term": term,
        "parameters": list(names),
        "delta_chi2": float(delta_chi2),
        "penalty": float(len(names) * math.log(n_samples)),
        "pinned": bool(pinned),
    }


def select_terms(record, fit, *, rng=None, log=None):
    """``fit`` with the optional terms the record does not support pinned off (module docstring).

    Parameters
    ----------
    record : identify.data.records.Record
        The record fitted.
    fit : identify.fitting.lsq.FitResult
        A least-squares fit of a model with effects (every term free or some pinned).
    rng : numpy.random.Generator, optional
        Passed to the refits (which use the given starts only).
    log : callable(str), optional
        One line per decision.

    Returns
    -------
    identify.fitting.lsq.FitResult
        The fit of the model with the unsupported terms pinned off (``fit`` itself when none
        is), its ``terms`` listing every test made (``pinned`` True or False) with its
        chi-square change and BIC penalty. The starts (``n_starts``, ``starts``,
        ``n_agree``) are ``fit``'s, the search that found the optimum the refits polish;
        ``seconds`` includes the tests.
    """
    t0 = time.perf_counter()
    say = log or (lambda message: None)
    n_samples = int(np.asarray(fit.residual).size)
    chi2_ref = _whitened_chi2(fit.residual, fit.noise, record.time)
    decisions = list(fit.terms)
    current = fit
    while True:
        tried = []  # (decision, reduced fit, its chi-square)
        for effect, term, names in optional_terms(current.model):
            if any(d["effect"] == effect and d["term"] == term for d in decisions):
                continue  # tested before and kept: the rest of the model has not lost anything it could use
            if not keeps_every_effect(current.model, [(effect, term)]):
                continue  # the effect's last form: the effect itself is the model's choice, not a term
            refit = _reduced_fit(record, current, effect, term, names, rng)
            if refit is not None:
                reduced, chi2 = refit
                tried.append((term_decision(effect, term, names, chi2 - chi2_ref, n_samples, False), reduced, chi2))
        if not tried:
            break
        tried.sort(key=lambda t: t[0]["delta_chi2"])
        cheapest, reduced, chi2 = tried[0]
        if cheapest["delta_chi2"] > cheapest["penalty"]:  # the cheapest removal costs more than its parameters
            for d, _, _ in tried:
                decisions.append(d)
                say(
                    f"{d['effect']} term '{d['term']}' kept: pinning it off raises chi-square by {d['delta_chi2']:.1f} "
                    f"> BIC penalty {d['penalty']:.1f} ({len(d['parameters'])} parameters)"
                )
            break
        decisions.append({**cheapest, "pinned": True})
        say(
            f"{cheapest['effect']} term '{cheapest['term']}' pinned off ({', '.join(cheapest['parameters'])}): the "
            f"record does not support it (chi-square {cheapest['delta_chi2']:+.1f} <= BIC penalty "
            f"{cheapest['penalty']:.1f} for {len(cheapest['parameters'])} parameters)"
        )
        current, chi2_ref = reduced, chi2
    if current is fit and decisions == list(fit.terms):
        return fit
    # the refits polish the multistart's end: its starts are still the search that found it
    return replace(
        current,
        terms=decisions,
        n_starts=fit.n_starts,
        starts=list(fit.starts),
        n_agree=fit.n_agree,
        seconds=fit.seconds + (time.perf_counter() - t0),
    )


def _dead_columns(residuals, theta, candidates) -> tuple[np.ndarray, set[int]]:
    """``(w, dead)``: the whitened residual at the full vector ``theta`` and the columns of
    ``candidates`` (full-vector indices of free parameters) along which it does not change at all
    there: each moved by 1 % of its range (toward the side inside its bounds), one batch.

    With a term switched off, a parameter that only shaped that term's action (training's fade
    length :math:`V_0` with every virgin difference but one off) acts no more, yet its
    Jacobian column at the fit still carries the term's shape; in the first-order
    re-optimisation it would rebuild the term that was switched off, and the term would go
    uncharged (measured: a strain gain 0.016 fading over 50 A, its column of :math:`V_0`
    absorbed it wholly). A column that is dead at the reduced point is no direction of the
    reduced model."""
    free = [int(j) for j in residuals.free]
    x = np.asarray(theta, dtype=float)[residuals.free]
    probes = [j for j in sorted(candidates) if j in free]
    rows = np.repeat(x[None, :], len(probes) + 1, axis=0)
    for k, column in enumerate(probes):
        i = free.index(column)
        lower, upper = residuals.lower[i], residuals.upper[i]
        span = upper - lower if np.isfinite(upper - lower) else max(abs(x[i]), 1.0)
        step = 0.01 * span
        rows[k + 1, i] = x[i] + step if x[i] + step <= upper else x[i] - step
    w, valid = residuals.batch(rows)
    base = w[0] if valid[0] else residuals(x)
    dead = {column for k, column in enumerate(probes) if valid[k + 1] and np.array_equal(w[k + 1], base)}
    return base, dead


#: At most this many optional terms, each cheap alone, are weighed jointly by :func:`best_form` (every subset).
MAX_JOINT_TERMS = 8


def best_form(record, fit, effects, n_samples, jacobian=None):
    r"""The best form of ``fit``'s effects ``effects`` by the BIC: which of their optional terms
    (:attr:`model.Effect.terms`) the record pays for, weighed without a refit.

    A general form nests simpler ones, and a comparison by BIC must not charge an effect for
    terms it does not use. For each subset :math:`S` of the terms (and each way of switching
    a term off, :meth:`model.Effect.term_reductions`), the terms are switched off exactly and
    the rest of the model is re-optimised to first order: with :math:`w_S` the whitened
    residual at the fit with the terms off and :math:`J_R` the Jacobian of the parameters
    left free (the terms' parameters excluded, their shapes included: a time constant of a
    term that is off is no parameter at all),
    :math:`\chi^2_S \approx \min_\delta \lVert w_S + J_R \delta \rVert^2`. The subset that
    maximises :math:`k_S \ln n - n \ln(\chi^2_S / \chi^2)` (:math:`k_S` its parameters) is
    returned; none when every term pays for itself (the subsets are those of the terms
    that pay less than their parameters alone). Switching the term off exactly, not
    along its own derivative, keeps the weighing sound at a term's bound or kink (measured:
    a soft training threshold fitted at 9e-5 A, whose central-difference derivative at that
    scale was 2e6 times its secant in norm, 4.8e9 against 2306); only the rest's re-optimisation is linearised, exact
    for the parameters that enter linearly and accurate for a term that changes little,
    which is where a term is unused. A rise below 0 counts as 0.

    Parameters
    ----------
    record : identify.data.records.Record
    fit : identify.fitting.lsq.FitResult
        The fit of the model with the effects (every term free); its noise is fixed.
    effects : collection of str
        The effects whose terms are weighed (e.g. the candidate effects a diagnosis adds).
    n_samples : float
        The sample count of the BIC (a diagnosis passes its effective count).
    jacobian : ndarray, shape (T, P_free), optional
        The whitened residual's Jacobian at ``fit.theta`` over ``fit``'s free parameters
        (default: central differences, one batch of ``2 P_free + 1`` evaluations).

    Returns
    -------
    dict
        ``{"terms": [(effect, term)], "parameters": k_S, "delta_chi2": chi2_S - chi2}`` of the
        best subset (empty, 0 and 0.0 when every term is kept).
    """
    model = fit.model
    terms = optional_terms(model, effects)
    none = {"terms": [], "parameters": 0, "delta_chi2": 0.0}
    if not terms:
        return none
    theta = np.asarray(fit.theta, dtype=float)
    residuals = WhitenedResiduals(record, model, fit.noise)
    free = [int(j) for j in residuals.free]
    effects_by_name = {e.name: type(e) for e in model.effects}
    # the weighed effects' free parameters: with some terms off, one of them may act no more
    weighed = {
        model.names.index(n)
        for e in model.effects
        if e.name in set(effects)
        for n in e.parameters.names
        if model.parameters[n].vary
    }
    options = [effects_by_name[effect].term_reductions(term) for effect, term, _ in terms]
    if jacobian is None:
        jacobian = residuals.central_jacobian(theta[residuals.free])
    info = jacobian.T @ jacobian
    w = residuals(theta[residuals.free])
    chi2 = float(w @ w)
    if not chi2 > 0:
        return none
    log_n = math.log(n_samples)

    rises = {}

    def rise(reductions) -> float:
        """The chi-square rise with these reductions applied and the rest re-optimised to first order."""
        key = tuple(tuple(sorted(reduction.items())) for reduction in reductions)
        if key not in rises:
            rises[key] = _rise(reductions)
        return rises[key]

    def _rise(reductions) -> float:
        values = {n: v for reduction in reductions for n, v in reduction.items()}
        reduced = theta.copy()
        for n, v in values.items():
            reduced[model.names.index(n)] = v
        w_s, dead = _dead_columns(residuals, reduced, weighed - {model.names.index(n) for n in values})
        off_columns = {model.names.index(n) for n in values} | dead
        rest = [j for j, column in enumerate(free) if column not in off_columns]
        projection = jacobian[:, rest].T @ w_s
        absorbed = float(
            projection @ np.linalg.pinv(info[np.ix_(rest, rest)], rcond=1e-15, hermitian=True) @ projection
        )
        return max(float(w_s @ w_s) - absorbed - chi2, 0.0)

    def gain(k, delta) -> float:
        return k * log_n - n_samples * math.log1p(delta / chi2)

    # one pass over the terms, then every combination of those that are cheap alone
    cheap = []
    for i, (_, _, names) in enumerate(terms):
        ways = [(reduction, rise([reduction])) for reduction in options[i]]
        ways = [(r, d) for r, d in ways if gain(len(names), d) > 0]
        if ways:
            cheap.append((i, [r for r, _ in ways]))
    cheap = cheap[:MAX_JOINT_TERMS]
    best, best_gain = none, 0.0
    for size in range(1, len(cheap) + 1):
        for subset in itertools.combinations(cheap, size):
            if not keeps_every_effect(model, [terms[i][:2] for i, _ in subset]):
                continue  # an effect with every form off is no form of it
            k = sum(len(terms[i][2]) for i, _ in subset)
            for choice in itertools.product(*(ways for _, ways in subset)):
                delta = rise(choice)
                if gain(k, delta) > best_gain:
                    best_gain = gain(k, delta)
                    best = {"terms": [terms[i][:2] for i, _ in subset], "parameters": k, "delta_chi2": delta}
    return best
