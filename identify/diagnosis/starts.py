"""Where a candidate's refit starts: the start strategies of the search.

The least squares of a GPI has several basins, and a hidden effect can move the GPI far from
the baseline's compromise, so every candidate is refitted from several groups of starts, each
group made by one strategy (:func:`identify.diagnosis.fits.short_refit` runs the most
promising starts of every group). A strategy is a small function that returns a list of full
start vectors of the candidate's model (empty where it does not apply):

* :func:`near` - a fit the search already has (the baseline of the candidate's threshold sign,
  or another candidate's fit: its GPI and the model's other effects) with the candidate's own
  parameters at each of several values (its screening grid, its short refit, its screening
  step), and with the candidate off;
* :func:`data_driven` - the data-driven GPI starts of :mod:`identify.fitting.lsq` (the paper's
  Table 1 rescaled to the record) with the candidate's values;
* :func:`screening_step` - the screening's best point, the GPI stepped along the linearised
  fit (a grid point on a stretch where the effect does nothing ties with "off" and would take
  every refit of a shared group);
* :func:`carried` - what an earlier round reached with the candidate (a better baseline moves
  the GPI, and a basin found against the old one must not be lost);
* :func:`members` - for a pair: each member's fit with the partner's parameters, and with the
  partner off but shaped as its own fit (its time constants kept, its gains off): the short
  refit is then never worse than the better member;
* :func:`from_scratch` - least squares from data-driven starts on the working copy, in a given
  threshold sign (a misspecified plain GPI can settle on the sign the hidden effect does not
  fit, and refits from its basin stay there).
"""

from __future__ import annotations

import numpy as np

from model import Model, get_effect

from ..fitting.lsq import FitResult, WhitenedResiduals, candidate_starts, fit_least_squares
from .fits import Working, effect_values, embed, same_threshold_sign, with_values
from .screening import ScreeningResult, acts, probe_change

__all__ = ["near", "data_driven", "screening_step", "carried", "members", "shapes", "from_scratch", "FRESH_STARTS"]

#: Data-driven starts of a fit from scratch (:func:`from_scratch`).
FRESH_STARTS = 2


def _in_bounds(model_e: Model, starts) -> list:
    return [s for s in starts if model_e.in_bounds(s)[0]]


def near(donor: FitResult, model_e: Model, values=(), extra=()) -> list:
    """``extra``, then ``donor``'s fit (parameters by name; the candidate's own off) with each
    ``{parameter: value}`` of ``values``, then with the candidate off. ``donor`` must pin the
    threshold sign of ``model_e``; parameters ``model_e`` lacks are dropped."""
    off = embed(donor.model, donor.theta, model_e, drop_extra=True)
    return _in_bounds(model_e, [*extra, *(with_values(model_e, off, v) for v in values), off])


def data_driven(work: Working, model_e: Model, values=(), n_starts: int = 2) -> list:
    """The data-driven GPI starts of ``model_e`` on the working copy
    (:func:`identify.fitting.lsq.candidate_starts`) with each of ``values``."""
    try:
        bases = [theta for _, theta in candidate_starts(work.record, model_e, n_starts=n_starts)]
    except ValueError:  # no start of that model gives a finite output
        return []
    return _in_bounds(model_e, [with_values(model_e, base, v) for v in values for base in bases])


def screening_step(screening: ScreeningResult | None, model_e: Model) -> list:
    """The screening's best start (when it is a vector of ``model_e``: the baseline's sign)."""
    if screening is None or not screening.starts or len(screening.starts[0]) != model_e.n_parameters:
        return []
    return _in_bounds(model_e, screening.starts[:1])


def carried(history, model_e: Model) -> list:
    """``(model, theta)`` pairs an earlier round reached, as vectors of ``model_e`` where they
    have its parameters and its threshold sign."""
    starts = []
    for model_from, theta in history:
        if set(model_from.names) == set(model_e.names) and same_threshold_sign(model_from, model_e):
            starts.append(embed(model_from, theta, model_e))
    return _in_bounds(model_e, starts)


def shapes(work: Working, baseline: FitResult, name: str, model_e: Model, theta_e) -> dict:
    """``{parameter: value}`` of effect ``name`` off but shaped as in ``theta_e``: the parameters
    that do nothing while the effect is off (time constants, travel scale, fade shape: moving
    one by 5 % of its range from the off point leaves the output unchanged) at their fitted
    values, the others (its gains) at :attr:`model.Effect.off`."""
    effect = get_effect(name)
    fitted = effect_values(model_e, theta_e, name)
    off_theta = embed(baseline.model, baseline.theta, model_e, drop_extra=True)
    columns = model_e.effect_slice(name)
    values = {}
    for offset, parameter in enumerate(model_e.names[columns]):
        column = columns.start + offset
        _, change = probe_change(model_e, off_theta, column, work.record)
        shape = change is not None and not acts(change)  # a probe that fails counts as a gain
        values[parameter] = fitted[parameter] if shape else float(effect.off.get(parameter, off_theta[column]))
    return values


def members(model_pair: Model, one, other, shaped=None) -> list:
    """Starts of a pair from its members' fits: each member's ``(name, model, theta)`` with the
    partner's fitted parameters, and with the partner off but shaped as its own fit
    (``shaped``: ``{name: values}`` of :func:`shapes`). A member fitted with another threshold
    sign than ``model_pair``'s gives no start."""
    shaped = {} if shaped is None else shaped
    starts = []
    for (_, model_a, theta_a), (name_b, model_b, theta_b) in ((one, other), (other, one)):
        if not same_threshold_sign(model_a, model_pair):
            continue
        member = embed(model_a, theta_a, model_pair, drop_extra=True)
        starts.append(with_values(model_pair, member, effect_values(model_b, theta_b, name_b)))
        if name_b in shaped:
            starts.append(with_values(model_pair, member, shaped[name_b]))
    return _in_bounds(model_pair, starts)


def from_scratch(
    work: Working, model_e: Model, rng: np.random.Generator, sign: str | None = None, n_starts: int = FRESH_STARTS
) -> list:
    """``model_e`` fitted from scratch on the working copy (least squares from
    :data:`FRESH_STARTS` data-driven starts, both solvers, in threshold sign ``sign``): its
    optimum as one start, in the model of that sign (the fit's ``model``); ``sign`` None: the
    better of both signs.

    Returns
    -------
    list of (Model, ndarray)
        ``[(model of that sign, full vector)]``.
    """
    fit = fit_least_squares(
        work.record, model_e, noise=work.noise, n_starts=n_starts, n_polish=1, rng=rng, threshold_sign=sign or "auto"
    )
    return [(fit.model, np.asarray(fit.theta, dtype=float))]


def working_chi2(work: Working, model_e: Model, theta) -> float:
    """Whitened chi-square of ``model_e`` at full vector ``theta`` on the working copy."""
    residuals = WhitenedResiduals(work.record, model_e, work.noise)
    w = residuals(np.asarray(theta, dtype=float)[residuals.free])
    return float(w @ w)
