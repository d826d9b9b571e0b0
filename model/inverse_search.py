"""The inverse's root search: per sample, the current on a side whose output meets the target.

:func:`inverse_kernel` walks the target sample by sample for a batch of parameter sets
(parallel over the batch): it chooses the side (rising or falling) from the target, finds the
current with an expanding probe and Brent's method
(``_search`` on ``_objective``, the output's distance from the target through
:func:`model.inverse_step.evaluate_step`; a side's edge located on the drive alone, ``_edge``
on ``_gap``), handles the Omega switch at a reversal and the current limits, and commits the
state (:func:`model.inverse_step.commit_step`). The method and the statuses are stated in
:mod:`model.inverse`'s docstring; :func:`model.inverse.invert` checks the inputs and calls
this kernel. The exported C (``identify/export/c/msma_gpi.c``) repeats this search operation
for operation: a change here is a change there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .effects.thermal import REFERENCE_CURRENT
from .gpi_kernels import operator_thresholds_and_weights
from .inverse_step import commit_step, creep_prepare, drive_step, evaluate_step, filter_coefficients

__all__ = ["inverse_kernel"]

#: The cap on the iterations of each loop of the search (the bisection for a side's edge, the
#: refinement of the bracket).
_MAX_ITERATIONS = 200
#: A side's edge is located to this many ``xtol`` (the width below which a bracket with an end off
#: the side is not refined further).
_EDGE_WIDTH = 16.0


@njit(cache=True)
def _objective(
    x,
    s,
    target,
    first,
    n_ops,
    g,
    thresholds,
    weights,
    memory,
    st,
    lag_c,
    has_training,
    tr,
    creep_on,
    creep_params,
    creep_affine,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """``(F, y_stage)``: ``F = s (y(s x) - target)`` on side ``s``, ``-inf`` off it (search coordinate
    ``x = s i``); ``y_stage`` the thermal stage's input there (0 off the side)."""
    y, _, _, _, _, side, _, _, y_stage = evaluate_step(
        s * x,
        first,
        n_ops,
        g,
        thresholds,
        weights,
        memory,
        st,
        lag_c,
        has_training,
        tr,
        creep_on,
        creep_params,
        creep_affine,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if not first and side != s:
        return -np.inf, 0.0
    return s * (y - target), y_stage


@njit(cache=True)
def _thermal_fall(y_stage, i0, ahead, first, thermal_on, th, thermal_c, lo, hi, htol):
    """The most the thermal stage can lower ``F`` from the current ``i0`` on a side (its input
    ``y_stage`` there) to any current beyond ``i0`` (``ahead`` > 0: up to ``hi``; < 0: down to
    ``lo``): ``|E - S y_stage|`` times the most the rise can change, both nodes (the rise is affine in
    the present heating ``(i / 5 A)^2``, weight ``1 - gain`` per node), with a quarter's margin plus
    ``htol``. The other stages keep ``F`` nondecreasing on a side (:mod:`model.inverse`)."""
    if not thermal_on or first:
        return 0.0
    a, b = (i0, hi) if ahead > 0 else (lo, i0)
    h_max = max(a * a, b * b)
    h_min = 0.0 if a < 0.0 < b else min(a * a, b * b)
    heating = max(h_max - i0 * i0, i0 * i0 - h_min) / (th[3] * th[3])
    rise = (1.0 - thermal_c[0] if thermal_c[2] > 0.5 else 1.0) * heating
    rise2 = (1.0 - thermal_c[3] if thermal_c[5] > 0.5 else 1.0) * rise
    return 1.25 * (abs(th[2] - th[1] * y_stage) * rise + abs(th[6] - th[5] * y_stage) * rise2) + htol


@njit(cache=True, inline="always")
def _beyond_fall(f, y_stage, i, ahead, first, thermal_on, th, thermal_c, lo, hi, htol):
    """Whether ``|F| = |f|`` at the current ``i`` exceeds what thermal can take off it before the limit."""
    return abs(f) > _thermal_fall(y_stage, i, ahead, first, thermal_on, th, thermal_c, lo, hi, htol)


@njit(cache=True)
def _gap(x, s, first, st, lag_c, has_training, tr):
    """``s (u(s x) - u_prev)``: how far the drive moves toward side ``s`` (the input stage alone)."""
    _, u, _, _ = drive_step(s * x, first, st, lag_c, has_training, tr)
    return s * (u - st[4])


@njit(cache=True)
def _dead_zone_end(x0, s, first, g, thresholds, memory, n_ops, st, lag_c, has_training, tr):
    """Where on side ``s`` the drive reaches the first operator it moves (search coordinate).

    The end of the dead zone a reversal leaves, where the output starts to follow the drive: on
    the rising side the operators move once the envelope passes :math:`\\min_j (m_j + r_j w)`, on
    the falling side once it passes below :math:`\\max_j (m_j - r_j w)`; the envelope's tanh is
    inverted there. The current is one secant step on the drive alone (:func:`_gap`) from ``x0``
    and a unit slope, exact for an affine input stage. A start for the probes, not a root: NaN
    when no operator is reached or the end lies behind ``x0``.
    """
    if first:
        return np.nan
    k = 0 if s > 0 else 4
    _, u, _, fade = drive_step(s * x0, first, st, lag_c, has_training, tr)
    width = 1.0
    if has_training and tr[5] != 0.0:
        width = 1.0 + tr[5] * fade
    level = np.inf if s > 0 else -np.inf
    for j in range(n_ops):
        v = memory[j] + s * thresholds[j] * width
        level = min(level, v) if s > 0 else max(level, v)
    arg = (level - g[k + 3]) / g[k]
    if not abs(arg) < 1.0:
        return np.nan
    distance = s * ((math.atanh(arg) - g[k + 2]) / g[k + 1] - st[4])  # the drive's way there
    d0 = s * (u - st[4])
    if not distance > d0:
        return np.nan
    xb = x0 + (distance - d0)
    db = _gap(xb, s, first, st, lag_c, has_training, tr)
    if db == distance:
        return xb
    if not db != d0:
        return np.nan
    x = xb + (distance - db) * (xb - x0) / (db - d0)
    return x if np.isfinite(x) and x > x0 else np.nan


@njit(cache=True, inline="always")
def _on_side(d, s, st):
    """Whether a drive gap ``d`` (:func:`_gap`) lies on side ``s``: a still drive keeps the last motion's."""
    return d > 0.0 or (d == 0.0 and (st[5] > 0.5) == (s > 0))


@njit(cache=True)
def _edge(xa, da, xb, db, s, xtol, first, st, lag_c, has_training, tr):
    """The point on side ``s`` within ``_EDGE_WIDTH xtol`` of its edge, between ``xa`` (off the side,
    drive gap ``da``) and ``xb`` (on it, gap ``db``), found on the drive alone (:func:`_gap`).

    Illinois regula falsi on the gap (affine in the current for a lag: one step), each point at
    least ``_EDGE_WIDTH xtol`` inside the bracket (the point next to the edge ends it), a
    bisection when the last two steps did not halve the bracket.
    """
    limit = _EDGE_WIDTH * xtol
    ga, gb = da, db
    last = 0
    width_1, width_2 = np.inf, np.inf
    for _ in range(_MAX_ITERATIONS):
        width = abs(xb - xa)
        if width <= limit:
            break
        toward = 1.0 if xb > xa else -1.0  # from xa to xb
        if gb > ga and width <= 0.5 * width_2 and width > 2.0 * limit:
            x = xb - gb * (xb - xa) / (gb - ga)
            x = min(max(toward * (x - xa), limit), width - limit) * toward + xa
        else:
            x = 0.5 * (xa + xb)
        width_2, width_1 = width_1, width
        d = _gap(x, s, first, st, lag_c, has_training, tr)
        if _on_side(d, s, st):
            xb, gb = x, d
            if last == 1:
                ga *= 0.5
            last = 1
        else:
            xa, ga = x, d
            if last == -1:
                gb *= 0.5
            last = -1
    return xb


@njit(cache=True, inline="always")
def _magnitude(f):
    return np.inf if f == -np.inf else abs(f)


@njit(cache=True)
def _search(
    s,
    start,
    step0,
    lo,
    hi,
    target,
    htol,
    rtol,
    xtol,
    first,
    n_ops,
    g,
    thresholds,
    weights,
    memory,
    st,
    lag_c,
    has_training,
    tr,
    creep_on,
    creep_params,
    creep_affine,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """The current on side ``s`` whose output meets the target, nearest ``start`` (``F`` = :func:`_objective`).

    In the search coordinate ``x = s i``:

    1. ``start`` itself when ``|F| <= htol`` there (a hold);
    2. a start off the side (a reversal: ``F = -inf``) is first moved to the side's edge, on
       the drive alone (:func:`_gap`, no envelope evaluated): probes from ``start`` growing 4x
       from ``_EDGE_WIDTH xtol`` (or to where the drive's gap, straight through the last two
       probes, closes: a lag's edge in one step), then :func:`_edge` to ``_EDGE_WIDTH xtol``;
       the root nearest the previous drive lies there;
    3. probes with steps growing 4x (from ``step0``) go first where a nondecreasing ``F``
       has its root (up when ``F < 0``; after a reversal the first probe is at the end of the
       dead zone it leaves, :func:`_dead_zone_end`, and the steps grow from there), then, if
       that direction reaches its limit or the side's edge without a sign change, the other way,
       but only as far as ``F`` can still fall to 0: while ``thermal`` can lower it by ``|F|``
       before the limit (:func:`_thermal_fall`: the heating's weight in one step, bounded),
       always with training's strain part on. Only when neither finds a sign change is the
       stretch between the side's edge and the last point on it examined (a root can lie there
       when the drive lags the current): the edge is located on the drive alone (:func:`_edge`;
       without input dynamics it is that point itself), and
       ``F`` there, if it changes sign, closes the bracket;
    4. the bracket is closed by Brent's method (Brent 1973, as scipy's ``brentq``) to
       ``|F| <= rtol`` or a width of ``xtol``: the secant or inverse quadratic step while it
       is short against the steps before it, bisection otherwise (``F`` flat at one end and
       steep at the other, the end of a dead zone, is where interpolation alone would crawl),
       and bisection while an end is off the side (done at a width of ``_EDGE_WIDTH xtol``).

    Every loop is capped at ``_MAX_ITERATIONS``; a reversal costs about 15-25 model steps, a
    sample in between 2-6.
    Without a sign change the evaluated point of smallest ``|F|`` is returned: a current
    limit (saturated) or the side's edge (an Omega switch). Returns ``(i, F, evaluations)``.
    """
    if s > 0:
        x_min, x_max = lo, hi
    else:
        x_min, x_max = -hi, -lo
    x0 = min(max(s * start, x_min), x_max)
    n_eval = 1
    f0, y_stage = _objective(
        x0,
        s,
        target,
        first,
        n_ops,
        g,
        thresholds,
        weights,
        memory,
        st,
        lag_c,
        has_training,
        tr,
        creep_on,
        creep_params,
        creep_affine,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if abs(f0) <= htol:
        return s * x0, f0, n_eval
    down_done = x0 <= x_min
    if f0 == -np.inf:
        # 2. the side's edge above x0, on the drive alone: probes growing 4x from _EDGE_WIDTH xtol
        # (or to where the drive's gap, straight through the last two probes, closes), then _edge
        xp, dp = x0, _gap(x0, s, first, st, lag_c, has_training, tr)
        step = _EDGE_WIDTH * xtol
        x = min(x0 + step, x_max)
        d = dp
        on = False
        for _ in range(_MAX_ITERATIONS):
            d = _gap(x, s, first, st, lag_c, has_training, tr)
            on = _on_side(d, s, st)
            if on or x >= x_max:
                break
            step *= 4.0
            x_next = x + step
            if d > dp:
                x_next = max(x_next, x - d * (x - xp) / (d - dp))
            xp, dp = x, d
            x = min(x_next, x_max)
        if not on:
            return s * x0, f0, n_eval  # the side cannot be reached within the limits
        x0 = _edge(xp, dp, x, d, s, xtol, first, st, lag_c, has_training, tr)
        f0, y_stage = _objective(
            x0,
            s,
            target,
            first,
            n_ops,
            g,
            thresholds,
            weights,
            memory,
            st,
            lag_c,
            has_training,
            tr,
            creep_on,
            creep_params,
            creep_affine,
            thermal_on,
            th,
            thermal_c,
            drift,
        )
        n_eval += 1
        down_done = True
        if abs(f0) <= htol:
            return s * x0, f0, n_eval
    # 3. probe for a sign change; away from the root of a nondecreasing F only while the thermal
    # stage can still make F fall by |F| before the limit (always with training's strain part on)
    bounded = not (has_training and tr[4] != 0.0)
    y_stage0 = y_stage
    best_x, best_f = x0, f0
    up_done = x0 >= x_max
    direction = 1 if f0 < 0.0 else -1
    if direction < 0 and down_done:
        direction = 1
    found = False
    edge_found = False
    xl, fl, xr, fr = x0, f0, x0, f0
    exl, efl, exr, efr = x0, f0, x0, f0
    for sweep in range(2):
        if sweep == 1:
            direction = -direction
        if (direction > 0 and up_done) or (direction < 0 and down_done):
            continue
        away = direction * f0 > 0.0
        if (
            away
            and bounded
            and _beyond_fall(f0, y_stage0, s * x0, s * f0, first, thermal_on, th, thermal_c, lo, hi, htol)
        ):
            continue
        xp, fp = x0, f0
        step = step0
        # toward the root after a reversal: the first probe at the dead zone's end, the steps grow
        # from there
        hint = np.nan
        if direction > 0 and not away and (st[5] > 0.5) != (s > 0):
            hint = _dead_zone_end(x0, s, first, g, thresholds, memory, n_ops, st, lag_c, has_training, tr)
        while True:
            x = min(xp + step, x_max) if direction > 0 else max(xp - step, x_min)
            if hint > x:
                x = min(hint, x_max)
            else:
                step *= 4.0
            hint = np.nan
            f, y_stage = _objective(
                x,
                s,
                target,
                first,
                n_ops,
                g,
                thresholds,
                weights,
                memory,
                st,
                lag_c,
                has_training,
                tr,
                creep_on,
                creep_params,
                creep_affine,
                thermal_on,
                th,
                thermal_c,
                drift,
            )
            n_eval += 1
            if f == -np.inf:  # off the side (F counts as negative there): a root may lie between its
                # edge and xp when F > 0 at xp, or the other way
                if fp > 0.0 and not edge_found:
                    edge_found = True
                    exl, efl, exr, efr = (xp, fp, x, f) if direction > 0 else (x, f, xp, fp)
                break
            if (f < 0.0) != (fp < 0.0):
                if direction > 0:
                    xl, fl, xr, fr = xp, fp, x, f
                else:
                    xl, fl, xr, fr = x, f, xp, fp
                found = True
                break
            if _magnitude(f) < _magnitude(best_f):
                best_x, best_f = x, f
            xp, fp = x, f
            if x >= x_max or x <= x_min:
                break
            if (
                away
                and bounded
                and _beyond_fall(f, y_stage, s * x, s * f0, first, thermal_on, th, thermal_c, lo, hi, htol)
            ):
                break
        if found:
            break
    if not found and edge_found:  # no sign change on the side: between its edge and the last point on it
        x_on, f_on, x_off = (exl, efl, exr) if efr == -np.inf else (exr, efr, exl)
        d_on = _gap(x_on, s, first, st, lag_c, has_training, tr)
        d_off = _gap(x_off, s, first, st, lag_c, has_training, tr)
        x = _edge(x_off, d_off, x_on, d_on, s, xtol, first, st, lag_c, has_training, tr)
        if x == x_on:
            return s * x_on, f_on, n_eval
        f, _ = _objective(
            x,
            s,
            target,
            first,
            n_ops,
            g,
            thresholds,
            weights,
            memory,
            st,
            lag_c,
            has_training,
            tr,
            creep_on,
            creep_params,
            creep_affine,
            thermal_on,
            th,
            thermal_c,
            drift,
        )
        n_eval += 1
        if (f < 0.0) == (f_on < 0.0):  # no root between: the point nearer the target
            if abs(f) < abs(f_on):
                return s * x, f, n_eval
            return s * x_on, f_on, n_eval
        xl, fl, xr, fr = (x, f, x_on, f_on) if x < x_on else (x_on, f_on, x, f)
        found = True
    if not found:
        return s * best_x, best_f, n_eval
    # 4. refine the bracket xl < xr, F changing sign: Brent's method (as scipy's brentq: the
    # secant or inverse quadratic step when it is short, bisection otherwise), by bisection
    # while an end is off the side (done at a width of _EDGE_WIDTH xtol)
    xpre, fpre, xcur, fcur, xblk, fblk = xl, fl, xr, fr, xl, fl
    spre = scur = 0.0
    delta = 0.5 * xtol
    for _ in range(_MAX_ITERATIONS):
        if fpre != 0.0 and fcur != 0.0 and (fpre < 0.0) != (fcur < 0.0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if _magnitude(fblk) < _magnitude(fcur):  # xcur: the better end of the bracket
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        sbis = 0.5 * (xblk - xcur)
        if _magnitude(fcur) <= rtol or abs(sbis) <= delta:
            break
        finite = fcur > -np.inf and fpre > -np.inf and fblk > -np.inf
        if not finite and abs(sbis) <= 0.5 * _EDGE_WIDTH * xtol:
            break
        scur, spre = _brent_step(xpre, fpre, xcur, fcur, xblk, fblk, spre, scur, sbis, delta, finite)
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0.0 else -delta)
        fcur, _ = _objective(
            xcur,
            s,
            target,
            first,
            n_ops,
            g,
            thresholds,
            weights,
            memory,
            st,
            lag_c,
            has_training,
            tr,
            creep_on,
            creep_params,
            creep_affine,
            thermal_on,
            th,
            thermal_c,
            drift,
        )
        n_eval += 1
    if _magnitude(fblk) < _magnitude(fcur):
        return s * xblk, fblk, n_eval
    return s * xcur, fcur, n_eval


@njit(cache=True)
def _brent_step(xpre, fpre, xcur, fcur, xblk, fblk, spre, scur, sbis, delta, finite):
    """Brent's next step from ``xcur`` and the step before it, ``(scur, spre)``: the secant
    (``xpre`` is the bracket's other end) or inverse quadratic step when the last steps shrank
    and it stays well inside the bracket, else the bisection ``sbis`` (always while an end is
    off the side)."""
    if finite and abs(spre) > delta and abs(fcur) < abs(fpre):
        if xpre == xblk:
            stry = -fcur * (xcur - xpre) / (fcur - fpre)
        else:
            dpre = (fpre - fcur) / (xpre - xcur)
            dblk = (fblk - fcur) / (xblk - xcur)
            stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
        if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):
            return stry, scur
    return sbis, sbis


@njit(parallel=True, cache=True)
def inverse_kernel(
    gpi_theta,
    n_ops,
    rising_is_a,
    z0,
    held,
    lag_tau,
    has_training,
    training,
    creep_on,
    creep_params,
    creep_taus,
    thermal_on,
    thermal,
    drift,
    time,
    target,
    lo,
    hi,
    ytol,
    current_out,
    output_out,
    status_out,
    evaluations,
):
    n_sets = gpi_theta.shape[0]
    n_samples = time.shape[0]
    n_modes = creep_taus.shape[1]
    xtol = 1e-15 * (hi - lo)
    scale = 1.0
    for k in range(n_samples):
        scale = max(scale, abs(target[k]))
    rtol = 4.0 * 2.220446049250313e-16 * scale  # rounding of the output
    htol = 16.0 * rtol  # a hold (no move) is accepted this close
    for w in prange(n_sets):
        th_ = gpi_theta[w]
        alpha, rho, tau = th_[0], th_[1], th_[2]
        g = np.empty(16)
        if rising_is_a:
            for q in range(4):
                g[q] = th_[3 + q]
                g[4 + q] = th_[7 + q]
        else:
            for q in range(4):
                g[q] = th_[7 + q]
                g[4 + q] = th_[3 + q]
        for q in range(8):
            g[8 + q] = th_[11 + q]
        thresholds, weights = operator_thresholds_and_weights(alpha, rho, tau, n_ops)
        memory = held[w].copy()  # the held part until the first sample is committed
        modes = np.empty(n_modes)
        creep_gain = np.empty(n_modes)
        creep_decay = np.empty(n_modes)
        creep_active = np.empty(n_modes, dtype=np.bool_)
        creep_affine = np.zeros(5)  # creep at the present sample, affine in the strain (creep_prepare)
        # scalar state: 0 i_prev, 1 u1_prev (lag output), 2 training's i_0, 3 travel,
        # 4 u_prev (GPI drive), 5 previous sample on Omega's c branch, 6 GPI output prev,
        # 7 temperature rise (node 1), 8 initial memory level z0, 9 heating prev,
        # 10 the current's travel, 11 the GPI output at the first sample, 12 the strain
        # (after training's strain part) prev, 13 temperature rise of node 2, 14 initial
        # excursion, 15 the strain two samples back, 16 its last direction of change, 17 the
        # strain held at the last leg's end, 18 the logarithmic creep's input prev
        st = np.zeros(19)
        st[8] = z0[w, 0]
        st[14] = z0[w, 1]
        lag_c = np.zeros(3)
        thermal_c = np.zeros(6)
        tr = training[w]
        th = np.empty(9)
        th[0] = thermal[w, 0]
        th[1] = thermal[w, 1]
        th[2] = thermal[w, 2]
        th[3] = REFERENCE_CURRENT
        th[4] = thermal[w, 3]
        th[5] = thermal[w, 4]
        th[6] = thermal[w, 5]
        th[7] = thermal[w, 6]
        th[8] = thermal[w, 7]
        n_eval_total = 0
        previous_step = 0.1 * (hi - lo)
        for k in range(n_samples):
            first = k == 0
            if not first:
                h = time[k] - time[k - 1]
                gain, decay, active = filter_coefficients(h, lag_tau[w])
                lag_c[0], lag_c[1], lag_c[2] = gain, decay, 1.0 if active else 0.0
                if creep_on:
                    for m in range(n_modes):
                        gain, decay, active = filter_coefficients(h, creep_taus[w, m])
                        creep_gain[m], creep_decay[m], creep_active[m] = gain, decay, active
                if thermal_on:
                    gain, decay, active = filter_coefficients(h, th[0])
                    thermal_c[0], thermal_c[1], thermal_c[2] = gain, decay, 1.0 if active else 0.0
                    gain, decay, active = filter_coefficients(h, th[4])
                    thermal_c[3], thermal_c[4], thermal_c[5] = gain, decay, 1.0 if active else 0.0
                if creep_on:
                    creep_prepare(st, creep_params[w], modes, creep_gain, creep_decay, creep_active, creep_affine)
            d = drift[w, k]
            tk = target[k]
            if first:
                pref = 1
                start = lo
                step0 = 0.1 * (hi - lo)
            else:
                pref = 1 if st[5] > 0.5 else -1  # continue on the previous sample's side first
                start = st[0]
                step0 = max(2.0 * previous_step, 1e-4 * (hi - lo))
            i_best, f_best, n_eval = _search(
                pref,
                start,
                step0,
                lo,
                hi,
                tk,
                htol,
                rtol,
                xtol,
                first,
                n_ops,
                g,
                thresholds,
                weights,
                memory,
                st,
                lag_c,
                has_training,
                tr,
                creep_on,
                creep_params[w],
                creep_affine,
                thermal_on,
                th,
                thermal_c,
                d,
            )
            n_eval_total += n_eval
            if abs(f_best) > htol and not first:
                i_other, f_other, n_eval = _search(
                    -pref,
                    start,
                    step0,
                    lo,
                    hi,
                    tk,
                    htol,
                    rtol,
                    xtol,
                    first,
                    n_ops,
                    g,
                    thresholds,
                    weights,
                    memory,
                    st,
                    lag_c,
                    has_training,
                    tr,
                    creep_on,
                    creep_params[w],
                    creep_affine,
                    thermal_on,
                    th,
                    thermal_c,
                    d,
                )
                n_eval_total += n_eval
                if abs(f_other) <= htol:
                    i_best, f_best = i_other, f_other
                else:
                    # Neither side exact. When the side toward the target cannot reach it
                    # (F < 0 along it), drive that side to its current limit: full effort (a lag
                    # keeps the drive from crossing a dead zone in one sample; committing to the
                    # reversal at full effort catches up soonest). Otherwise (the side overshoots
                    # from its edge: a gap at an Omega switch) the output nearer the target wins,
                    # at most half the jump away.
                    f_rise = f_best if pref > 0 else f_other
                    f_fall = f_other if pref > 0 else f_best
                    toward = tk - output_out[w, k - 1]
                    if toward > 0.0 and -np.inf < f_rise < 0.0:
                        i_best = hi
                    elif toward < 0.0 and -np.inf < f_fall < 0.0:
                        i_best = lo
                    elif _magnitude(f_other) < _magnitude(f_best):
                        i_best, f_best = i_other, f_other
            if not first:
                previous_step = abs(i_best - st[0])
            y = commit_step(
                i_best,
                first,
                n_ops,
                g,
                thresholds,
                weights,
                memory,
                st,
                lag_c,
                has_training,
                tr,
                creep_on,
                creep_params[w],
                modes,
                creep_gain,
                creep_decay,
                creep_active,
                creep_affine,
                thermal_on,
                th,
                thermal_c,
                d,
            )
            current_out[w, k] = i_best
            output_out[w, k] = y
            if abs(y - tk) <= ytol:
                status_out[w, k] = 0
            else:
                status_out[w, k] = 1 if (i_best <= lo or i_best >= hi) else 2
        evaluations[w] = n_eval_total
