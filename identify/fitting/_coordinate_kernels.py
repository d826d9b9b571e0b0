"""The sampler-coordinate map of :class:`identify.fitting.coordinates.GPICoordinates`, row by
row in compiled loops.

The map is evaluated for every proposal of every step (a few dozen rows of a few dozen
parameters). In array code each block is a dozen small NumPy calls, and their overhead (about
0.1 ms a call of the map) is a tenth of the sampling time on a 7001-sample record; here a
call costs a few microseconds. The formulas are those of the class's docstrings.

A :class:`Layout` says where each block's parameters are (column ``-1``: pinned, the value
from ``pinned``); ``blocks`` flags ``[weights, envelope a, envelope b, omega c, omega d,
thermal node 1, thermal node 2]``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

#: Order of the flags in :attr:`Layout.blocks`.
BLOCKS = ("weights", "envelope_a", "envelope_b", "omega_c", "omega_d", "thermal", "thermal_core")


class Layout(NamedTuple):
    """Where the blocks' parameters are in a row (see the module docstring).

    Attributes
    ----------
    blocks : ndarray of bool, shape (7,)
        Which blocks of :data:`BLOCKS` are in use.
    weights : ndarray of int, shape (2,)
        Columns of ``rho`` and ``tau`` (-1: pinned).
    envelopes : ndarray of int, shape (2, 4)
        Columns of ``a0..a3`` and ``b0..b3``.
    omegas : ndarray of int, shape (2, 2)
        Columns of ``c1, c2`` and ``d1, d2``.
    thermal : ndarray of int, shape (2, 3)
        Columns of each node's time constant and its two gains (-1: pinned).
    pinned : ndarray, shape (4,)
        Values of ``rho, tau, thermal_tau, thermal_tau_core`` where pinned (NaN if unknown).
    three_values : ndarray of bool, shape (2,)
        Per envelope: its coordinates are three values and the amplitude's logarithm (else two
        values, the slope and the centre).
    points : ndarray, shape (3,)
        The three equally spaced inputs where the envelopes' values are taken (two values: the
        outer two).
    r : ndarray, shape (N,)
        The thresholds ``alpha j``, ``j = 1..N`` (equally spaced: :func:`_exponential_sums`).
    duration : float
        The record's duration [s] (NaN: no thermal blocks).
    """

    blocks: np.ndarray
    weights: np.ndarray
    envelopes: np.ndarray
    omegas: np.ndarray
    thermal: np.ndarray
    pinned: np.ndarray
    three_values: np.ndarray
    points: np.ndarray
    r: np.ndarray
    duration: float


@njit(cache=True, error_model="numpy")
def _value(row, column, pinned):
    return row[column] if column >= 0 else pinned


@njit(cache=True, error_model="numpy")
def _exponential_sums(t, r, top):
    """``(s0, s1, s2)``: the sums of ``e_j``, ``e_j r_j`` and ``e_j r_j^2`` with
    ``e_j = e^{-t r_j - top}``, for the layout's thresholds ``r_j = alpha j`` (``j = 1..N``,
    equally spaced from ``alpha``). One ``exp`` and the ratio ``e^{-t alpha}`` (or its inverse)
    carried from term to term, from the largest term: the j-th term differs from its own
    ``exp`` by about j units in the last place, where a dozen ``exp`` calls cost ten times more."""
    n = r.shape[0]
    if t >= 0.0:  # the terms fall from the first threshold
        j, step, ratio = 0, 1, math.exp(-t * r[0])
    else:  # they fall from the last
        j, step, ratio = n - 1, -1, math.exp(t * r[0])
    e = math.exp(-t * r[j] - top)
    s0 = s1 = s2 = 0.0
    for _ in range(n):
        s0 += e
        s1 += e * r[j]
        s2 += e * r[j] * r[j]
        e *= ratio
        j += step
    return s0, s1, s2


@njit(cache=True, error_model="numpy")
def _moments(rho, tau, r):
    """``(S, R, central second moment, s0)`` of the weights ``p_j = rho e^{-tau r_j}``."""
    s0, s1, s2 = _exponential_sums(tau, r, 0.0)
    return rho * s0, rho * s1, rho * (s2 - s1 * s1 / s0), s0


@njit(cache=True, error_model="numpy")
def _thermal_scales(row, thermal, pinned, duration):
    """``(g1, g2)``: each node's rise at the end of the record under a constant unit heating."""
    g1 = -math.expm1(-duration / _value(row, thermal[0, 0], pinned[2]))
    return g1, g1 * -math.expm1(-duration / _value(row, thermal[1, 0], pinned[3]))


