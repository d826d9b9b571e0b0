"""A rival's chance before a name: a candidate the search did not finish, started where it
reproduces what the named explanation predicts.

The search finishes the candidates that its screening and short refits find promising. A
screening is a local look around the baseline; an effect whose correction is far from the
baseline in its own parameters (a heating through two nodes of opposite sign, say) can
look useless there and still reproduce, once fitted, what another effect explains. A name
says the data prefer one physics to every other, so every other candidate must have been
fitted, from a start that gives it the named explanation's correction if it can make it:
its own parameters fitted to the named explanation's model output (the GPI held at the
named fit's), then refitted on the data as any candidate.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from model import Model, get_effect

from ..fitting.lapack import release_the_gil_in_least_squares
from .fits import embed, same_threshold_sign, with_values

__all__ = ["mimic_start"]

#: Solver evaluations of the fit to the named explanation's output (the candidate's own few
#: parameters on the working copy; a start, not a result: the refit on the data follows).
MIMIC_EVALUATIONS = 200
#: Starts solved from: the lowest in output distance of the defaults and the given ones.
MIMIC_STARTS = 3


def mimic_start(
    named_model: Model, named_theta, model_e: Model, name: str, time, current, starts=()
) -> np.ndarray | None:
    """A full vector of ``model_e`` (the baseline plus candidate ``name``) whose output is closest
    to the named explanation's on ``time``/``current`` (the working copy), or None.

    Parameters
    ----------
    named_model : Model
        The named explanation's model (the baseline with the named effect or pair).
    named_theta : ndarray, shape (P_named,)
        Its fitted full vector.
    model_e : Model
        The baseline with candidate ``name``; must pin the named fit's threshold sign.
    name : str
        The candidate effect.
    time, current : ndarray, shape (T,)
        [s], [A] of the working copy.
    starts : sequence of dict, optional
        ``{parameter: value}`` of the candidate's own parameters to start from, beside its
        defaults.

    Returns
    -------
    ndarray, shape (P_e,) or None
        None where the signs differ or no start gives a finite output.
    """
    if not same_threshold_sign(named_model, model_e):
        return None
    target = np.asarray(named_model(np.asarray(named_theta, dtype=float), time, current), dtype=float)
    base = embed(named_model, named_theta, model_e, drop_extra=True)
    own = [n for n in get_effect(name).parameters.names if model_e.parameters[n].vary]  # a pinned one stays
    index = [model_e.names.index(n) for n in own]
    lower = np.array([model_e.parameters[n].lower for n in own])
    upper = np.array([model_e.parameters[n].upper for n in own])
    scale = max(float(np.ptp(target)), 1e-300)

    def residual(x):
        theta = base.copy()
        theta[index] = x
        out = np.asarray(model_e(theta, time, current), dtype=float)
        return np.where(np.isfinite(out), (out - target) / scale, 1e3)

    inside = 1e-9 * (upper - lower)
    x0s = np.array(
        [np.clip(with_values(model_e, base, v)[index], lower + inside, upper - inside) for v in [{}, *starts]]
    )
    thetas = np.repeat(base[None, :], len(x0s), axis=0)
    thetas[:, index] = x0s
    outputs = np.asarray(model_e(thetas, time, current), dtype=float)
    first_costs = np.where(np.all(np.isfinite(outputs), axis=1), np.sum((outputs - target) ** 2, axis=1), np.inf)
    best, best_cost = None, np.inf
    release_the_gil_in_least_squares()
    for i in np.argsort(first_costs, kind="stable")[:MIMIC_STARTS]:
        if not np.isfinite(first_costs[i]):
            continue
        try:
            sol = least_squares(residual, x0s[i], bounds=(lower, upper), max_nfev=MIMIC_EVALUATIONS, x_scale="jac")
        except (ValueError, ArithmeticError):
            continue
        if np.isfinite(sol.cost) and sol.cost < best_cost:
            best_cost, best = float(sol.cost), sol.x
    if best is None:
        return None
    theta = base.copy()
    theta[index] = best
    return theta
