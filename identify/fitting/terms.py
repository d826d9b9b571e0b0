"""Pin off the optional terms of the effects that a record does not support: :func:`select_terms`.

An effect's general form has optional terms (:attr:`model.Effect.terms`: the second node of
``thermal``, the settling warm-up and the ambient cycle of ``sensor_drift``, the logarithmic
part of ``creep``).
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

import math
import time
from dataclasses import replace

import numpy as np

from .noise import whiten

__all__ = ["select_terms", "optional_terms", "term_decision"]


def optional_terms(model) -> list[tuple[str, str, tuple[str, ...]]]:
    """``[(effect, term, parameter names)]`` of ``model``'s optional terms whose parameters all vary."""
    out = []
    for effect in model.effects:
        for term, names in type(effect).terms.items():
            if all(model.parameters[n].vary for n in names):
                out.append((effect.name, term, tuple(names)))
    return out


def _whitened_chi2(residual, noise) -> float:
    return float(np.sum(whiten(residual, noise) ** 2))


def _reduced_fit(record, fit, effect_name, term, names, rng):
    """``(fit, chi2)``: the best least-squares fit of ``fit.model`` with ``term`` pinned off,
    from the effect's reduced starts, and its chi-square under ``fit``'s noise model; None
    when no start could be fitted."""
    from .lsq import fit_least_squares

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
        chi2 = _whitened_chi2(candidate.residual, fit.noise)
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
    chi2_ref = _whitened_chi2(fit.residual, fit.noise)
    decisions = list(fit.terms)
    current = fit
    while True:
        tried = []  # (decision, reduced fit, its chi-square)
        for effect, term, names in optional_terms(current.model):
            if any(d["effect"] == effect and d["term"] == term for d in decisions):
                continue  # tested before and kept: the rest of the model has not lost anything it could use
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
                say(f"{d['effect']} term '{d['term']}' kept: pinning it off raises chi-square by {d['delta_chi2']:.1f} "
                    f"> BIC penalty {d['penalty']:.1f} ({len(d['parameters'])} parameters)")  # fmt: skip
            break
        decisions.append({**cheapest, "pinned": True})
        say(f"{cheapest['effect']} term '{cheapest['term']}' pinned off ({', '.join(cheapest['parameters'])}): the "
            f"record does not support it (chi-square {cheapest['delta_chi2']:+.1f} <= BIC penalty "
            f"{cheapest['penalty']:.1f} for {len(cheapest['parameters'])} parameters)")  # fmt: skip
        current, chi2_ref = reduced, chi2
    if current is fit and decisions == list(fit.terms):
        return fit
    # the refits polish the multistart's end: its starts are still the search that found it
    return replace(current, terms=decisions, n_starts=fit.n_starts, starts=list(fit.starts), n_agree=fit.n_agree,
                   seconds=fit.seconds + (time.perf_counter() - t0))
