r"""The inverse of the GPI model (plus effects): the drive that makes the model follow a target.

Given a desired output trajectory :math:`y^*_k` at sample times :math:`t_k` and a model
(GPI plus any library effect), :func:`invert` returns a drive :math:`i_k` within
``[lo, hi]`` such that the model's output on that drive equals :math:`y^*_k` wherever the
model can produce it, for one parameter set or a batch (posterior draws), in one numba
kernel parallel over the batch. Pure: no I/O, no plotting.

Method: a per-sample 1-D root find carried forward with the model's state
-------------------------------------------------------------------------------
The model is causal and its state after sample ``k-1`` is finite-dimensional: the ``N``
operator memories, the previous drive and Omega branch (GPI, :mod:`model.gpi`); the
lag filter's output, the first-cycle travel (``training``); the creep modes; the
temperature rise (``thermal``). Given that state, the output at sample ``k`` is a scalar
function :math:`y_k(i)` of the present current alone, and on each *side* it is monotone:

* the drive the hysteresis sees, :math:`u_k(i)`, is increasing in :math:`i` (``lag``:
  affine, :math:`u_k = i(1 - g) + \dots` with the exact step of
  :func:`model.effects.first_order_lowpass`, gain :math:`g < 1`; ``training``: the
  soft-thresholded, scaled excursion, increasing except for extreme settings);
* **rising side** :math:`u_k \ge u_{k-1}` (Omega's ``c`` branch, eq. 13):
  :math:`y = \Omega_c(u) + \sum_j p_j \max(z_j, \gamma_\uparrow(u) - r_j)`, nondecreasing
  in :math:`u` for increasing envelopes, positive weights and an increasing
  :math:`\Omega_c`; **falling side** :math:`u_k < u_{k-1}`: the same with ``min``,
  :math:`\gamma_\downarrow + r_j` and :math:`\Omega_d`;
* output-stage effects are increasing in the GPI output at the present sample
  (``creep``: :math:`1 - A + A\,\overline{(1 - \text{gain})} > 0`; ``thermal``:
  :math:`1 - S\vartheta > 0`; ``sensor_drift``: an offset). ``thermal`` also depends on the
  present current directly, through :math:`(i/5\,\mathrm{A})^2` in one exact filter step
  (weight about :math:`h/2\tau_T`, 2.5e-4 at 100 Hz and 20 s), which can make the output
  very slightly non-monotone where the GPI is flat; the search still returns a root
  where the target is crossed.

So sample by sample, the inverse solves :math:`y_k(i) = y^*_k` on one side by a
bracketed search in the current (an expanding probe from the previous current, then
Illinois regula falsi with bisection as the safeguard), commits the state with the
current found, and moves on. Each root is found to ``ytol`` in the output (default
``1e-12 (1 + max|y*|)``, rounding level): the model driven by the returned current
reproduces a target it could produce to rounding (``tests/test_inverse.py``).

Side (direction) choice and the Omega switch at a reversal
-----------------------------------------------------------
The side is chosen from the target: rising when :math:`y^*_k > y^*_{k-1}`, falling when
it decreases, the side of the previous sample when it is flat (after a sample that was not
reached exactly: the sign of :math:`y^*_k - y_{k-1}`). At a reversal Omega switches branch
(eq. 13: ``c`` for :math:`\Delta u \ge 0`, ``d`` for :math:`\Delta u < 0`) with memory
unchanged, so the output jumps by :math:`\Omega_d(u) - \Omega_c(u)` (Table 1: +1.9 to
+3.0 um at a peak, the opposite at a trough) the moment the drive reverses. The search
handles this explicitly: on the new side the output starts from the jumped value, and
the root lies where the operators have moved enough to take the jump back (a step of the
current at the reversal; with Table 1's sign every target reversal is reachable this way).
When the jump has the other sign, targets just past the reversal lie in a gap neither
side can produce: then both sides are searched and the output closer to the target wins
(never more than half the jump away); the sample is flagged :data:`STATUS_BRANCH`. A
still drive keeps Omega on the branch of its last motion (:mod:`model.gpi`), so a hold of the
target is a hold of the current.

Current limits and unreachable targets
--------------------------------------
The current stays in ``[lo, hi]`` (the rig's 0-5 A by default). A target sample beyond
what the model produces at a limit (on the chosen side, after trying the other) gets the
limit and the remaining error; it is flagged :data:`STATUS_SATURATED`. The caller decides
whether that is an error (``python -m identify compensate`` refuses such targets).

Effects with dynamics
---------------------
``lag``, ``creep`` and ``thermal`` are inverted exactly in their general forms, each with
its own state in the per-sample step: the current found at sample ``k`` is the one whose
*filtered* drive (lag) and whose heating (thermal, both nodes) give the target; creep's
modes (the saturating spectrum and the logarithmic ones, these with the part held to the
leg's end) are advanced with the strain found. A lag's dead time (``lag_delay`` not 0) is
refused: the current at a sample acts on the output only a dead time later, which no
per-sample step can reach. A lag is inverted exactly too, which means the current leads the
drive (:math:`i \approx u + \tau_L \dot u`) and steps where the drive has a kink; the exact
step of a first-order filter with an input linear between samples has a zero near -1 in the
sample domain, so a step in :math:`u` makes :math:`i` ring with alternating sign, decaying
as :math:`(-1 + h/3\tau_L)^k`: real, but the current limits may bind. ``training`` (its
drive, width and strain parts) and ``initial_state`` (its level, prior excursion and held
memory) are inverted as identified (the compensation starts from the model's initial state).
``sensor_drift`` is supported here (an offset per sample, whatever its form: the effect's
own output on a zero displacement), but it is a property of the sensor, not of the
transducer (the workflows leave it out of a compensation). An effect without an inverse step
here raises a :class:`ValueError` naming it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .composite import Model
from .effects._filters import leg_end_level
from .effects.creep import CREEP_MODES, LOG_CREEP_MODE_WEIGHT, creep_time_constants, log_creep_time_constants
from .effects.thermal import REFERENCE_CURRENT
from .gpi import READINGS, THETA_NAMES
from .gpi_kernels import initial_operator_memory, operator_thresholds_and_weights

__all__ = [
    "invert",
    "InverseResult",
    "SUPPORTED_EFFECTS",
    "STATUS_EXACT",
    "STATUS_SATURATED",
    "STATUS_BRANCH",
    "STATUS_NAMES",
    "DEFAULT_CURRENT_RANGE",
]

#: Effects :func:`invert` knows the state and step of.
SUPPORTED_EFFECTS = ("lag", "training", "initial_state", "creep", "thermal", "sensor_drift")
#: The target is reproduced to ``ytol``.
STATUS_EXACT = 0
#: The current sits at a limit and the target is not reached.
STATUS_SATURATED = 1
#: Not reached within the limits for another reason: a gap at an Omega branch switch.
STATUS_BRANCH = 2
STATUS_NAMES = {STATUS_EXACT: "exact", STATUS_SATURATED: "saturated", STATUS_BRANCH: "branch"}
#: The rig's current range [A] (the paper's 5 A excitation, coils never driven negative).
DEFAULT_CURRENT_RANGE = (0.0, 5.0)

_MAX_ITERATIONS = 200


@dataclass(frozen=True, eq=False)
class InverseResult:
    """The drive found by :func:`invert`, and what the model does with it.

    Attributes
    ----------
    current : ndarray, shape (W, T) or (T,)
        The drive [input unit], within ``current_range``; 1-D for a 1-D ``theta``.
    output : ndarray, shape like ``current``
        The model's output on that drive [output unit] as the kernel computed it
        (equal to :meth:`model.Model.evaluate` to rounding).
    status : ndarray of int8, shape like ``current``
        Per sample: :data:`STATUS_EXACT`, :data:`STATUS_SATURATED` or :data:`STATUS_BRANCH`.
    target : ndarray, shape (T,)
    current_range : (float, float)
    ytol : float
        Output tolerance of the root finds.
    evaluations : ndarray of int64, shape (W,)
        Model steps evaluated per parameter set (about 10-20 per sample).
    """

    current: np.ndarray
    output: np.ndarray
    status: np.ndarray
    target: np.ndarray
    current_range: tuple
    ytol: float
    evaluations: np.ndarray

    @property
    def error(self) -> np.ndarray:
        """``output - target`` [output unit]."""
        return self.output - self.target

    @property
    def exact(self) -> np.ndarray:
        """Boolean like ``status``: reproduced to ``ytol``."""
        return self.status == STATUS_EXACT


# --------------------------------------------------------------------------------------
# kernel
# --------------------------------------------------------------------------------------
@njit(cache=True)
def _filter_coefficients(step, tau):
    """``(gain, decay, active)`` of one exact step of ``tau du/dt = x - u`` (as model.effects)."""
    if tau <= 0.0:
        return 1.0, 0.0, False
    ratio = step / tau
    decay = math.exp(-ratio)
    if ratio > 1e-3:
        gain = (1.0 - decay) / ratio
    else:
        gain = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)))
    return gain, decay, True


@njit(cache=True, inline="always")
def _filter_step(state, x_prev, x_now, gain, decay, active):
    if not active:
        return x_now
    return x_now - (x_now - x_prev) * gain + decay * (state - x_prev)


@njit(cache=True, inline="always")
def _env(k0, k1, k2, k3, v):
    return k0 * math.tanh(k1 * v + k2) + k3


@njit(cache=True, inline="always")
def _initial_envelopes(g, u, excursion):
    """The envelopes :func:`model.gpi.initial_operator_memory` reads at the first drive ``u``:
    ``(rising at u, falling at u, the one the prior excursion moves along at u + excursion)``."""
    excursion_env = 0.0
    if excursion > 0.0:
        excursion_env = _env(g[0], g[1], g[2], g[3], u + excursion)
    elif excursion < 0.0:
        excursion_env = _env(g[4], g[5], g[6], g[7], u + excursion)
    return _env(g[0], g[1], g[2], g[3], u), _env(g[4], g[5], g[6], g[7], u), excursion_env


@njit(cache=True)
def _evaluate(
    i,
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
    cp,
    modes,
    creep_gain,
    creep_decay,
    creep_active,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """Model output at the present sample for current ``i``, from the committed state.

    ``g``: the 16 envelope/Omega coefficients (rising env 0-3, falling env 4-7, Omega c
    8-11, Omega d 12-15). ``st``: scalar state (see the kernel). ``tr``: training's six
    parameters. ``cp``: creep's saturating amplitude, number of saturating modes, logarithmic
    rate, number of logarithmic modes, the part held to the leg's end (``modes`` holds the
    saturating modes, then the logarithmic ones). ``th``: thermal's node-1 time constant, sensitivity, expansion, the
    reference current, node 2's time constant, sensitivity, expansion; ``thermal_c`` the
    two nodes' step coefficients. ``drift``: the sensor drift at this sample.
    Before the first sample is committed, ``memory`` holds the initial memory held beyond
    the bounds (``initial_state``'s :math:`h_j`), which the first sample adds to the clamped
    memory. Returns ``(y, y_gpi, u1, u, travel, side, y_strain, width)``; ``side`` +1 on Omega's c
    branch (the drive last moved up), -1 on d; ``y_strain`` the strain after training's strain part (the
    output stage's input); ``width`` the factor on the thresholds in force.
    """
    # input stage: lag, then training
    if first:
        u1 = i
    else:
        u1 = _filter_step(st[1], st[0], i, lag_c[0], lag_c[1], lag_c[2] > 0.5)
    travel = 0.0
    u = u1
    if has_training:
        if first:
            travel = 0.0
        else:
            travel = st[3] + abs(u1 - st[1])
        fade = math.exp(-((travel / tr[2]) ** tr[3]))
        excursion = 0.0 if first else u1 - st[2]
        kept = np.sign(excursion) * max(abs(excursion) - tr[1] * fade, 0.0)
        u = u1 - (excursion - kept * (1.0 - tr[0] * fade))
    # the play width in force (training's virgin width)
    width = 1.0
    if has_training and tr[5] != 0.0:
        width = 1.0 + tr[5] * math.exp(-((travel / tr[2]) ** tr[3]))
    # hysteresis
    if first:
        rising_env, falling_env, excursion_env = _initial_envelopes(g, u, st[14])
        s = 0.0
        for j in range(n_ops):
            s += weights[j] * (
                initial_operator_memory(st[8], thresholds[j], rising_env, falling_env, st[14], excursion_env)
                + memory[j]
            )
        y_gpi = _env(g[8], g[9], g[10], g[11], u) + s
        side = 1
    else:
        dv = u - st[4]
        if dv > 0.0:
            env = _env(g[0], g[1], g[2], g[3], u)
            s = 0.0
            for j in range(n_ops):
                s += weights[j] * max(memory[j], env - thresholds[j] * width)
            y_gpi = _env(g[8], g[9], g[10], g[11], u) + s
            side = 1
        elif dv < 0.0:
            env = _env(g[4], g[5], g[6], g[7], u)
            s = 0.0
            for j in range(n_ops):
                s += weights[j] * min(memory[j], env + thresholds[j] * width)
            y_gpi = _env(g[12], g[13], g[14], g[15], u) + s
            side = -1
        else:  # a still drive: the memories and Omega's branch as at the sample before, so the output repeats
            side = 1 if st[5] > 0.5 else -1
            y_gpi = st[6]
    # training's strain part (the commanded current's travel), then creep, thermal, drift
    y_strain = y_gpi
    if has_training and tr[4] != 0.0 and not first:
        travel_i = st[10] + abs(i - st[0])
        y_strain = y_gpi + tr[4] * math.exp(-((travel_i / tr[2]) ** tr[3])) * (y_gpi - st[11])
    y = y_strain
    if creep_on and not first:
        n_sat = int(cp[1])
        n_log = int(cp[3])
        if cp[0] != 0.0:
            total = 0.0
            for m in range(n_sat):
                total += _filter_step(modes[m], st[12], y_strain, creep_gain[m], creep_decay[m], creep_active[m])
            y = y - cp[0] * (y_strain - total / n_sat)
        if cp[2] != 0.0 and n_log > 0:
            x_prev, x_now = st[12], y_strain
            if cp[4] != 0.0:  # the part creeping from the leg's end sees the held strain
                held, _ = leg_end_level(st[12], st[15], st[17], st[16])
                x_prev, x_now = st[18], (1.0 - cp[4]) * y_strain + cp[4] * held
            grown = 0.0
            for m in range(n_sat, n_sat + n_log):
                grown += _filter_step(modes[m], x_prev, x_now, creep_gain[m], creep_decay[m], creep_active[m]) - st[11]
            y = y + cp[2] * LOG_CREEP_MODE_WEIGHT * grown
    if thermal_on:
        if first:
            rise = 0.0
            rise2 = 0.0
        else:
            heating = (i / th[3]) ** 2
            rise = _filter_step(st[7], st[9], heating, thermal_c[0], thermal_c[1], thermal_c[2] > 0.5)
            rise2 = _filter_step(st[13], st[7], rise, thermal_c[3], thermal_c[4], thermal_c[5] > 0.5)
        if th[5] != 0.0 or th[6] != 0.0:
            y = y * (1.0 - th[1] * rise - th[5] * rise2) + th[2] * rise + th[6] * rise2
        else:
            y = y * (1.0 - th[1] * rise) + th[2] * rise
    y = y + drift
    return y, y_gpi, u1, u, travel, side, y_strain, width


@njit(cache=True)
def _commit(
    i,
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
    cp,
    modes,
    creep_gain,
    creep_decay,
    creep_active,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """Advance the state with the chosen current ``i``; returns the output."""
    y, y_gpi, u1, u, travel, side, y_strain, width = _evaluate(
        i,
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
        cp,
        modes,
        creep_gain,
        creep_decay,
        creep_active,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if first:
        rising_env, falling_env, excursion_env = _initial_envelopes(g, u, st[14])
        for j in range(n_ops):
            memory[j] = (  # before the first commit ``memory`` holds the held part (see _evaluate)
                initial_operator_memory(st[8], thresholds[j], rising_env, falling_env, st[14], excursion_env)
                + memory[j]
            )
        for m in range(modes.shape[0]):
            modes[m] = y_gpi
        st[15] = y_strain
        st[16] = 0.0
        st[17] = y_strain
        st[18] = y_strain
        st[7] = 0.0
        st[13] = 0.0
        st[5] = 1.0
        st[10] = 0.0
        st[11] = y_gpi
    else:
        dv = u - st[4]
        if dv > 0.0:
            env = _env(g[0], g[1], g[2], g[3], u)
            for j in range(n_ops):
                memory[j] = max(memory[j], env - thresholds[j] * width)
        elif dv < 0.0:
            env = _env(g[4], g[5], g[6], g[7], u)
            for j in range(n_ops):
                memory[j] = min(memory[j], env + thresholds[j] * width)
        if creep_on:
            n_sat = int(cp[1])
            for m in range(n_sat):
                modes[m] = _filter_step(modes[m], st[12], y_strain, creep_gain[m], creep_decay[m], creep_active[m])
            x_prev, x_now = st[12], y_strain
            if cp[4] != 0.0:
                held, direction = leg_end_level(st[12], st[15], st[17], st[16])
                x_prev, x_now = st[18], (1.0 - cp[4]) * y_strain + cp[4] * held
                st[16] = direction
                st[17] = held
                st[18] = x_now
            for m in range(n_sat, n_sat + int(cp[3])):
                modes[m] = _filter_step(modes[m], x_prev, x_now, creep_gain[m], creep_decay[m], creep_active[m])
            st[15] = st[12]
        if thermal_on:
            heating = (i / th[3]) ** 2
            previous = st[7]
            st[7] = _filter_step(st[7], st[9], heating, thermal_c[0], thermal_c[1], thermal_c[2] > 0.5)
            st[13] = _filter_step(st[13], previous, st[7], thermal_c[3], thermal_c[4], thermal_c[5] > 0.5)
        st[5] = 1.0 if dv > 0.0 else (0.0 if dv < 0.0 else st[5])  # Omega's branch: the last motion's
        st[10] = st[10] + abs(i - st[0])
    if first:
        st[2] = u1  # training's reference drive i_0
    st[0] = i
    st[1] = u1
    st[3] = travel
    st[4] = u
    st[6] = y_gpi
    st[12] = y_strain
    if thermal_on:
        st[9] = (i / th[3]) ** 2
    return y


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
    modes,
    creep_gain,
    creep_decay,
    creep_active,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """``s (y(s x) - target)`` on side ``s``, ``-inf`` off it (search coordinate ``x = s i``)."""
    y, _, _, _, _, side, _, _ = _evaluate(
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
        modes,
        creep_gain,
        creep_decay,
        creep_active,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if not first and side != s:
        return -np.inf
    return s * (y - target)


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
    modes,
    creep_gain,
    creep_decay,
    creep_active,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """The current on side ``s`` whose output meets the target, nearest ``start`` (``F`` = :func:`_objective`).

    In the search coordinate ``x = s i``:

    1. ``start`` itself when ``|F| <= htol`` there (a hold);
    2. a start off the side (a reversal: ``F = -inf``) is first moved to the side's edge
       (probes from ``start`` with steps growing 4x from ``16 xtol``, then bisection of the
       off/on transition to ``xtol``): the root nearest the previous drive lies there;
    3. probes with steps growing 4x (from ``step0``) go first where a nondecreasing ``F``
       has its root (up when ``F < 0``), then, if that direction reaches its limit or the
       side's edge without a sign change, the other way (``thermal`` can make ``F`` fall
       slowly away from an edge in a dead zone); only when neither finds a sign change is the
       bracket between the side's edge and the last point on it refined (a root can lie there
       when the drive lags the current);
    4. the first bracket is closed by Illinois regula falsi (bisection while one end is
       off the side) to ``|F| <= rtol`` or a width of ``xtol``.

    Without a sign change the evaluated point of smallest ``|F|`` is returned: a current
    limit (saturated) or the side's edge (an Omega switch). Returns ``(i, F, evaluations)``.
    """
    if s > 0:
        x_min, x_max = lo, hi
    else:
        x_min, x_max = -hi, -lo
    x0 = min(max(s * start, x_min), x_max)
    n_eval = 1
    f0 = _objective(
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
        modes,
        creep_gain,
        creep_decay,
        creep_active,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if abs(f0) <= htol:
        return s * x0, f0, n_eval
    down_done = x0 <= x_min
    if f0 == -np.inf:
        # 2. find the side's edge above x0
        off = x0
        step = 16.0 * xtol
        x = x0
        f = f0
        while f == -np.inf and x < x_max:
            off = x
            x = min(x0 + step, x_max)
            step *= 4.0
            f = _objective(
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
                modes,
                creep_gain,
                creep_decay,
                creep_active,
                thermal_on,
                th,
                thermal_c,
                drift,
            )
            n_eval += 1
        if f == -np.inf:
            return s * x0, f0, n_eval  # the side cannot be reached within the limits
        on, f_on = x, f
        for _ in range(_MAX_ITERATIONS):
            if on - off <= 16.0 * xtol:  # without input dynamics the edge is x0 itself: no bisection
                break
            x = 0.5 * (off + on)
            f = _objective(
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
                modes,
                creep_gain,
                creep_decay,
                creep_active,
                thermal_on,
                th,
                thermal_c,
                drift,
            )
            n_eval += 1
            if f == -np.inf:
                off = x
            else:
                on, f_on = x, f
        x0, f0 = on, f_on
        down_done = True
        if abs(f0) <= htol:
            return s * x0, f0, n_eval
    # 3. probe for a sign change
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
        xp, fp = x0, f0
        step = step0
        while True:
            x = min(xp + step, x_max) if direction > 0 else max(xp - step, x_min)
            step *= 4.0
            f = _objective(
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
                modes,
                creep_gain,
                creep_decay,
                creep_active,
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
        if found:
            break
    if not found and edge_found:  # no sign change on the side: the bracket at its edge
        xl, fl, xr, fr = exl, efl, exr, efr
        found = True
    if not found:
        return s * best_x, best_f, n_eval
    # 4. refine the bracket xl < xr, F changing sign: Illinois, bisection while an end is -inf
    gl, gr = fl, fr  # the values the interpolation uses (halved by Illinois)
    last = 0
    for _ in range(_MAX_ITERATIONS):
        if abs(fl) <= rtol or abs(fr) <= rtol or xr - xl <= xtol:
            break
        if gl > -np.inf and gr > -np.inf:
            x = xr - gr * (xr - xl) / (gr - gl)
            if not (xl < x < xr):
                x = 0.5 * (xl + xr)
        else:
            x = 0.5 * (xl + xr)
        f = _objective(
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
            modes,
            creep_gain,
            creep_decay,
            creep_active,
            thermal_on,
            th,
            thermal_c,
            drift,
        )
        n_eval += 1
        if (f < 0.0) == (fl < 0.0):
            xl, fl, gl = x, f, f
            if last == -1 and gr > -np.inf:
                gr *= 0.5
            last = -1
        else:
            xr, fr, gr = x, f, f
            if last == 1 and gl > -np.inf:
                gl *= 0.5
            last = 1
    if _magnitude(fl) < _magnitude(fr):
        return s * xl, fl, n_eval
    return s * xr, fr, n_eval


@njit(parallel=True, cache=True)
def _inverse_kernel(
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
        th = np.empty(7)
        th[0] = thermal[w, 0]
        th[1] = thermal[w, 1]
        th[2] = thermal[w, 2]
        th[3] = REFERENCE_CURRENT
        th[4] = thermal[w, 3]
        th[5] = thermal[w, 4]
        th[6] = thermal[w, 5]
        n_eval_total = 0
        previous_step = 0.1 * (hi - lo)
        for k in range(n_samples):
            first = k == 0
            if not first:
                h = time[k] - time[k - 1]
                gain, decay, active = _filter_coefficients(h, lag_tau[w])
                lag_c[0], lag_c[1], lag_c[2] = gain, decay, 1.0 if active else 0.0
                if creep_on:
                    for m in range(n_modes):
                        gain, decay, active = _filter_coefficients(h, creep_taus[w, m])
                        creep_gain[m], creep_decay[m], creep_active[m] = gain, decay, active
                if thermal_on:
                    gain, decay, active = _filter_coefficients(h, th[0])
                    thermal_c[0], thermal_c[1], thermal_c[2] = gain, decay, 1.0 if active else 0.0
                    gain, decay, active = _filter_coefficients(h, th[4])
                    thermal_c[3], thermal_c[4], thermal_c[5] = gain, decay, 1.0 if active else 0.0
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
                modes,
                creep_gain,
                creep_decay,
                creep_active,
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
                    modes,
                    creep_gain,
                    creep_decay,
                    creep_active,
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
            y = _commit(
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


# --------------------------------------------------------------------------------------
# Python entry
# --------------------------------------------------------------------------------------
def _effect_columns(model: Model, theta2: np.ndarray, name: str, width: int, off) -> np.ndarray:
    if name in model.effect_names:
        return np.array(theta2[:, model.effect_slice(name)], dtype=float, order="C")
    return np.array(np.broadcast_to(np.asarray(off, dtype=float), (theta2.shape[0], width)), dtype=float, order="C")


def invert(model: Model, theta, time, target, *, current_range=DEFAULT_CURRENT_RANGE, ytol=None) -> InverseResult:
    """The drive within ``current_range`` that makes ``model`` follow ``target`` (method: module docstring).

    Parameters
    ----------
    model : Model
        GPI plus effects from :data:`SUPPORTED_EFFECTS`.
    theta : array_like, shape (P,) or (W, P)
        Full parameter vectors (``model.names`` order); a batch is inverted in one
        parallel call (e.g. posterior draws).
    time : array_like, shape (T,)
        Sample times [s], strictly increasing (the dynamic effects use them).
    target : array_like, shape (T,)
        Desired output [output unit], ``T >= 2``.
    current_range : (float, float), default (0, 5)
        ``(lo, hi)`` limits of the drive [input unit], ``lo < hi``.
    ytol : float, optional
        Output tolerance of each root find; default ``1e-12 (1 + max|target|)``.

    Returns
    -------
    InverseResult

    Raises
    ------
    ValueError
        Malformed arguments, or an effect without an inverse step here (named).
    """
    if not isinstance(model, Model):
        raise ValueError(f"model must be a model.Model, got {type(model).__name__}")
    unsupported = [e for e in model.effect_names if e not in SUPPORTED_EFFECTS]
    if unsupported:
        raise ValueError(
            f"no inverse for the effect(s) {', '.join(map(repr, unsupported))}: model.inverse knows "
            f"{', '.join(SUPPORTED_EFFECTS)}"
        )
    theta = np.asarray(theta, dtype=float)
    single = theta.ndim == 1
    theta2 = np.ascontiguousarray(np.atleast_2d(theta))
    if theta2.ndim != 2 or theta2.shape[1] != model.n_parameters or theta2.shape[0] < 1:
        raise ValueError(
            f"theta must have shape ({model.n_parameters},) or (W, {model.n_parameters}) for {model!r}, got "
            f"{theta.shape}"
        )
    if not np.isfinite(theta2).all():
        raise ValueError("theta has a non-finite value")
    time = np.ascontiguousarray(time, dtype=float)
    target = np.ascontiguousarray(target, dtype=float)
    if time.ndim != 1 or target.shape != time.shape or time.size < 2:
        raise ValueError(f"time and target must both have shape (T,) with T >= 2, got {time.shape} and {target.shape}")
    if not (np.isfinite(time).all() and np.isfinite(target).all()):
        raise ValueError("time and target must be finite")
    if not (np.diff(time) > 0).all():
        raise ValueError("time must be strictly increasing")
    try:
        lo, hi = (float(x) for x in current_range)
    except (TypeError, ValueError):
        raise ValueError(f"current_range must be two numbers (lo, hi), got {current_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"current_range must satisfy lo < hi (finite), got {current_range!r}")
    if ytol is None:
        ytol = 1e-9 * (1.0 + float(np.max(np.abs(target))))
    ytol = float(ytol)
    if not (ytol > 0 and math.isfinite(ytol)):
        raise ValueError(f"ytol must be a positive finite number, got {ytol!r}")

    n_sets = theta2.shape[0]
    gpi_theta = np.ascontiguousarray(theta2[:, : len(THETA_NAMES)])
    z0 = np.ascontiguousarray(_effect_columns(model, theta2, "initial_state", 2, [0.0, 0.0])[:, :2])  # level, excursion
    held = np.zeros((n_sets, int(model.n_operators)))
    if "initial_state" in model.effect_names:
        effect = model.effects[model.effect_names.index("initial_state")]
        held = np.ascontiguousarray(
            effect.initial_held(theta2[:, model.effect_slice("initial_state")], model.n_operators)
        )
    lag = _effect_columns(model, theta2, "lag", 2, [0.0, 0.0])
    if np.any(lag[:, 1] != 0.0):
        rows = np.flatnonzero(lag[:, 1] != 0.0)
        raise ValueError(
            f"no inverse for lag's dead time (lag_delay = {lag[rows[0], 1]:.4g} s in parameter set {int(rows[0])}): "
            "the current at a sample acts on the output only a dead time later, which a per-sample inverse "
            "cannot reach; model.inverse inverts the first-order lag (lag_tau) alone"
        )
    lag_tau = np.ascontiguousarray(lag[:, 0])
    has_training = "training" in model.effect_names
    training = _effect_columns(model, theta2, "training", 6, [0.0, 0.0, 2.0, 1.0, 0.0, 0.0])
    if has_training and not ((training[:, 2] > 0).all() and (training[:, 3] > 0).all() and (training[:, 1] >= 0).all()):
        raise ValueError("training: training_threshold >= 0 and training_travel, training_shape > 0 are required")
    creep_on = "creep" in model.effect_names
    creep = _effect_columns(model, theta2, "creep", 6, [0.0, 1.0, 1.0, 0.0, 0.1, 0.0])
    if creep_on:
        saturating = creep_time_constants(creep[:, 1], creep[:, 2])
        if saturating.shape[1] != CREEP_MODES:  # pragma: no cover - consistency
            raise ValueError("creep modes mismatch")
        log_taus, n_log = log_creep_time_constants(creep[:, 4], float(time[-1] - time[0]))
        log_taus = np.where(np.arange(log_taus.shape[1])[None, :] < n_log[:, None], log_taus, 1.0)
        creep_taus = np.ascontiguousarray(np.hstack([saturating, log_taus]))
        creep_params = np.ascontiguousarray(
            np.column_stack(
                [
                    creep[:, 0],
                    np.full(n_sets, float(saturating.shape[1])),
                    creep[:, 3],
                    n_log.astype(float),
                    creep[:, 5],
                ]
            )
        )
    else:
        creep_taus = np.ones((n_sets, 1))
        creep_params = np.zeros((n_sets, 5))
    thermal_on = "thermal" in model.effect_names
    thermal = _effect_columns(model, theta2, "thermal", 6, [30.0, 0.0, 0.0, 300.0, 0.0, 0.0])
    # the sensor drift is an offset per sample whatever its form: the effect's own output on 0
    drift = np.zeros((n_sets, time.size))
    if "sensor_drift" in model.effect_names:
        effect = model.effects[model.effect_names.index("sensor_drift")]
        drift = np.ascontiguousarray(
            effect.output(theta2[:, model.effect_slice("sensor_drift")], time, np.zeros_like(time), drift), dtype=float
        )

    current = np.empty((n_sets, time.size))
    output = np.empty((n_sets, time.size))
    status = np.empty((n_sets, time.size), dtype=np.int8)
    evaluations = np.zeros(n_sets, dtype=np.int64)
    _inverse_kernel(
        gpi_theta,
        int(model.n_operators),
        READINGS[model.reading],
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
        current,
        output,
        status,
        evaluations,
    )
    if single:
        current, output, status = current[0], output[0], status[0]
    return InverseResult(current, output, status, target, (lo, hi), ytol, evaluations)