@njit(cache=True, error_model="numpy")
def forward_rows(x, blocks, weights, envelopes, omegas, thermal, pinned, three_values, points, r, duration, u):
    """Sampler coordinates ``u`` (W, D) of parameters ``x`` (W, D)."""
    for w in range(x.shape[0]):
        row = x[w]
        for k in range(row.shape[0]):
            u[w, k] = row[k]
        S, R, _, _ = _moments(_value(row, weights[0], pinned[0]), _value(row, weights[1], pinned[1]), r)
        if blocks[0]:
            u[w, weights[0]] = S
            u[w, weights[1]] = R
        for p in range(2):
            if blocks[1 + p]:
                c = envelopes[p]
                k0, k1, k2, k3 = row[c[0]], row[c[1]], row[c[2]], row[c[3]]
                u[w, c[0]] = S * (k0 * math.tanh(k1 * points[0] + k2) + k3)
                u[w, c[3]] = S * (k0 * math.tanh(k1 * points[2] + k2) + k3)
                if three_values[p]:
                    u[w, c[1]] = S * (k0 * math.tanh(k1 * points[1] + k2) + k3)
                    u[w, c[2]] = math.log(k0) if k0 > 0 else (-math.inf if k0 == 0 else math.nan)
                else:  # the slope stays, the offset becomes the centre
                    u[w, c[2]] = -k2 / k1
        for p in range(2):
            if blocks[3 + p]:
                c = omegas[p]
                k1 = row[c[0]]
                u[w, c[0]] = math.log(k1) if k1 > 0 else (-math.inf if k1 == 0 else math.nan)
                u[w, c[1]] = -row[c[1]] / k1
        if blocks[5] or blocks[6]:
            g = _thermal_scales(row, thermal, pinned, duration)
            for k in range(2):
                if blocks[5 + k]:
                    tau = row[thermal[k, 0]]
                    u[w, thermal[k, 0]] = math.log(tau) if tau > 0 else (-math.inf if tau == 0 else math.nan)
                    for m in (1, 2):
                        u[w, thermal[k, m]] = row[thermal[k, m]] * g[k]


@njit(cache=True, error_model="numpy")
def _mean_and_var(t, r):
    """Mean and variance of the thresholds under the weights ``e^{-t r}`` (scaled by the
    exponent's maximum, at the first or the last threshold: no overflow)."""
    s0, s1, s2 = _exponential_sums(t, r, max(-t * r[0], -t * r[-1]))
    m = s1 / s0
    return m, s2 / s0 - m * m


@njit(cache=True, error_model="numpy")
def solve_tau(target, r, lower, upper, mean_lo, mean_hi, m0, v0, max_steps, start=math.nan):
    """The ``tau`` in ``[lower, upper]`` whose weighted mean threshold is ``target``:
    safeguarded Newton from the linearisation at ``tau = 0`` (mean ``m0``, variance ``v0``; a
    bisection step whenever Newton leaves the bracket) until a step moves ``tau`` by at most
    ``1e-13 (1 + |tau|)``; NaN where ``target`` is not finite or outside ``[mean_hi, mean_lo]``,
    the means at the bounds. The mean decreases in ``tau`` with slope ``-var``, the weights'
    variance of the thresholds. A finite ``start`` inside the bounds (a nearby point's ``tau``:
    the walker a proposal moves from) replaces the linearisation's first guess."""
    if not (target <= mean_lo and target >= mean_hi and math.isfinite(target)):
        return math.nan
    lo, hi = lower, upper
    t = start if lo <= start <= hi else min(max((m0 - target) / v0, lo), hi)
    for _ in range(max_steps):
        m, var = _mean_and_var(t, r)
        f = m - target  # > 0: the root lies at larger tau
        if f > 0:
            lo = t
        else:
            hi = t
        newton = t + f / var
        t_new = newton if lo <= newton <= hi else 0.5 * (lo + hi)
        done = abs(t_new - t) <= 1e-13 * (1.0 + abs(t))
        t = t_new
        if done:
            break
    return t


#: The spacing of doubles at 1 (numpy.finfo(float).eps).
_EPSILON = 2.220446049250313e-16


@njit(cache=True, error_model="numpy")
def _atanh(t):
    return 0.5 * (math.log1p(t) - math.log1p(-t))


