"""Screening: a linearised score of every candidate effect at the baseline's optimum.

For every library effect not in the model, its parameters are put on a small grid
(:func:`screening_grid`): parameters that do nothing while the effect is off (time constants,
spectrum widths, shapes) and parameters the output depends on nonlinearly get grid values;
parameters the output depends on linearly (amplitudes) stay off and enter through their
Jacobian columns. At each grid point the whitened residual is projected out of the span of
the model's own Jacobian columns and the effect's columns are fitted to what remains by
bounded linear least squares (an amplitude bounded at 0 cannot explain a residual of the
wrong sign). The score is the predicted drop of the chi-square, best over the grid: a score
test with a grid over the nonlinear parameters. The grid is generic (from the parameters'
units, bounds and a numerical probe), so an effect added to the library is screened with no
code here; :data:`SCREENING_GRIDS` overrides it where an effect's parts enter one at a time.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from model import EFFECTS, Model, get_effect

from ..fitting.lsq import FitResult, WhitenedResiduals
from ..fitting.noise import NoiseModel
from ..fitting.threads import single_threaded_blas
from .fits import embed, with_values

__all__ = [
    "SCREENING_GRIDS",
    "ScreeningResult",
    "screening_grid",
    "screen_one",
    "screen_candidates",
    "probe_change",
    "acts",
]


def _training_grid(model_e: Model, record) -> list[dict]:
    """Screening grid of ``training``: its amplitudes off, its fade on a grid.

    The deficit ``g``, threshold ``F``, width ``w`` and strain gain ``s`` stay off and enter
    through their Jacobian columns (the drive, the thresholds and the output change smoothly
    with them near 0; the screening's bounded fit takes the signs of ``g``, ``w`` and ``s``
    and keeps ``F >= 0``). The
    fade's travel scale ``V0`` and shape ``p`` do nothing while the amplitudes are 0, and
    the generic rule would spread them over a product grid thinned to a few points; here
    ``V0`` is log-spaced over 1/50 of the record's total drive travel to the whole of it
    (clipped to the bounds: on the paper's 47.5 A, 0.95-47.5 A) and ``p`` takes 1
    (exponential), 3 and 8 (nearly a step at ``V0``), 15 points: differently shaped fades
    (a linear one, a step at the first reversal, one still going on at the record's end)
    start near their best fit.
    """
    effect = get_effect("training")
    names = effect.parameters.names
    params = {n: model_e.parameters[n] for n in names}
    total = float(np.sum(np.abs(np.diff(record.current))))
    scale = params["training_travel"]
    low = min(max(scale.lower, total / 50.0), scale.upper)
    high = max(min(scale.upper, total), low)
    off = {n: float(effect.off[n]) for n in names}
    points = [off]
    for travel in np.geomspace(low, high, 5) if high > low else [low]:
        for shape in (1.0, 3.0, 8.0):
            shape = min(max(shape, params["training_shape"].lower), params["training_shape"].upper)
            point = off | {"training_travel": float(travel), "training_shape": float(shape)}
            if point not in points:
                points.append(point)
    return points


#: Values of ``initial_state``'s prior excursion per play operator over the drive's range above
#: its first value (half as many below): its objective changes only where the excursion's envelope
#: passes an operator's memory, so the grid must fall between every two such places.
EXCURSION_VALUES_PER_OPERATOR = 4


def _initial_state_grid(model_e: Model, record) -> list[dict]:
    """Screening grid of ``initial_state``: each part of the history on its own axis.

    The prior excursion ``e`` acts through the rising envelope at :math:`v_0 + e` (the
    falling one for :math:`e < 0`), which moves within the drive's range and saturates
    beyond it; the memories it leaves change steeply where that envelope passes them and
    not at all in between. So ``e`` takes 12 values evenly over the drive's range above
    :math:`v_0` and 6 over the range below it (where the record starts at its lowest or
    highest drive: 2 %, 10 % and 50 % of the half-range beyond it); the held memory's level
    ``h`` and slope ``s`` take 2 %, 10 % and 50 % of their half-range, both signs (6 each);
    the other parts off, the pinned level where it is. A product of the three axes thinned
    to the generic cap of 24 would keep two values of each, all of one sign: here the parts
    of a history enter one at a time, and the short refits then move them together.
    """
    effect = get_effect("initial_state")
    names = effect.parameters.names
    off = {n: float(effect.off[n]) for n in names}
    current = np.asarray(record.current, dtype=float)
    v0 = float(current[0])
    above, below = float(current.max()) - v0, v0 - float(current.min())
    points = [off]
    for name in ("initial_state_excursion", "initial_state_held", "initial_state_held_slope"):
        parameter = model_e.parameters[name]
        if not parameter.vary:
            continue
        half = 0.5 * (float(parameter.upper) - float(parameter.lower))
        beyond = [size * half for size in (0.02, 0.1, 0.5)]
        if name == "initial_state_excursion":
            per = EXCURSION_VALUES_PER_OPERATOR * model_e.n_operators
            up = list(np.linspace(0.0, above, per + 1)[1:]) if above > 0 else beyond
            down = list(np.linspace(0.0, below, per // 2 + 1)[1:]) if below > 0 else beyond
            values = [off[name] + e for e in up] + [off[name] - e for e in down]
        else:
            values = [off[name] + sign * size for size in beyond for sign in (-1.0, 1.0)]
        for value in values:
            point = off | {name: float(min(max(value, parameter.lower), parameter.upper))}
            if point not in points:
                points.append(point)
    return points


#: ``incomplete_reset``'s virgin-loading shapes on its screening grid beside the strain-proportional
#: form: ``(drive share m, shape p, onset c, sharpness k)``, front-loaded (p < 1), late (p > 1),
#: set by the drive (m = 1), and setting in with a step in the drive at a low, middle and high
#: level (k = 10: over about a fifth of the range). The step's sharpness has no slope at k = 0
#: (the level's first change is of order k^2), so only the grid can start it.
INCOMPLETE_RESET_SHAPES = (
    (0.0, 0.4, 0.5, 0.0),
    (0.0, 2.5, 0.5, 0.0),
    (1.0, 0.4, 0.5, 0.0),
    (1.0, 1.0, 0.5, 0.0),
    (1.0, 2.5, 0.5, 0.0),
    (1.0, 1.0, 0.3, 10.0),
    (1.0, 1.0, 0.5, 10.0),
    (1.0, 1.0, 0.7, 10.0),
)


#: ``incomplete_reset``'s stroke shares b on its screening grid (the retained strain keeps the top
#: of the later strokes where it was at b = 1, lowers it at b = 2): nothing moves b while A = 0.
INCOMPLETE_RESET_STROKES = (1.0, 2.0)


def _incomplete_reset_grid(model_e: Model, record) -> list[dict]:
    """Screening grid of ``incomplete_reset``: the strain-proportional form's grid, then the
    virgin loading's other shapes.

    The strain ``A`` stays off and enters through its Jacobian column; the retained fraction
    ``R``, the fade, the drive share ``m`` and the shape ``p`` do nothing while ``A = 0``,
    so only the grid gives them values. First the grid the generic rule gave the
    strain-proportional form (``m = 0``, ``p = 1``, no step): ``R`` at 0, the middle and the
    top of its range, the fade at five values over its range (15 points, the same order);
    then the retained strain narrowing the later strokes (:data:`INCOMPLETE_RESET_STROKES`,
    at each ``R`` above 0, no fade); then each shape of :data:`INCOMPLETE_RESET_SHAPES` with
    ``R`` at the same three values and no fade (24 points). The generic rule over all four
    would thin ``R`` to its two ends and miss ``p = 1``. A pinned parameter keeps its value
    (a shape that needs it moved is left out); the short refits move them together.
    """
    effect = get_effect("incomplete_reset")
    names = effect.parameters.names
    params = {n: model_e.parameters[n] for n in names}
    off = {n: float(effect.off[n]) if params[n].vary else float(params[n].value) for n in names}

    def spread(name, count):
        parameter = params[name]
        if not parameter.vary:
            return [off[name]]
        return [float(v) for v in np.linspace(parameter.lower, parameter.upper, count)]

    retained = spread("incomplete_reset_retained", 5)[::2]
    points = [off]
    for r in retained:
        for fade in spread("incomplete_reset_fade", 5):
            point = off | {"incomplete_reset_retained": r, "incomplete_reset_fade": fade}
            if point not in points:
                points.append(point)
    b = params["incomplete_reset_stroke"]
    strokes = [v for v in INCOMPLETE_RESET_STROKES if b.vary and b.lower <= v <= b.upper]
    for r in (r for r in retained if r > 0.0):  # nothing is retained at R = 0: no stroke to narrow
        for stroke in strokes:
            point = off | {"incomplete_reset_retained": r, "incomplete_reset_stroke": stroke}
            if point not in points:
                points.append(point)
    for share, shape, onset, sharpness in INCOMPLETE_RESET_SHAPES:
        values = {
            "incomplete_reset_drive": share,
            "incomplete_reset_shape": shape,
            "incomplete_reset_onset": onset,
            "incomplete_reset_sharpness": sharpness,
        }
        if any(
            (not params[n].vary and v != off[n]) or not params[n].lower <= v <= params[n].upper
            for n, v in values.items()
        ):
            continue
        for r in retained:
            point = off | values | {"incomplete_reset_retained": r}
            if point not in points:
                points.append(point)
    return points


#: effect name -> callable(model_with_effect, record) returning a list of {parameter: value}
#: grid points, the "off" point first; effects not listed use :func:`screening_grid`'s
#: generic rule.
SCREENING_GRIDS: dict[str, Callable] = {
    "training": _training_grid,
    "initial_state": _initial_state_grid,
    "incomplete_reset": _incomplete_reset_grid,
}


_MAX_GRID = 24


def _is_log_scale(parameter) -> bool:
    return parameter.unit == "s"


def _axis_values(parameter, off_value, record_time, n_values, include_off):
    """Grid values of one parameter: log-spaced for time constants, else spread around ``off``."""
    lo, hi = float(parameter.lower), float(parameter.upper)
    if _is_log_scale(parameter):
        dt = float(np.median(np.diff(record_time)))
        duration = float(record_time[-1] - record_time[0])
        start = max(lo, 2.0 * dt) if lo <= 0 else lo
        stop = min(hi, 10.0 * duration)
        if stop <= start:
            stop = hi
        values = list(np.geomspace(start, stop, n_values)) if stop > start > 0 else [start]
    elif not include_off:  # a shape parameter: spread over its range
        values = list(np.linspace(lo, hi, n_values)) if np.isfinite(hi - lo) else [off_value]
    else:
        half = 0.5 * (hi - lo)
        values = []
        for fraction in np.geomspace(0.02, 1.0, n_values + 1):
            for sign in (-1.0, 1.0):
                v = off_value + sign * fraction * half
                if lo <= v <= hi:
                    values.append(v)
    if include_off:
        values = [off_value] + [v for v in values if v != off_value]
    return values


def probe_change(model_e: Model, base_theta, column, record):
    """``(probe, change)``: the parameter in ``column`` moved by 5 % of its range from its value
    in ``base_theta`` (downward at the upper bound) and the model's output change on ``record``
    (None where an output is not finite)."""
    parameter = model_e.parameters[column]
    value = float(base_theta[column])
    span = parameter.upper - parameter.lower
    step = 0.05 * span if np.isfinite(span) else 0.05 * max(abs(value), 1.0)
    probe = value + step if value + step <= parameter.upper else value - step
    return probe, _response_change(model_e, base_theta, column, probe, record)


def acts(change) -> bool:
    """Whether a probed output change (:func:`probe_change`) is more than rounding."""
    return change is not None and float(np.max(np.abs(change))) > 1e-9


def _response_change(model_e: Model, base_theta, column, value, record):
    theta = base_theta.copy()
    theta[column] = value
    y, valid = model_e.evaluate(np.vstack([base_theta, theta]), record.time, record.current)
    if not valid.all():
        return None
    return y[1] - y[0]


def screening_grid(model_e: Model, effect_name: str, base_theta, record, n_values=5) -> list[dict]:
    """Generic screening grid of one effect's parameters (see the module docstring).

    Parameters
    ----------
    model_e : Model
        The model with the effect added.
    effect_name : str
    base_theta : ndarray, shape (P,)
        Full vector of ``model_e`` with the effect off.
    record : Record
    n_values : int, default 5
        Values per gridded parameter (the product is capped at 24 points).

    Returns
    -------
    list of dict
        ``{parameter: value}`` grid points (the effect's parameters only); the first
        is the "off" point.
    """
    if effect_name in SCREENING_GRIDS:
        return list(SCREENING_GRIDS[effect_name](model_e, record))
    effect = get_effect(effect_name)
    cols = model_e.effect_slice(effect_name)
    names = model_e.names[cols]
    axes = []
    for offset, _name in enumerate(names):
        column = cols.start + offset
        parameter = model_e.parameters[column]
        off_value = float(base_theta[column])
        if not parameter.vary:
            axes.append([off_value])
            continue
        probe, change = probe_change(model_e, base_theta, column, record)
        if not acts(change):  # a shape parameter (does nothing while the effect is off)
            axes.append(_axis_values(parameter, off_value, record.time, n_values, include_off=False))
            continue
        probe2 = off_value + 2.0 * (probe - off_value)
        linear = False
        if parameter.lower <= probe2 <= parameter.upper:
            change2 = _response_change(model_e, base_theta, column, probe2, record)
            if change2 is not None:
                scale = float(np.linalg.norm(change2))
                linear = scale > 0 and float(np.linalg.norm(change2 - 2.0 * change)) < 1e-3 * scale
        axes.append(
            [off_value] if linear else _axis_values(parameter, off_value, record.time, n_values, include_off=True)
        )
    # cap the product by thinning the longest axes
    while np.prod([len(a) for a in axes]) > _MAX_GRID:
        longest = int(np.argmax([len(a) for a in axes]))
        a = axes[longest]
        axes[longest] = a[::2] if len(a) > 2 else a[:1]
    points = [dict(zip(names, map(float, combo))) for combo in itertools.product(*axes)]
    off_point = {n: float(effect.off[n]) for n in names}
    return [off_point] + [p for p in points if p != off_point]


@dataclass(frozen=True)
class ScreeningResult:
    """Linearised score of one candidate effect.

    Attributes
    ----------
    effect : str
    chi2_drop : float
        Predicted drop of the whitened chi-square after one bounded Gauss-Newton step
        from the best grid point (0 when nothing helps).
    chi2_after : float
        Predicted chi-square after that step.
    start : ndarray, shape (P_e,)
        Full vector of the model with the effect, after the step (the refit's first start).
    grid_point : dict
        The effect parameters of the best grid point.
    n_grid : int
        Grid points tried.
    starts : list of ndarray, shape (P_e,) each
        Starts for the refit, most promising first: the best point after the step, then
        the baseline GPI with the effect's parameters moved by their part of the step
        from the best few grid points (the GPI's own step can be large along its
        near-degenerate directions, so several nearby starts are tried).
    grid : list of dict
        The grid points tried (effect parameters only).
    """

    effect: str
    chi2_drop: float
    chi2_after: float
    start: np.ndarray
    grid_point: dict[str, float]
    n_grid: int
    starts: list[np.ndarray] = field(default_factory=list)
    grid: list[dict[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "chi2_drop": float(self.chi2_drop),
            "chi2_after": float(self.chi2_after),
            "grid_point": {k: float(v) for k, v in self.grid_point.items()},
            "n_grid": int(self.n_grid),
        }


def orthonormal_basis(matrix, rtol=1e-9):
    """Orthonormal basis of the column span of ``matrix`` (T, m) by SVD, rank-revealing."""
    if matrix.shape[1] == 0:
        return np.zeros((matrix.shape[0], 0))
    u, s, _ = np.linalg.svd(matrix, full_matrices=False)
    keep = s > rtol * (s[0] if s.size else 0.0)
    return u[:, keep]


def partial_jacobian(residuals: WhitenedResiduals, x, columns) -> np.ndarray:
    """Forward-difference columns ``(T, len(columns))`` of the whitened residual, one batched call."""
    columns = np.asarray(columns, dtype=int)
    steps = np.sqrt(np.finfo(float).eps) * np.maximum(np.abs(x[columns]), 0.01)
    steps = np.where(x[columns] + steps > residuals.upper[columns], -steps, steps)
    rows = np.repeat(x[None, :], columns.size + 1, axis=0)
    rows[1 + np.arange(columns.size), columns] += steps
    w, valid = residuals.batch(rows)
    jac = np.zeros((w.shape[1], columns.size))
    for i in range(columns.size):
        if valid[0] and valid[i + 1]:
            jac[:, i] = (w[i + 1] - w[0]) / steps[i]
    return jac


def screen_one(record, model: Model, theta0, noise: NoiseModel, effect_name: str) -> ScreeningResult:
    with single_threaded_blas():  # small dense algebra: threads only compete with the model
        return _screen_one_impl(record, model, theta0, noise, effect_name)


def _bounded_step(j_perp, w_perp, lower, upper) -> np.ndarray:
    """Gauss-Newton step of the effect's parameters: ``w(x + d) ~ w + J d`` (``w`` = whitened data
    - model), minimising ``|w_perp + j_perp d|`` within the bounds ``lower <= d <= upper``, over
    the columns that act here (a time constant does nothing while its amplitude is 0)."""
    norms = np.linalg.norm(j_perp, axis=0)
    acting = norms > 1e-9 * max(float(norms.max(initial=0.0)), 1e-300)
    step = np.zeros(j_perp.shape[1])
    if acting.any():
        sol = lsq_linear(
            j_perp[:, acting] / norms[acting],
            -w_perp,
            bounds=(lower[acting] * norms[acting], upper[acting] * norms[acting]),
            method="bvls",
        )
        step[acting] = sol.x / norms[acting]
    return step


def _screen_one_impl(record, model: Model, theta0, noise: NoiseModel, effect_name: str) -> ScreeningResult:
    model_e = model + effect_name
    base = embed(model, theta0, model_e)
    cols = model_e.effect_slice(effect_name)
    residuals = WhitenedResiduals(record, model_e, noise)
    free = residuals.free
    effect_free = np.array([i for i, c in enumerate(free) if cols.start <= c < cols.stop], dtype=int)
    other_free = np.array([i for i, c in enumerate(free) if not cols.start <= c < cols.stop], dtype=int)
    grid = screening_grid(model_e, effect_name, base, record)
    x0 = base[free]
    w0 = residuals(x0)
    jac0 = residuals.jacobian(x0)
    basis0 = orthonormal_basis(jac0[:, other_free])
    w0_perp = w0 - basis0 @ (basis0.T @ w0)
    chi2_reference = float(w0_perp @ w0_perp)  # the GPI alone, linearised: what the effect must beat
    outcomes = []  # (chi2_after, x, step, point)
    for point in grid:
        theta = with_values(model_e, base, point)
        if not model_e.in_bounds(theta)[0]:
            continue
        x = theta[free]
        w, valid = residuals.batch(x[None, :])
        if not valid[0]:
            continue
        w = w[0]
        if np.array_equal(w, w0):
            # the effect is still off here (only its shape parameters moved): the GPI's
            # columns are the baseline's, only the effect's own columns are new
            jac = jac0.copy()
            jac[:, effect_free] = partial_jacobian(residuals, x, effect_free)
            basis = basis0
        else:
            jac = residuals.jacobian(x)
            basis = orthonormal_basis(jac[:, other_free])
        w_perp = w - basis @ (basis.T @ w)
        j_perp = jac[:, effect_free] - basis @ (basis.T @ jac[:, effect_free])
        lower = residuals.lower[effect_free] - x[effect_free]
        upper = np.maximum(residuals.upper[effect_free] - x[effect_free], lower + 1e-12)
        step_eff = _bounded_step(j_perp, w_perp, lower, upper)
        remaining = w_perp + j_perp @ step_eff
        chi2_after = float(remaining @ remaining)
        outcomes.append((chi2_after, x, step_eff, point, (w, jac)))
    if not outcomes:
        return ScreeningResult(effect_name, 0.0, chi2_reference, base, {}, len(grid), [base], grid)
    outcomes.sort(key=lambda o: o[0])
    chi2_after, x, step_eff, point, (w, jac) = outcomes[0]
    step = np.zeros(free.size)
    step[effect_free] = step_eff
    if other_free.size:
        # the GPI's part of the step (best point only): the least-squares response to what
        # remains, with the GPI's near-degenerate directions cut (truncated SVD)
        full_rest = w + jac[:, effect_free] @ step_eff
        step[other_free] = np.linalg.lstsq(jac[:, other_free], -full_rest, rcond=1e-6)[0]
    trials = [x + step, x + 0.5 * step, x + 0.25 * step]
    for _, xk, step_k, _, _ in outcomes[:3]:
        effect_step = np.zeros(free.size)
        effect_step[effect_free] = step_k
        trials.append(xk + effect_step)
    trials.append(x)
    trials = np.clip(np.vstack(trials), residuals.lower, residuals.upper)
    w_trials, valid = residuals.batch(trials)
    chi2_trials = np.where(valid, np.sum(w_trials**2, axis=1), np.inf)
    order = [int(i) for i in np.argsort(chi2_trials, kind="stable") if np.isfinite(chi2_trials[i])]
    starts = []
    for i in order:
        if not any(np.array_equal(trials[i], trials[j]) for j in order[: order.index(i)]):
            starts.append(residuals.full(trials[i]))
    drop = max(chi2_reference - chi2_after, 0.0)
    return ScreeningResult(effect_name, drop, float(w0 @ w0) - drop, starts[0], dict(point), len(grid), starts, grid)


def screen_candidates(record, fit: FitResult, candidates=None) -> list[ScreeningResult]:
    """Linearised screening of candidate effects at a fit's optimum, best first.

    Parameters
    ----------
    record : Record
    fit : FitResult
        The baseline fit (its model, optimum and noise model are used).
    candidates : sequence of str, optional
        Effects to screen; default every library effect not in the model.

    Returns
    -------
    list of ScreeningResult
        Sorted by ``chi2_drop``, largest first.
    """
    model = fit.model
    if candidates is None:
        candidates = [name for name in EFFECTS if name not in model.effect_names]
    results = [screen_one(record, model, fit.theta, fit.noise, name) for name in candidates]
    return sorted(results, key=lambda r: -r.chi2_drop)
