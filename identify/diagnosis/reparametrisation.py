"""Candidates that are exact reparametrisations of the model: they can explain nothing.

A part of an effect whose every setting the model's own parameters reproduce exactly adds no
freedom: a refit that "wins" with it only credits it with the optimiser's failure to find the
equivalent plain fit. :data:`GPI_EQUIVALENTS` maps such parts back to the model; the diagnosis
checks the claim numerically on the record (:func:`exact_reparametrisation`), lists the
candidate as not identifiable, and uses the extra direction only as a path for the baseline's
optimiser (:func:`through_reparametrisation`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from model import READINGS, Model, envelope, get_effect

from .fits import embed

__all__ = ["GPI_EQUIVALENTS", "REPARAMETRISED_PARAMETERS", "exact_reparametrisation", "through_reparametrisation"]


def _initial_state_as_envelope_offset(model_e: Model, theta_e, time, current) -> np.ndarray:
    r"""``initial_state``'s level folded into the GPI's offsets: the same output with the effect off.

    Only the level: the prior excursion must be off (it moves some operators and not
    others, which no offset does). A held memory (``initial_state_held``, ``_slope``) is
    carried along unchanged: it is added after the clamp, which the shift moves by
    :math:`s` like every bound.

    The operators' initial memory :math:`z_j(t_0) = \max(L_j, \min(U_j, z^0))`, with
    :math:`L_j = \gamma_\uparrow(v_0) - r_j`, :math:`U_j = \gamma_\downarrow(v_0) + r_j`, and
    every later memory update are clamps against the two envelopes. Shifting both envelope
    offsets (``a3``, ``b3``) by :math:`s` shifts every bound, hence every memory value, by
    :math:`s`, and the output by :math:`s P`, :math:`P = \sum_j p_j`; lowering both
    :math:`\Omega` offsets (``c3``, ``d3``) by :math:`s P` cancels that. With
    :math:`s = -\mathrm{clip}(z^0, \min_j L_j, \max_j U_j)` the initial level becomes 0,
    the plain GPI's. So a constant initial memory level is *exactly* the plain GPI with
    other offsets, on every input (the clip only drops levels beyond every bound, which
    clamp alike).

    Parameters
    ----------
    model_e : Model
        A model containing ``initial_state`` (any other effects).
    theta_e : ndarray, shape (P,)
        Its full parameter vector.
    time, current : ndarray, shape (T,)
        The record's time [s] and drive [A] (the drive at ``t_0`` sets the bounds).

    Returns
    -------
    ndarray, shape (P,)
        ``theta_e`` with ``initial_state`` off and the four offsets moved.
    """
    theta = np.array(theta_e, dtype=float)
    names = model_e.names
    excursion = float(theta[names.index("initial_state_excursion")])
    if excursion != 0.0:
        raise ValueError(
            f"initial_state_excursion = {excursion:.4g} A: a prior excursion is not a shift of the offsets; "
            "only the level (initial_state_memory) folds into them"
        )
    drive = np.asarray(current, dtype=float)
    for effect in model_e.effects:
        if effect.stage == "input":
            params = theta[None, model_e.effect_slice(effect.name)]
            drive = np.asarray(effect.drive(params, time, drive), dtype=float)[0]
    v0 = float(np.ravel(drive)[0])
    rising_is_a = READINGS[model_e.reading]
    a_env = float(envelope(theta[3:7], v0))
    b_env = float(envelope(theta[7:11], v0))
    rising, falling = (a_env, b_env) if rising_is_a else (b_env, a_env)
    thresholds = theta[0] * np.arange(1, model_e.n_operators + 1)
    weights_sum = float(np.sum(theta[1] * np.exp(-theta[2] * thresholds)))
    lower, upper = rising - thresholds, falling + thresholds
    low, high = float(lower.min()), float(upper.max())
    z0_column = names.index("initial_state_memory")
    level = min(max(float(theta[z0_column]), low), max(high, low))
    shift = -level
    for offset in ("a3", "b3"):
        theta[names.index(offset)] += shift
    for offset in ("c3", "d3"):
        theta[names.index(offset)] -= shift * weights_sum
    theta[z0_column] = float(get_effect("initial_state").off["initial_state_memory"])
    return theta


#: effect name -> callable(model_e, theta_e, time, current) returning a full vector of
#: ``model_e`` with the effect off and the same output, for the effect's parameters in
#: :data:`REPARAMETRISED_PARAMETERS` (its others off): the parts of effects that are exact
#: reparametrisations of the GPI (:func:`exact_reparametrisation` checks the claim
#: numerically on the record before the diagnosis relies on it).
GPI_EQUIVALENTS: dict[str, Callable] = {"initial_state": _initial_state_as_envelope_offset}


#: effect name -> the parameters :data:`GPI_EQUIVALENTS` folds into the GPI (``initial_state``:
#: the level, pinned by default; its prior excursion is a candidate like any effect)
REPARAMETRISED_PARAMETERS: dict[str, tuple[str, ...]] = {"initial_state": ("initial_state_memory",)}


def through_reparametrisation(model: Model, effect_name: str) -> Model:
    """``model + effect_name`` with only the parameters :data:`GPI_EQUIVALENTS` folds away
    free, the effect's other parameters pinned off: a path for the baseline's optimiser
    (:func:`identify.diagnosis.search.reparametrisation_paths`)."""
    model_e = model + effect_name
    effect = get_effect(effect_name)
    parameters = model_e.parameters
    for parameter in effect.parameters:
        if parameter.name in REPARAMETRISED_PARAMETERS[effect_name]:
            parameters = parameters.replace(parameter.name, vary=True)
        else:
            parameters = parameters.replace(parameter.name, value=float(effect.off[parameter.name]), vary=False)
    return model_e.with_parameters(parameters)


def exact_reparametrisation(record, model: Model, theta, effect_name: str, rtol: float = 1e-9) -> bool:
    """Is adding ``effect_name`` to ``model`` an exact reparametrisation on this record?

    True when :data:`GPI_EQUIVALENTS` has a map for the effect that covers all its
    parameters (:data:`REPARAMETRISED_PARAMETERS`) and, at the effect's
    parameters spread over their bounds (lower, upper, a quarter of the way in from each,
    the test setting) around ``theta``, the mapped vector with the effect off lies within
    the model's bounds and reproduces the output to ``rtol`` of its range.
    Such a candidate can explain nothing the model cannot: the diagnosis reports it as not
    identifiable instead of refitting it (a refit that "wins" would only credit it with
    the optimiser's failure to find the equivalent plain fit).

    Parameters
    ----------
    record : Record
        ``time`` [s], ``current`` [A], shape (T,).
    model : Model
        The model without the effect.
    theta : ndarray, shape (P,)
        A full vector of ``model`` (e.g. the baseline fit).
    effect_name : str
    rtol : float, default 1e-9
        Tolerance relative to the output's range (round-off of the shifted offsets).

    Returns
    -------
    bool
    """
    if effect_name not in GPI_EQUIVALENTS:
        return False
    effect = get_effect(effect_name)
    if set(effect.parameters.names) - set(REPARAMETRISED_PARAMETERS[effect_name]):
        return False  # a part the map does not cover (initial_state's prior excursion)
    model_e = model + effect_name
    if not all(model_e.parameters[name].vary for name in ("a3", "b3", "c3", "d3")):
        return False
    base = embed(model, theta, model_e)
    rows, mapped = [], []
    for parameter in effect.parameters:
        lo, hi = float(parameter.lower), float(parameter.upper)
        values = [
            lo,
            hi,
            lo + 0.25 * (hi - lo),
            hi - 0.25 * (hi - lo),
            effect.get_test_parameters().get(parameter.name, lo),
        ]
        for value in values:
            theta_e = base.copy()
            theta_e[model_e.names.index(parameter.name)] = value
            rows.append(theta_e)
            mapped.append(GPI_EQUIVALENTS[effect_name](model_e, theta_e, record.time, record.current))
    rows, mapped = np.array(rows), np.array(mapped)
    if not (model_e.in_bounds(rows).all() and model_e.in_bounds(mapped).all()):
        return False
    y, valid = model_e.evaluate(np.vstack([rows, mapped]), record.time, record.current)
    if not valid.all():
        return False
    half = len(rows)
    scale = max(float(np.ptp(y[:half])), 1e-300)
    return bool(np.max(np.abs(y[:half] - y[half:])) <= rtol * scale)