@njit(cache=True, error_model="numpy")
def equal_steps(d1, d2, max_steps, start=math.nan):
    """The ``t`` in ``(-1, 1 - d1 - d2)`` where the tanh rises by ``d1`` and then by ``d2`` over
    two equal steps of its argument: ``atanh(t + d1) - atanh(t) = atanh(t + d1 + d2) - atanh(t + d1)``
    (an increasing envelope's three values at equally spaced inputs, less its offset and over its
    amplitude); NaN unless ``d1, d2 > 0`` and ``d1 + d2 < 2``.

    ``f(t) = 2 atanh(t + d1) - atanh(t) - atanh(t + d1 + d2)`` runs from ``+inf`` to ``-inf``
    over the interval, so a root lies inside; it need not be monotone, and it crossed zero once
    on every point of a 200 x 200 grid of ``(d1, d2)`` (a numerical check, not a proof; the
    round-trip tests cover the envelopes' regimes). Safeguarded Newton from ``start`` when it lies
    inside the interval (a nearby point's ``t``: the walker a proposal moves from), else from the
    interval's midpoint, a bisection step whenever Newton leaves the bracket, until a step (or
    the bracket) is at most four units in the last place of the largest of ``t, t + d1,
    t + d1 + d2``: the equation adds ``t`` to ``d1`` and ``d2``, so its values carry no finer
    ``t`` than that. From the midpoint a root near a singularity (a tanh's tail: ``t`` near
    ``1 - d1 - d2``) takes a dozen steps or more; from a nearby point a few."""
    hi = 1.0 - d1 - d2
    if not (d1 > 0.0 and d2 > 0.0 and hi > -1.0):
        return math.nan
    lo = -1.0
    t = start if lo < start < hi else 0.5 * (lo + hi)
    for _ in range(max_steps):
        tm, t2 = t + d1, t + d1 + d2
        f = 2.0 * _atanh(tm) - _atanh(t) - _atanh(t2)
        if f > 0.0:  # the root lies at larger t
            lo = t
        else:
            hi = t
        slope = 2.0 / (1.0 - tm * tm) - 1.0 / (1.0 - t * t) - 1.0 / (1.0 - t2 * t2)
        newton = t - f / slope
        tolerance = 4.0 * _EPSILON * max(abs(t), abs(tm), abs(t2))
        if abs(newton - t) <= tolerance:  # converged (t itself may be a bracket end by now)
            return newton
        t_new = newton if lo < newton < hi else 0.5 * (lo + hi)
        done = hi - lo <= tolerance
        t = t_new
        if done:
            break
    return t


@njit(cache=True, error_model="numpy")
def inverse_rows(
    u,
    blocks,
    weights,
    envelopes,
    omegas,
    thermal,
    pinned,
    three_values,
    points,
    r,
    duration,
    tau_bounds,
    max_steps,
    starts,
    warm,
    x,
):
    """Parameters ``x`` (W, D) of sampler coordinates ``u`` (W, D); rows outside the map's
    range are NaN. With ``warm``, row ``w``'s one-dimensional solves start from the parameters
    ``starts[w]`` (a point near the answer, e.g. the walker a proposal moves from); the answer
    is the same root to the solves' tolerance, found in fewer steps."""
    lower, upper = tau_bounds[0], tau_bounds[1]
    mean_lo, _ = _mean_and_var(lower, r)  # the same for every row
    mean_hi, _ = _mean_and_var(upper, r)
    m0, v0 = _mean_and_var(0.0, r)
    for w in range(u.shape[0]):
        row = u[w]
        out = x[w]
        for k in range(row.shape[0]):
            out[k] = row[k]
        bad = False
        if blocks[0]:
            S, R = row[weights[0]], row[weights[1]]
            mean = R / S if S > 0 else math.nan
            start = starts[w, weights[1]] if warm and weights[1] >= 0 else math.nan
            tau = solve_tau(mean, r, lower, upper, mean_lo, mean_hi, m0, v0, max_steps, start)
            out[weights[0]] = S / _exponential_sums(tau, r, 0.0)[0]
            out[weights[1]] = tau
            bad = bad or not (S > 0) or not math.isfinite(tau)
        S = _moments(_value(out, weights[0], pinned[0]), _value(out, weights[1], pinned[1]), r)[0]
        for p in range(2):
            if blocks[3 + p]:
                c = omegas[p]
                k1 = math.exp(row[c[0]])
                out[c[0]] = k1
                out[c[1]] = -row[c[1]] * k1
        for p in range(2):
            if blocks[1 + p]:
                c = envelopes[p]
                if three_values[p]:
                    k0 = math.exp(row[c[2]])
                    e1, em, e2 = row[c[0]] / S, row[c[1]] / S, row[c[3]] / S
                    start = math.tanh(starts[w, c[1]] * points[0] + starts[w, c[2]]) if warm else math.nan
                    t1 = equal_steps((em - e1) / k0, (e2 - em) / k0, max_steps, start)
                    z1 = _atanh(t1)
                    k1 = (_atanh(t1 + (em - e1) / k0) - z1) / (points[1] - points[0])
                    out[c[0]] = k0
                    out[c[1]] = k1
                    out[c[2]] = z1 - k1 * points[0]
                    out[c[3]] = e1 - k0 * t1
                    bad = bad or not (k1 > 0)
                else:
                    k1 = row[c[1]]
                    k2 = -row[c[2]] * k1
                    t1 = math.tanh(k1 * points[0] + k2)
                    t2 = math.tanh(k1 * points[2] + k2)
                    e1, e2 = row[c[0]] / S, row[c[3]] / S
                    k0 = (e1 - e2) / (t1 - t2)
                    out[c[0]] = k0
                    out[c[2]] = k2
                    out[c[3]] = e1 - k0 * t1
                    bad = bad or not (k1 != 0) or not (t1 != t2)
        if blocks[5] or blocks[6]:
            for k in range(2):  # both time constants before the scales
                if blocks[5 + k]:
                    out[thermal[k, 0]] = math.exp(row[thermal[k, 0]])
            g = _thermal_scales(out, thermal, pinned, duration)
            for k in range(2):
                if blocks[5 + k]:
                    for m in (1, 2):
                        out[thermal[k, m]] = row[thermal[k, m]] / g[k]
                    bad = bad or not (g[k] > 0)
        for k in range(out.shape[0]):
            bad = bad or not math.isfinite(out[k])
        if bad:
            for k in range(out.shape[0]):
                out[k] = math.nan


