"""The least squares' multi-start list (:func:`candidate_starts`): Table 1, Table 1 rescaled to
the record, the classical-PI-like start for positive thresholds, and perturbed copies of the
best of them, each inside the bounds with a finite model output.

The starts are described in :mod:`identify.fitting.lsq`'s docstring, "Starts"; the search
from them is :func:`identify.fitting.lsq.fit_least_squares`.
"""

from __future__ import annotations

import math

import numpy as np

from model import GPI_PARAMETERS, THETA_NAMES, Model

from .lsq_result import SLOPE_NAMES
from .parametrisation import gpi_scaling, record_unit_factors

__all__ = ["candidate_starts", "PAPER_PEAK_INPUT", "TABLE1_N_OPERATORS"]

#: Peak drive of the paper's record [A]; the input scale of the data-driven start.
PAPER_PEAK_INPUT = 5.0
#: Operators of Table 1's fit (the paper's N); Table-1-shaped starts for another N are rescaled.
TABLE1_N_OPERATORS = 12


def _rescaled_to_operators(theta: np.ndarray, model: Model) -> np.ndarray:
    """A Table-1-shaped ``theta`` (made for :data:`TABLE1_N_OPERATORS` operators) for ``model.n_operators``.

    The ``N`` operators keep the 12 operators' threshold range and total weight:
    ``alpha`` and ``rho`` times ``12 / N`` (a finer discretisation of the same density
    ``p(r)``). When ``alpha`` is pinned (the normalisation), the exact scaling (k = N / 12,
    :func:`identify.fitting.parametrisation.gpi_scaling`) then brings it back to its pinned value:
    ``rho`` times ``(12/N)**2``, ``tau`` times ``12/N``, ``a0, a3, b0, b3`` times ``N/12``.
    The output is unchanged up to the discretisation of the density. Returns a new
    array, shape (P,); ``theta`` itself when ``N`` is 12.
    """
    n_operators = model.n_operators
    if n_operators == TABLE1_N_OPERATORS:
        return theta
    ratio = TABLE1_N_OPERATORS / n_operators
    i_alpha, i_rho = THETA_NAMES.index("alpha"), THETA_NAMES.index("rho")
    out = np.array(theta, dtype=float)
    out[i_alpha] *= ratio
    out[i_rho] *= ratio
    if not model.parameters["alpha"].vary:
        out = gpi_scaling(out, 1.0 / ratio)
        out[i_alpha] = theta[i_alpha]  # exactly the pinned value
    return out


def _table1_theta(model: Model) -> np.ndarray:
    """Table 1 (with the model's pinned alpha and effects off), for ``model.n_operators``."""
    return _rescaled_to_operators(model.default_theta(), model)


def _data_scaled_theta(record, model: Model) -> np.ndarray | None:
    """Table 1 rescaled to the record's input and output ranges (see module docstring)."""
    theta = _table1_theta(model)
    names = model.names
    peak = float(np.max(np.abs(record.current)))
    if not peak > 0:
        return None
    # the model's default slopes are already per the record's input unit prefix (in_record_units)
    input_scale = peak / PAPER_PEAK_INPUT / record_unit_factors(record)[0]
    for n in SLOPE_NAMES:
        i = names.index(n)
        if model.parameters[i].vary:
            theta[i] = theta[i] / input_scale
    return _fit_gain_and_offset(record, model, theta)


def _fit_gain_and_offset(record, model: Model, theta: np.ndarray) -> np.ndarray | None:
    """Scale ``rho, c0, c3, d0, d3`` and shift ``c3, d3`` so the prediction best matches the data
    in linear least squares; None when the output is not finite or the gain is not > 0."""
    names = model.names
    theta = np.clip(theta, model.parameters.lower, model.parameters.upper)
    y, valid = model.evaluate(theta, record.time, record.current)
    if not valid[0]:
        return None
    design = np.column_stack([np.ones(y.shape[1]), y[0]])
    (offset, gain), *_ = np.linalg.lstsq(design, record.displacement, rcond=None)
    if not (np.isfinite(gain) and gain > 0):
        return None
    for n in ("rho", "c0", "c3", "d0", "d3"):
        theta[names.index(n)] *= gain
    for n in ("c3", "d3"):
        theta[names.index(n)] += offset
    return np.clip(theta, model.parameters.lower, model.parameters.upper)


