"""The log-posterior's per-row prior work and the snooker move's arithmetic in compiled passes.

:class:`identify.fitting.posterior.LogPosterior` is called two to four times per sampler step
with a few dozen rows. In array code, the support test, the built-in priors and the full
parameter vectors of the rows inside the support are a dozen small NumPy calls, about 20 us a
call (a few per cent of the sampling time on a 7001-sample record). Here they are one pass
over the rows. The values are the array code's: the same operations in the same order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def support_prior_theta(x, lower, upper, constant, log_uniform, template, free):
    """The rows of ``x`` inside the box support, their log prior and their full parameter vectors.

    Parameters
    ----------
    x : ndarray, shape (W, D)
        Sampled coordinates.
    lower, upper : ndarray, shape (D,)
        The finite box support; a row with a value outside it, or NaN, is out.
    constant : float
        The log prior's constant (every built-in prior's normalisation).
    log_uniform : ndarray of int, shape (L,)
        Columns whose prior is log-uniform: ``log x`` is subtracted, summed in column order.
    template : ndarray, shape (P,)
        The model's parameter vector (pinned values).
    free : ndarray of int, shape (F,)
        Where the first F coordinates go in the parameter vector.

    Returns
    -------
    prior : ndarray, shape (R,)
        ``constant - sum(log x[log_uniform])`` of each row inside.
    inside : ndarray of int, shape (R,)
        The rows inside, in order.
    theta : ndarray, shape (R, P)
        Their parameter vectors.
    """
    n_rows, n_dim = x.shape
    prior = np.empty(n_rows)
    inside = np.empty(n_rows, dtype=np.int64)
    count = 0
    for i in range(n_rows):
        ok = True
        for j in range(n_dim):
            value = x[i, j]
            if not (value >= lower[j] and value <= upper[j]):
                ok = False
                break
        if ok:
            logs = 0.0
            for c in log_uniform:
                logs += math.log(x[i, c])
            prior[count] = constant - logs
            inside[count] = i
            count += 1
    theta = np.empty((count, template.shape[0]))
    for r in range(count):
        theta[r, :] = template
        for k in range(free.shape[0]):
            theta[r, free[k]] = x[inside[r], k]
    return prior[:count], inside[:count], theta


@njit(cache=True)
def _order_of_three(keys):
    """``np.argsort(keys)`` of three distinct values: the indices from the smallest."""
    a, b, c = keys[0], keys[1], keys[2]
    if a < b:
        if b < c:
            return 0, 1, 2
        return (0, 2, 1) if a < c else (2, 0, 1)
    if a < c:
        return 1, 0, 2
    return (1, 2, 0) if b < c else (2, 1, 0)


@njit(cache=True)
def snooker_proposals(s, c0, c1, c2, picks, keys, gamma, proposal, log_factor):
    """The snooker update of :class:`identify.fitting.moves.SnookerMove` for every walker.

    Parameters
    ----------
    s : ndarray, shape (n, D)
        The walkers.
    c0, c1, c2 : ndarray, shape (m_j, D)
        The other three splits' walkers.
    picks : ndarray of int, shape (n, 3)
        Each walker's row of ``c0``, ``c1`` and ``c2`` (drawn by the move).
    keys : ndarray, shape (n, 3)
        Uniform draws whose order (:func:`numpy.argsort`'s) assigns the roles: ``z``, ``z1``,
        ``z2`` are the picks of the groups with the smallest, middle and largest key.
    gamma : float
    proposal : ndarray, shape (n, D)
        Out: ``x + gamma e e^T (z1 - z2)`` with ``e = (x - z) / |x - z|``.
    log_factor : ndarray, shape (n,)
        Out: ``(D - 1) log(|x' - z| / |x - z|)``.
    """
    n, d = s.shape
    for i in range(n):
        chosen = (c0[picks[i, 0]], c1[picks[i, 1]], c2[picks[i, 2]])
        first, second, third = _order_of_three(keys[i])
        z = chosen[first]
        z1 = chosen[second]
        z2 = chosen[third]
        distance = 0.0
        for k in range(d):
            distance += (s[i, k] - z[k]) ** 2
        distance = math.sqrt(distance)
        along = 0.0
        for k in range(d):
            along += (s[i, k] - z[k]) / distance * (z1[k] - z2[k])
        step = gamma * along
        moved = 0.0
        for k in range(d):
            unit = (s[i, k] - z[k]) / distance
            proposal[i, k] = s[i, k] + unit * step
            moved += (proposal[i, k] - z[k]) ** 2
        log_factor[i] = (d - 1.0) * (math.log(math.sqrt(moved)) - math.log(distance))