@njit(cache=True, error_model="numpy")
def _log_abs(v):
    return math.log(abs(v)) if v != 0 else -math.inf


@njit(cache=True, error_model="numpy")
def log_det_rows(x, blocks, weights, envelopes, omegas, thermal, pinned, three_values, points, r, duration, out):
    """``log |det du/dx|`` (W,) at parameters ``x`` (W, D), block by block."""
    for w in range(x.shape[0]):
        row = x[w]
        total = 0.0
        S, _, central, s0 = _moments(_value(row, weights[0], pinned[0]), _value(row, weights[1], pinned[1]), r)
        if blocks[0]:
            total += _log_abs(s0) + _log_abs(central)
        for p in range(2):
            if blocks[1 + p]:
                c = envelopes[p]
                k1, k2 = row[c[1]], row[c[2]]
                if three_values[p]:
                    # |det d(E1, Em, E2, log a0) / d(a0..a3)| = S^3 a0 |det N|, N's rows
                    # (s_i v_i, s_i, 1) with s_i = 1 - tanh^2 = sech^2 at the three points
                    s1 = 1.0 / math.cosh(k1 * points[0] + k2) ** 2
                    sm = 1.0 / math.cosh(k1 * points[1] + k2) ** 2
                    s2 = 1.0 / math.cosh(k1 * points[2] + k2) ** 2
                    v1, vm, v2 = points[0], points[1], points[2]
                    det = s1 * v1 * (sm - s2) - s1 * (sm * vm - s2 * v2) + sm * s2 * (vm - v2)
                    total += 3.0 * _log_abs(S) + _log_abs(row[c[0]]) + _log_abs(det)
                else:
                    t1 = math.tanh(k1 * points[0] + k2)
                    t2 = math.tanh(k1 * points[2] + k2)
                    total += 2.0 * _log_abs(S) + _log_abs(t1 - t2) - _log_abs(k1)
        for p in range(2):
            if blocks[3 + p]:
                total -= 2.0 * _log_abs(row[omegas[p][0]])
        if blocks[5] or blocks[6]:
            g = _thermal_scales(row, thermal, pinned, duration)
            for k in range(2):
                if blocks[5 + k]:
                    total += 2.0 * _log_abs(g[k]) - _log_abs(row[thermal[k, 0]])
        out[w] = total


@njit(cache=True, error_model="numpy")
def back_rows(
    s,
    q_u,
    factors,
    log_det_s,
    blocks,
    weights,
    envelopes,
    omegas,
    thermal,
    pinned,
    three_values,
    points,
    r,
    duration,
    tau_bounds,
    max_steps,
    q,
    factors_out,
    log_det_q,
):
    """A move's proposals ``q_u`` (W, D) in the sampler coordinates back in the parameters ``q``,
    their log factors with the Jacobian ratio added and their log-determinants, in one pass
    (:meth:`identify.fitting.coordinates.CoordinateMove._back`, the same operations): a row
    outside the map's range, or whose factor is not finite, stays at ``s`` with factor ``-inf``
    (its log-determinant NaN where the map gave none)."""
    layout = (blocks, weights, envelopes, omegas, thermal, pinned, three_values, points, r, duration)
    inverse_rows(q_u, *layout, tau_bounds, max_steps, s, True, q)  # each solve from its walker
    for w in range(q.shape[0]):
        ok = True
        for k in range(q.shape[1]):
            ok = ok and math.isfinite(q[w, k])
        log_det_q[w] = math.nan
        factor = factors[w]
        if ok:
            log_det_rows(q[w : w + 1], *layout, log_det_q[w : w + 1])
            factor = factor + (log_det_s[w] - log_det_q[w])
            ok = math.isfinite(factor)
        if not ok:
            for k in range(q.shape[1]):
                q[w, k] = s[w, k]
            factor = -math.inf
        factors_out[w] = factor