def _classical_theta(record, model: Model) -> np.ndarray | None:
    """Start for positive thresholds: identical mildly saturating envelopes (module docstring)."""
    names = model.names
    alpha = model.parameters["alpha"].value
    peak = float(np.max(np.abs(record.current)))
    if not (alpha > 0 and peak > 0):
        return None
    theta = model.default_theta()
    scale = alpha / abs(float(GPI_PARAMETERS["alpha"].value))  # envelopes scale with |alpha|
    values = {"rho": 1.0 / scale, "tau": 0.5 / scale}
    for branch in ("a", "b"):
        values.update({f"{branch}0": 3.0 * scale, f"{branch}1": 0.5 / peak, f"{branch}2": 0.0, f"{branch}3": 0.0})
    for branch in ("c", "d"):
        values.update({f"{branch}0": 1.0, f"{branch}1": 1.0 / peak, f"{branch}2": 0.0, f"{branch}3": 0.0})
    for n, v in values.items():
        i = names.index(n)
        if model.parameters[i].vary:
            theta[i] = v
    return _fit_gain_and_offset(record, model, _rescaled_to_operators(theta, model))


def _is_time_constant(parameter) -> bool:
    return parameter.unit == "s" and parameter.upper > 0


def _perturbed_theta(base: np.ndarray, model: Model, rng: np.random.Generator, spread: float) -> np.ndarray:
    theta = base.copy()
    n_gpi = len(THETA_NAMES)
    lower, upper = model.parameters.lower, model.parameters.upper
    for i, p in enumerate(model.parameters):
        if not p.vary:
            continue
        z = rng.standard_normal()
        if i < n_gpi:
            theta[i] = base[i] * math.exp(spread * z)
        elif _is_time_constant(p):
            lo = max(p.lower, 1e-3 * p.upper)
            theta[i] = math.exp(rng.uniform(math.log(lo), math.log(p.upper)))
        else:
            width = (p.upper - p.lower) if np.isfinite(p.upper - p.lower) else 1.0
            theta[i] = base[i] + 0.01 * width * z
    return np.clip(theta, lower, upper)


def candidate_starts(record, model: Model, *, n_starts=8, rng=None, start=None) -> list[tuple[str, np.ndarray]]:
    """The multi-start list ``[(label, theta), ...]`` (full vectors within the bounds, finite output).

    Parameters
    ----------
    record : Record
    model : model.Model
    n_starts : int, default 8
        Total number of starts (deterministic ones first, then rng-perturbed).
    rng : numpy.random.Generator, optional
        Default ``numpy.random.default_rng(0)``.
    start : array_like, shape (P,), optional
        A user start, tried first.
    """
    if isinstance(n_starts, bool) or not isinstance(n_starts, (int, np.integer)) or n_starts < 1:
        raise ValueError(f"n_starts must be an integer >= 1, got {n_starts!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    pinned = ~model.parameters.vary
    template = model.parameters.values

    def valid(theta):
        if not model.in_bounds(theta)[0]:
            return False
        return bool(model.evaluate(theta, record.time, record.current)[1][0])

    starts: list[tuple[str, np.ndarray]] = []
    if start is not None:
        theta = np.asarray(start, dtype=float)
        if theta.shape != (model.n_parameters,):
            raise ValueError(f"start must have shape ({model.n_parameters},) for {model!r}, got {theta.shape}")
        theta = np.where(pinned, template, theta)
        if not valid(theta):
            raise ValueError("the given start lies outside the parameter bounds or gives a non-finite model output")
        starts.append(("user", theta))
    if getattr(record, "input_unit", "A") == "A" and getattr(record, "output_unit", "um") == "um":
        theta = np.clip(_table1_theta(model), model.parameters.lower, model.parameters.upper)
        if valid(theta):
            starts.append(("table1", theta))
    scaled = _data_scaled_theta(record, model)
    if scaled is not None and valid(scaled):
        starts.append(("data_scaled", scaled))
    classical = _classical_theta(record, model)
    if classical is not None and valid(classical):
        starts.append(("classical", classical))
        scaled = classical
    if not starts:
        raise ValueError(
            "no valid least-squares start: Table 1 (rescaled to the record) gives a non-finite model "
            "output on this input; pass an explicit start"
        )
    base = starts[-1][1] if scaled is not None else starts[0][1]
    starts = starts[:n_starts]
    k = 0
    while len(starts) < n_starts:
        spread = 0.15
        for _attempt in range(50):
            theta = _perturbed_theta(base, model, rng, spread)
            if valid(theta):
                break
            spread *= 0.8
        else:
            theta = None
        k += 1
        if theta is not None:
            starts.append((f"perturbed-{k}", theta))
        if k > 4 * n_starts:
            break
    return starts
