r"""Library of physical effects that can be added to the GPI model (see :mod:`model.composite`).

Every effect registers itself in :data:`model.composite.EFFECTS` with
:func:`~model.composite.register_effect`, names its parameters ``<effect>_<what>`` with
physical units and bounds, has an exact ``off`` setting (the model is then the plain GPI
bit for bit) and a typical "on" setting (:meth:`get_test_parameters`).

``lag`` (input)
    :math:`\tau_L \dot v = i - v`, the GPI sees :math:`u(t) = v(t - d)` (first order plus dead time)
``training`` (input)
    excursion :math:`i - i_0` less :math:`F f`, times :math:`1 - g f`; thresholds times :math:`1 + w f`; strain
    excursion times :math:`1 + s f`; :math:`f = e^{-(V/V_0)^p}`, :math:`V` the drive's travel
``rate_width`` (input)
    thresholds :math:`r_j (1 + b g)` (:math:`b \ge 0`) or :math:`r_j / (1 + |b| g)` (:math:`b < 0`),
    :math:`g = \ln(1 + c|\dot u|)/c`: rate-dependent hysteresis
``initial_state`` (state)
    operators' initial memory from a level :math:`z^0` and a prior excursion
``incomplete_reset`` (output)
    :math:`y = y_g + A (n + q)`: extra strain on the virgin loading, fraction :math:`R` kept after unloading, fading
    with travel
``creep`` (output)
    saturating spectrum :math:`y_g - A(y_g - \tfrac1M\sum_m s_m)` plus logarithmic creep :math:`\gamma` per decade
    after each change (or from the end of its leg)
``thermal`` (output)
    two nodes :math:`\tau_T \dot\vartheta_1 = (i/i_\mathrm{ref})^2 - \vartheta_1`,
    :math:`\tau_2 \dot\vartheta_2 = \vartheta_1 - \vartheta_2`,
    :math:`y = y_g (1 - S\vartheta_1 - S_2\vartheta_2) + E\vartheta_1 + E_2\vartheta_2`
``sensor_drift`` (output)
    :math:`y = y_g + D_1 s + D_2 s^2 + D_w (1 - e^{-t/\tau_w})`, :math:`s = (t - t_0)/(t_{T-1} - t_0)`

Output-stage effects act in the order incomplete reset, creep, thermal, sensor drift (the
registration order): the first-cycle strain and creep belong to the strain, temperature
scales the strain and adds expansion, and the sensor drifts on top of everything.

Each effect is written in a general physical form whose earlier, simpler form is a special
case (its extra amplitudes 0): the test parameters (:meth:`get_test_parameters`) are that
simpler form. Each docstring says which parameters trade off with each other or with the
GPI; ``docs/effects.md`` gives the measured Jacobian ranks on the paper's input.

All first-order filters use the actual sample times (no assumed sampling rate) and the
exact solution of :math:`\tau \dot u = x - u` for an input that is linear between
samples (:func:`first_order_lowpass`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .composite import Effect, register_effect
from .gpi import kernel_array
from .parameters import Parameter, ParameterSet

__all__ = [
    "Lag",
    "Training",
    "RateWidth",
    "InitialState",
    "Creep",
    "Thermal",
    "SensorDrift",
    "IncompleteReset",
    "first_order_lowpass",
    "delayed_lowpass",
    "log_creep_time_constants",
    "incomplete_reset_strain",
    "creep_time_constants",
    "thermal_rise",
    "accumulated_travel",
    "drive_rate",
    "rate_threshold_scale",
    "training_fade",
    "REFERENCE_CURRENT",
    "CREEP_MODES",
    "LOG_CREEP_MODES_PER_DECADE",
]

#: Current [A] at which the normalised heating (i / i_ref)^2 is 1: the paper's 5 A excitation.
REFERENCE_CURRENT = 5.0
#: Number of relaxation modes spanning the creep spectrum.
CREEP_MODES = 9
#: Logarithmic creep: modes per decade of time constant, each weighing 1/this decades.
LOG_CREEP_MODES_PER_DECADE = 2
#: Weight [decades] of each logarithmic-creep mode.
LOG_CREEP_MODE_WEIGHT = 1.0 / LOG_CREEP_MODES_PER_DECADE
#: Logarithmic creep modes reach this multiple of the record's duration (it keeps growing over the whole record).
LOG_CREEP_REACH = 10.0
#: Most logarithmic-creep modes (a 1 ms onset on a 70 s record needs 12).
LOG_CREEP_MAX_MODES = 24


# -- numerical core ------------------------------------------------------------------


@njit(cache=True, inline="always")
def _lowpass_step(state, x_prev, x_now, step, tau):
    r"""One exact step of :math:`\tau \dot u = x - u` with ``x`` linear over the step.

    With slope :math:`s = (x_k - x_{k-1})/h` and :math:`a = e^{-h/\tau}`:
    :math:`u_k = x_k - \tau s (1 - a) + a (u_{k-1} - x_{k-1})`. ``tau <= 0`` returns
    ``x_now`` (no filter).
    """
    if tau <= 0.0:
        return x_now
    ratio = step / tau
    decay = math.exp(-ratio)  # the one transcendental call per step
    if ratio > 1e-3:
        gain = (1.0 - decay) / ratio  # relative rounding error < 2e-13
    else:  # (1 - e^-x)/x by its series; truncation error < x^5/720 < 2e-18
        gain = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)))
    return x_now - (x_now - x_prev) * gain + decay * (state - x_prev)


@njit(parallel=True, cache=True)
def _lowpass_kernel(time, signal, tau, initial, out):
    """``out[w] = lowpass(signal[w or 0], tau[w])`` starting from ``initial[w]``."""
    n_sets = out.shape[0]
    n_samples = out.shape[1]
    row_step = 0 if signal.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        state = initial[w]
        out[w, 0] = state
        for k in range(1, n_samples):
            state = _lowpass_step(state, signal[row, k - 1], signal[row, k], time[k] - time[k - 1], tau[w])
            out[w, k] = state


@njit(cache=True, inline="always")
def _lowpass_coefficients(step, tau):
    """``(decay, gain)`` of :func:`_lowpass_step` for one step (``tau > 0``)."""
    ratio = step / tau
    decay = math.exp(-ratio)
    if ratio > 1e-3:
        gain = (1.0 - decay) / ratio
    else:
        gain = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)))
    return decay, gain


#: Most distinct sample steps for which the filters tabulate their coefficients
#: (:func:`_distinct_steps`); a record with more computes them at every sample.
MAX_DISTINCT_STEPS = 64
#: The creep kernel keeps a step's coefficients until the sample step changes by more than
#: this share of itself.
CREEP_STEP_HOLD = 1e-12


@njit(cache=True)
def _distinct_steps(time, max_distinct, hold=0.0):
    """``(steps, index)``: the distinct values of ``time[k] - time[k-1]`` (first
    occurrence order) and, for ``k >= 1``, ``index[k]`` with ``steps[index[k]]`` that
    step (exactly: equal floats); ``index[0] = 0``. Empty ``steps`` when there are more
    than ``max_distinct`` (then no table pays).

    ``hold > 0``: a step is kept while the sample step differs from it by at most ``hold``
    of itself (:func:`_creep_kernel`'s rule, :data:`CREEP_STEP_HOLD`), and
    ``steps[index[k]]`` is the step kept at sample ``k``; a new one is looked up (exactly)
    when the rule lets go."""
    n_samples = time.shape[0]
    steps = np.empty(max_distinct)
    index = np.zeros(n_samples, dtype=np.int64)
    n_distinct = 0
    last = 0
    for k in range(1, n_samples):
        step = time[k] - time[k - 1]
        if n_distinct > 0 and abs(step - steps[last]) <= hold * step:  # the common case: the step kept
            index[k] = last
            continue
        found = -1
        for m in range(n_distinct):
            if steps[m] == step:
                found = m
                break
        if found < 0:
            if n_distinct == max_distinct:
                return steps[:0], index
            steps[n_distinct] = step
            found = n_distinct
            n_distinct += 1
        index[k] = found
        last = found
    return steps[:n_distinct], index


@njit(cache=True, inline="always")
def _lowpass_table(steps, tau, decay, gain):
    """Fill ``decay[m], gain[m]`` with :func:`_lowpass_step`'s coefficients for ``steps[m]``
    (``tau > 0``): the same operations, so a tabulated step equals the direct one bit for bit."""
    for m in range(steps.shape[0]):
        ratio = steps[m] / tau
        a = math.exp(-ratio)
        decay[m] = a
        if ratio > 1e-3:
            gain[m] = (1.0 - a) / ratio
        else:
            gain[m] = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)))


@njit(cache=True, inline="always")
def _thermal_lane(rise, rise2, x_prev, x_now, gain1, decay1, gain2, decay2, y, s, e, s2, e2):
    """One sample of one parameter set of :func:`_thermal_kernel` (both nodes, tabulated
    coefficients): ``(rise, rise2, output)``, the kernel's operations in its order."""
    previous = rise
    rise = x_now - (x_now - x_prev) * gain1 + decay1 * (rise - x_prev)
    rise2 = rise - (rise - previous) * gain2 + decay2 * (rise2 - previous)
    return rise, rise2, y * (1.0 - s * rise - s2 * rise2) + e * rise + e2 * rise2


@njit(cache=True)
def _thermal_four(
    w0, index, steps, heating, tau, sensitivity, expansion, tau2, sensitivity2, expansion2, displacement, out
):
    """Parameter sets ``w0 .. w0 + 3`` of :func:`_thermal_kernel` in lockstep (both nodes,
    tabulated): four independent recursions interleaved, so one's latency hides behind the
    others'; each set's operations are those of :func:`_thermal_one`, bit for bit."""
    n_samples = displacement.shape[1]
    n_steps = steps.shape[0]
    a1 = np.empty((4, n_steps))
    g1 = np.empty((4, n_steps))
    a2 = np.empty((4, n_steps))
    g2 = np.empty((4, n_steps))
    for lane in range(4):
        _lowpass_table(steps, tau[w0 + lane], a1[lane], g1[lane])
        _lowpass_table(steps, tau2[w0 + lane], a2[lane], g2[lane])
    w1, w2, w3 = w0 + 1, w0 + 2, w0 + 3
    s0, s1, s2, s3 = sensitivity[w0], sensitivity[w1], sensitivity[w2], sensitivity[w3]
    e0, e1, e2, e3 = expansion[w0], expansion[w1], expansion[w2], expansion[w3]
    t0, t1, t2, t3 = sensitivity2[w0], sensitivity2[w1], sensitivity2[w2], sensitivity2[w3]
    f0, f1, f2, f3 = expansion2[w0], expansion2[w1], expansion2[w2], expansion2[w3]
    for lane in range(4):
        w = w0 + lane
        out[w, 0] = displacement[w, 0] * (1.0 - sensitivity[w] * 0.0) + expansion[w] * 0.0
    r0 = r1 = r2 = r3 = 0.0
    q0 = q1 = q2 = q3 = 0.0
    for k in range(1, n_samples):
        m = index[k]
        x_prev = heating[k - 1]
        x_now = heating[k]
        r0, q0, y0 = _thermal_lane(
            r0, q0, x_prev, x_now, g1[0, m], a1[0, m], g2[0, m], a2[0, m], displacement[w0, k], s0, e0, t0, f0
        )
        r1, q1, y1 = _thermal_lane(
            r1, q1, x_prev, x_now, g1[1, m], a1[1, m], g2[1, m], a2[1, m], displacement[w1, k], s1, e1, t1, f1
        )
        r2, q2, y2 = _thermal_lane(
            r2, q2, x_prev, x_now, g1[2, m], a1[2, m], g2[2, m], a2[2, m], displacement[w2, k], s2, e2, t2, f2
        )
        r3, q3, y3 = _thermal_lane(
            r3, q3, x_prev, x_now, g1[3, m], a1[3, m], g2[3, m], a2[3, m], displacement[w3, k], s3, e3, t3, f3
        )
        out[w0, k] = y0
        out[w1, k] = y1
        out[w2, k] = y2
        out[w3, k] = y3


@njit(cache=True)
def _thermal_one(
    w, time, steps, index, heating, tau, sensitivity, expansion, tau2, sensitivity2, expansion2, displacement, out
):
    """Parameter set ``w`` of :func:`_thermal_kernel`, alone (any case)."""
    n_samples = displacement.shape[1]
    n_steps = steps.shape[0]
    tabulated = n_steps > 0
    second = sensitivity2[w] != 0.0 or expansion2[w] != 0.0
    table1 = tabulated and tau[w] > 0.0
    table2 = tabulated and tau2[w] > 0.0
    decay1 = np.empty(n_steps)
    gain1 = np.empty(n_steps)
    decay2 = np.empty(n_steps)
    gain2 = np.empty(n_steps)
    if table1:
        _lowpass_table(steps, tau[w], decay1, gain1)
    if table2 and second:
        _lowpass_table(steps, tau2[w], decay2, gain2)
    rise = 0.0
    rise2 = 0.0
    out[w, 0] = displacement[w, 0] * (1.0 - sensitivity[w] * rise) + expansion[w] * rise
    for k in range(1, n_samples):
        previous = rise
        x_prev = heating[k - 1]
        x_now = heating[k]
        if table1:
            m = index[k]
            rise = x_now - (x_now - x_prev) * gain1[m] + decay1[m] * (rise - x_prev)
        else:
            rise = _lowpass_step(rise, x_prev, x_now, time[k] - time[k - 1], tau[w])
        if second:
            if table2:
                m = index[k]
                rise2 = rise - (rise - previous) * gain2[m] + decay2[m] * (rise2 - previous)
            else:
                rise2 = _lowpass_step(rise2, previous, rise, time[k] - time[k - 1], tau2[w])
            out[w, k] = (
                displacement[w, k] * (1.0 - sensitivity[w] * rise - sensitivity2[w] * rise2)
                + expansion[w] * rise
                + expansion2[w] * rise2
            )
        else:
            out[w, k] = displacement[w, k] * (1.0 - sensitivity[w] * rise) + expansion[w] * rise


@njit(parallel=True, cache=True)
def _thermal_kernel(time, heating, tau, sensitivity, expansion, tau2, sensitivity2, expansion2, displacement, out):
    """Two-node thermal network: ``rise`` (node 1) low-passes ``heating``, ``rise2`` (node 2)
    low-passes ``rise`` (both from 0); ``out = displacement (1 - S rise - S2 rise2) + E rise + E2 rise2``.
    Node 2 is skipped (exactly the one-node form) where both of its gains are 0.

    With at most :data:`MAX_DISTINCT_STEPS` distinct sample steps (uniform sampling has a
    handful, differing in the last bits) each node's filter coefficients are computed
    once per distinct step and parameter set (:func:`_distinct_steps`) instead of one
    ``exp`` per sample, bit-identical to :func:`_lowpass_step` at every sample. Groups of
    four parameter sets with both nodes on and tabulated run in lockstep
    (:func:`_thermal_four`: the recursion is latency-bound), the rest one by one
    (:func:`_thermal_one`); the values are the same either way."""
    n_sets = displacement.shape[0]
    steps, index = _distinct_steps(time, MAX_DISTINCT_STEPS)
    tabulated = steps.shape[0] > 0
    n_groups = (n_sets + 3) // 4
    for g in prange(n_groups):
        w0 = 4 * g
        w_end = min(w0 + 4, n_sets)
        lockstep = tabulated and w_end - w0 == 4
        for w in range(w0, w_end):
            if not (tau[w] > 0.0 and tau2[w] > 0.0 and (sensitivity2[w] != 0.0 or expansion2[w] != 0.0)):
                lockstep = False
        if lockstep:
            _thermal_four(
                w0,
                index,
                steps,
                heating,
                tau,
                sensitivity,
                expansion,
                tau2,
                sensitivity2,
                expansion2,
                displacement,
                out,
            )
        else:
            for w in range(w0, w_end):
                _thermal_one(
                    w,
                    time,
                    steps,
                    index,
                    heating,
                    tau,
                    sensitivity,
                    expansion,
                    tau2,
                    sensitivity2,
                    expansion2,
                    displacement,
                    out,
                )


@njit(cache=True, inline="always")
def _leg_end_level(y_prev, y_before, held, last_direction):
    """``(held, direction)`` after the sample ``y_prev`` (the one before it ``y_before``): the
    output at the end of the last completed leg, a stop (``y_prev == y_before``) or a reversal
    (the change's direction flips: the leg ended at ``y_before``), known once the sample after
    it is; ``held`` and ``last_direction`` (+1, -1, 0 before any change) are the values so far.
    :func:`_creep_kernel` and :mod:`model.inverse` (``creep_log_hold``) share it."""
    change = y_prev - y_before
    if change == 0.0:
        return y_prev, last_direction
    direction = 1.0 if change > 0.0 else -1.0
    if last_direction != 0.0 and direction != last_direction:
        held = y_before
    return held, direction


@njit(parallel=True, cache=True)
def _creep_kernel(time, displacement, amplitude, taus, log_rate, log_taus, n_log, hold, out):
    """Creep of each row of ``displacement``: ``taus.shape[1]`` equal-weight saturating modes
    (amplitude ``amplitude[w]``) plus ``n_log[w]`` logarithmic-creep modes ``log_taus[w, :n_log[w]]``
    of weight :data:`LOG_CREEP_MODE_WEIGHT` decades each (rate ``log_rate[w]`` per decade),
    which follow ``(1 - hold[w])`` times the displacement plus ``hold[w]`` times the
    displacement at the end of the last completed leg (``creep_log_hold``).
    A part whose amplitude is 0 is skipped. The per-step decay is recomputed only when the step
    changes by more than :data:`CREEP_STEP_HOLD` (1e-12) of itself (uniform sampling: once per mode). With at most
    :data:`MAX_DISTINCT_STEPS` distinct steps under that rule (:func:`_distinct_steps`; a CSV
    record at 1 kHz changes its step in the last bits at most samples but has about 16
    distinct steps) each mode's coefficients are computed once per distinct step and
    parameter set instead of at every change (a change then copies the step's row), the
    same values bit for bit."""
    n_sets = displacement.shape[0]
    n_samples = displacement.shape[1]
    n_modes = taus.shape[1]
    n_log_max = log_taus.shape[1]
    steps, index = _distinct_steps(time, MAX_DISTINCT_STEPS, CREEP_STEP_HOLD)
    n_table = steps.shape[0]
    tabulated = n_table > 0
    for w in prange(n_sets):
        modes = np.empty(n_modes)
        logs = np.empty(n_log_max)
        decay_table = np.empty((max(n_table, 1), n_modes + n_log_max))
        gain_table = np.empty((max(n_table, 1), n_modes + n_log_max))
        for i in range(n_table):
            for m in range(n_modes):
                if taus[w, m] > 0.0:
                    a, g = _lowpass_coefficients(steps[i], taus[w, m])
                    decay_table[i, m] = a
                    gain_table[i, m] = g
            for m in range(n_log[w]):
                a, g = _lowpass_coefficients(steps[i], log_taus[w, m])
                decay_table[i, n_modes + m] = a
                gain_table[i, n_modes + m] = g
        decay = np.empty(n_modes + n_log_max)
        gain = np.empty(n_modes + n_log_max)
        spectrum = amplitude[w] != 0.0
        logarithmic = log_rate[w] != 0.0 and n_log[w] > 0
        held_part = hold[w] != 0.0
        y0 = displacement[w, 0]
        held = y0
        last_direction = 0.0
        x_prev = y0
        for m in range(n_modes):
            modes[m] = y0  # at rest at the start: every mode at equilibrium
        for m in range(n_log_max):
            logs[m] = y0
        out[w, 0] = y0
        last_step = -1.0
        for k in range(1, n_samples):
            step = time[k] - time[k - 1]
            if abs(step - last_step) > CREEP_STEP_HOLD * step:
                last_step = step
                if tabulated:  # the table's row of this step (index[k]: the step itself here)
                    row = index[k]
                    for m in range(n_modes + n_log[w]):
                        decay[m] = decay_table[row, m]
                        gain[m] = gain_table[row, m]
                else:
                    for m in range(n_modes):
                        if taus[w, m] > 0.0:
                            a, g = _lowpass_coefficients(step, taus[w, m])
                            decay[m] = a
                            gain[m] = g
                    for m in range(n_log[w]):
                        a, g = _lowpass_coefficients(step, log_taus[w, m])
                        decay[n_modes + m] = a
                        gain[n_modes + m] = g
            y_prev = displacement[w, k - 1]
            y_now = displacement[w, k]
            value = y_now
            if spectrum:
                total = 0.0
                for m in range(n_modes):
                    if taus[w, m] > 0.0:
                        modes[m] = y_now - (y_now - y_prev) * gain[m] + decay[m] * (modes[m] - y_prev)
                    else:
                        modes[m] = y_now
                    total += modes[m]
                value -= amplitude[w] * (y_now - total / n_modes)
            if logarithmic:
                x_before, x_now = y_prev, y_now
                if held_part:
                    # the part ``hold`` of each leg's change creeps from the leg's end: the modes
                    # see the output held there
                    y_before = displacement[w, k - 2] if k >= 2 else y0
                    held, last_direction = _leg_end_level(y_prev, y_before, held, last_direction)
                    x_before, x_now = x_prev, (1.0 - hold[w]) * y_now + hold[w] * held
                    x_prev = x_now
                grown = 0.0
                for m in range(n_log[w]):
                    j = n_modes + m
                    logs[m] = x_now - (x_now - x_before) * gain[j] + decay[j] * (logs[m] - x_before)
                    grown += logs[m] - y0
                value += log_rate[w] * LOG_CREEP_MODE_WEIGHT * grown
            out[w, k] = value


@njit(parallel=True, cache=True)
def _delay_kernel(time, signal, lagged, tau, delay, out):
    """``out[w, k]`` = the first-order lag of ``signal`` (``lagged[w]`` at the samples) at time
    ``t_k - delay[w]``: from the sample ``m`` before it, an exact partial step with the signal
    linear between samples; ``signal[row, 0]`` (at rest) before the record's start."""
    n_sets = out.shape[0]
    n_samples = out.shape[1]
    row_step = 0 if signal.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        d = delay[w]
        if d <= 0.0:
            for k in range(n_samples):
                out[w, k] = lagged[w, k]
            continue
        m = 0
        for k in range(n_samples):
            target = time[k] - d
            if target <= time[0]:
                out[w, k] = signal[row, 0]
                continue
            while m + 1 < n_samples and time[m + 1] <= target:
                m += 1
            if m + 1 >= n_samples or target == time[m]:
                out[w, k] = lagged[w, m]
                continue
            step = time[m + 1] - time[m]
            part = target - time[m]
            x_target = signal[row, m] + (signal[row, m + 1] - signal[row, m]) * (part / step)
            out[w, k] = _lowpass_step(lagged[w, m], signal[row, m], x_target, part, tau[w])


@njit(parallel=True, cache=True)
def _incomplete_reset_kernel(current, excursion, strain, retained, fade, out_extra):
    """Extra strain of :class:`IncompleteReset` per row (see its docstring), shape ``(W, T)``:
    ``excursion[w]`` is row ``w``'s strain excursion from its first value, ``current`` the
    drive whose travel fades the retained part.

    The excursion levels set on a virgin loading and not reset since are kept as a stack of
    disjoint intervals ``[low, high]`` (ascending); an unloading to ``e`` resets every set
    level above ``e`` (it pops or cuts the top intervals), a new largest excursion sets the
    levels between the previous largest and it. Each level is pushed and popped at most
    once per new excursion, so the cost is linear in the samples."""
    n_sets = out_extra.shape[0]
    n_samples = out_extra.shape[1]
    row_step = 0 if excursion.shape[0] == 1 else 1
    for w in prange(n_sets):
        row = w * row_step
        scale = 0.0
        for k in range(n_samples):
            scale = max(scale, excursion[row, k])
        out_extra[w, 0] = 0.0
        if not scale > 0.0:
            for k in range(1, n_samples):
                out_extra[w, k] = 0.0
            continue
        low = np.empty(n_samples)
        high = np.empty(n_samples)
        count = 0
        reached = 0.0  # largest excursion so far (the virgin territory)
        unreset = 0.0  # measure of the set levels the spring has not reset yet
        kept = 0.0  # retained part (normalised)
        previous = excursion[row, 0]
        for k in range(1, n_samples):
            e = excursion[row, k]
            if kept != 0.0 and fade[w] > 0.0:
                kept *= math.exp(-fade[w] * abs(current[k] - current[k - 1]))
            if e > reached:
                if count > 0 and high[count - 1] == reached:
                    high[count - 1] = e
                else:
                    low[count] = reached
                    high[count] = e
                    count += 1
                unreset += e - reached
                reached = e
            elif e < previous:
                while count > 0 and high[count - 1] > e:
                    if low[count - 1] >= e:
                        moved = high[count - 1] - low[count - 1]
                        count -= 1
                    else:
                        moved = high[count - 1] - e
                        high[count - 1] = e
                    unreset -= moved
                    kept += retained[w] * moved / scale
            previous = e
            out_extra[w, k] = strain[w] * (max(unreset, 0.0) / scale + kept)


def first_order_lowpass(time, signal, tau, initial=None):
    r"""Exact first-order low-pass :math:`\tau \dot u = x - u` of a piecewise-linear signal.

    Parameters
    ----------
    time : array_like, shape (T,)
        Sample times [s], strictly increasing (steps may vary).
    signal : array_like, shape (T,) or (W, T)
        Input :math:`x` at the samples, taken as linear between them.
    tau : float or array_like, shape (W,)
        Time constants [s]; ``tau <= 0`` passes the signal through unchanged.
    initial : float or array_like of shape (W,), optional
        :math:`u(t_0)`; default ``x(t_0)`` (at rest).

    Returns
    -------
    ndarray, shape (W, T)
        :math:`u` at the samples; ``W`` is the larger of the batch sizes given.
    """
    time = np.ascontiguousarray(time, dtype=float)
    signal2 = np.ascontiguousarray(np.atleast_2d(np.asarray(signal, dtype=float)))
    if time.ndim != 1 or signal2.ndim != 2 or signal2.shape[1] != time.size:
        raise ValueError(
            f"time must be (T,) and signal (T,) or (W, T) with the same T; got {time.shape}, {np.shape(signal)}"
        )
    tau = np.atleast_1d(np.asarray(tau, dtype=float))
    n_sets = max(signal2.shape[0], tau.size)
    if signal2.shape[0] not in (1, n_sets) or tau.size not in (1, n_sets):
        raise ValueError(f"signal has {signal2.shape[0]} rows and tau {tau.size} values: they must match or be 1")
    tau = np.broadcast_to(tau, (n_sets,))  # the kernel call makes it contiguous and writeable
    if initial is None:
        initial = signal2[:, 0]
    initial = np.broadcast_to(np.asarray(initial, dtype=float), (n_sets,))
    out = np.empty((n_sets, time.size))
    _lowpass_kernel(kernel_array(time), kernel_array(signal2), kernel_array(tau), kernel_array(initial), out)
    return out


def delayed_lowpass(time, signal, tau, delay):
    r"""First order plus dead time: :math:`\tau \dot u = x - u`, read at :math:`t - d`.

    The lag is :func:`first_order_lowpass` (exact for a signal linear between samples);
    its value at :math:`t_k - d` is reached from the sample before that time by an exact
    partial step, so a delay that is not a whole number of samples is resolved with the
    same accuracy as the lag itself, and the output is continuous in :math:`d` (with
    :math:`\tau > 0` also its derivative: the lag's response to a piecewise-linear signal
    is continuously differentiable in time). Before the record's start the system is at
    rest: :math:`u = x(t_0)`.

    Parameters
    ----------
    time : array_like, shape (T,)
        Sample times [s], strictly increasing.
    signal : array_like, shape (T,) or (W, T)
    tau : float or array_like, shape (W,)
        Time constants [s]; 0 is no lag (then the delayed signal is the linear
        interpolation of ``signal``).
    delay : float or array_like, shape (W,)
        Dead time [s], ``>= 0``; 0 returns the lag itself, bit for bit.

    Returns
    -------
    ndarray, shape (W, T)
    """
    time = np.ascontiguousarray(time, dtype=float)
    signal2 = np.ascontiguousarray(np.atleast_2d(np.asarray(signal, dtype=float)))
    tau = np.atleast_1d(np.asarray(tau, dtype=float))
    delay = np.atleast_1d(np.asarray(delay, dtype=float))
    n_sets = max(signal2.shape[0], tau.size, delay.size)
    if delay.size not in (1, n_sets):
        raise ValueError(f"delay has {delay.size} values for {n_sets} rows")
    if np.any(~np.isfinite(delay)) or np.any(delay < 0):
        raise ValueError("the dead time must be finite and >= 0")
    lagged = first_order_lowpass(time, signal2, np.broadcast_to(tau, (n_sets,)) if tau.size == 1 else tau)
    if lagged.shape[0] != n_sets:
        lagged = np.ascontiguousarray(np.broadcast_to(lagged, (n_sets, time.size)))
    delay = np.broadcast_to(delay, (n_sets,))  # the kernel call makes it contiguous and writeable
    if not np.any(delay > 0):
        return lagged
    tau_rows = np.broadcast_to(tau, (n_sets,))
    out = np.empty((n_sets, time.size))
    _delay_kernel(
        kernel_array(time),
        kernel_array(signal2),
        kernel_array(lagged),
        kernel_array(tau_rows),
        kernel_array(delay),
        out,
    )
    return out


def log_creep_time_constants(onset, duration):
    r"""Time constants of the logarithmic-creep modes: :math:`\tau_j = t_0\,10^{j/2}`, :math:`j = 1, 2, \ldots`

    up to the first one at or beyond :data:`LOG_CREEP_REACH` times the record's
    ``duration`` (at most :data:`LOG_CREEP_MAX_MODES`). With each mode weighing half a
    decade, :math:`\sum_j \tfrac12 (1 - e^{-t/\tau_j})` follows :math:`\log_{10}(1 + t/t_0)`
    within 0.05 for :math:`t \ge 10\,t_0` up to about the longest mode (and rises as
    :math:`0.4\,t/t_0` below :math:`t_0`): a step keeps creeping by a constant amount per
    decade of elapsed time over the whole record.

    Parameters
    ----------
    onset : array_like, shape (W,)
        :math:`t_0` [s], > 0.
    duration : float
        Record length [s].

    Returns
    -------
    taus : ndarray, shape (W, J)
        Rows padded with 0 past their count.
    counts : ndarray of int64, shape (W,)
    """
    onset = np.atleast_1d(np.asarray(onset, dtype=float))
    reach = LOG_CREEP_REACH * max(float(duration), 1e-300)
    counts = np.clip(
        np.ceil(LOG_CREEP_MODES_PER_DECADE * np.log10(np.maximum(reach / onset, 1.0 + 1e-12))), 1, LOG_CREEP_MAX_MODES
    ).astype(np.int64)
    width = int(counts.max()) if counts.size else 1
    j = np.arange(1, width + 1)
    taus = onset[:, None] * 10.0 ** (j[None, :] / LOG_CREEP_MODES_PER_DECADE)
    taus[j[None, :] > counts[:, None]] = 0.0
    return np.ascontiguousarray(taus), counts


def creep_time_constants(tau, decades, n_modes=CREEP_MODES):
    r"""The creep modes' time constants :math:`\tau_m = \tau \cdot 10^{d\,(m/(M-1) - 1/2)}`.

    Parameters
    ----------
    tau : float or array_like, shape (W,)
        Central time constant [s] (geometric mean of the modes').
    decades : float or array_like, shape (W,)
        Width ``d`` of the spectrum in decades; 0 collapses every mode onto ``tau``.
    n_modes : int, default :data:`CREEP_MODES`

    Returns
    -------
    ndarray, shape (W, n_modes)
    """
    tau = np.atleast_1d(np.asarray(tau, dtype=float))
    decades = np.atleast_1d(np.asarray(decades, dtype=float))
    position = np.linspace(-0.5, 0.5, n_modes) if n_modes > 1 else np.zeros(1)
    return tau[:, None] * 10.0 ** (decades[:, None] * position[None, :])


def thermal_rise(time, current, tau):
    r"""Normalised temperature rise :math:`\vartheta`: :math:`\tau \dot\vartheta = (i/i_\mathrm{ref})^2 - \vartheta`,
    :math:`\vartheta(t_0) = 0`.

    Parameters
    ----------
    time : array_like, shape (T,)
        [s].
    current : array_like, shape (T,)
        Coil current [A]; the Joule heating :math:`i^2 R` is normalised by
        :data:`REFERENCE_CURRENT` and taken as linear between samples.
    tau : float or array_like, shape (W,)
        Thermal time constant [s].

    Returns
    -------
    ndarray, shape (W, T)
        :math:`\vartheta`, dimensionless; 1 is the steady rise under a constant 5 A.
    """
    heating = (np.asarray(current, dtype=float) / REFERENCE_CURRENT) ** 2
    return first_order_lowpass(time, heating, tau, initial=0.0)


def accumulated_travel(drive):
    r"""Accumulated travel of a drive since the record's start, :math:`V_k = \sum_{m=1}^{k} |u_m - u_{m-1}|`.

    Parameters
    ----------
    drive : array_like, shape (T,) or (W, T)
        Drive at the samples [A].

    Returns
    -------
    ndarray, shape (W, T)
        :math:`V` [A], 0 at the first sample, non-decreasing (``W = 1`` for a 1-D drive).
    """
    drive2 = np.atleast_2d(np.asarray(drive, dtype=float))
    if drive2.ndim != 2:
        raise ValueError(f"drive must have shape (T,) or (W, T), got {np.shape(drive)}")
    travel = np.zeros(drive2.shape)
    np.cumsum(np.abs(np.diff(drive2, axis=1)), axis=1, out=travel[:, 1:])
    return travel


def training_fade(travel, travel_scale, shape):
    r"""The first-cycle fade :math:`f = \exp(-(V/V_0)^p)` of :class:`Training`.

    Parameters
    ----------
    travel : array_like, shape (W, T)
        Accumulated drive travel :math:`V` [A] (:func:`accumulated_travel`).
    travel_scale : array_like, shape (W, 1) or scalar
        :math:`V_0` [A], > 0.
    shape : array_like, shape (W, 1) or scalar
        :math:`p` (dimensionless), > 0: 1 an exponential fade, large a step at :math:`V_0`,
        about 2.4 close to a linear fade to 0 at about :math:`1.6 V_0`.

    Returns
    -------
    ndarray, shape (W, T)
        :math:`f`, 1 at :math:`V = 0`, non-increasing, :math:`1/e` at :math:`V = V_0`.
    """
    return np.exp(-((np.asarray(travel, dtype=float) / travel_scale) ** shape))


def _column(params, i):
    """Column ``i`` of a ``(W, k)`` parameter array as a contiguous float ``(W,)`` array."""
    return np.ascontiguousarray(np.asarray(params, dtype=float)[:, i])


# -- effects -------------------------------------------------------------------------


@register_effect
class Lag(Effect):
    r"""Rate dependence: the field-equivalent drive lags the coil current (first order plus dead time).

    .. math::  \tau_L \frac{dv}{dt} = i(t) - v(t), \quad v(t_0) = i(t_0), \qquad u(t) = v(t - d)

    and the GPI sees :math:`u` instead of :math:`i` (:math:`u = i(t_0)` for
    :math:`t - d < t_0`: at rest before the record). Physics: the magnetic field in the
    air gap is set by the flux, which follows the current through the magnetic circuit's
    inductance and, in a solid (non-laminated) steel core such as the paper's S215,
    through eddy currents that oppose flux changes; to first order both give a
    first-order lag (e.g. the eddy-current time constant of a solid core). The dead time
    :math:`d` is the latency of the chain outside the magnetics: the power source's
    control loop, the DAC/ADC pipeline of the control and acquisition system (the paper's
    dSPACE), a sensor's filter group delay: the displacement belongs to an earlier
    current than the one recorded with it. A higher-order lag (several cascaded poles,
    amplifier plus core) is close to one pole plus a dead time (the usual FOPDT reduction),
    so this form absorbs both a smooth lag and a pure delay.
    Discretised exactly for a current linear between samples, with the actual time steps;
    a delay that is not a whole number of samples is read by an exact partial step of the
    lag (:func:`delayed_lowpass`), so the output is continuous in :math:`d` (and, with
    :math:`\tau_L > 0`, differentiable): a least-squares solver can move it smoothly.

    What the dead time does to the GPI's reversals: the GPI is rate independent, so a pure
    delay moves its output in time, :math:`y(t) = \mathrm{GPI}[i](t - d)`, every reversal
    (and the memory wiped there) :math:`d` later; nothing else changes. With a delay that
    is not a whole number of samples the drive is read between samples, so a reversal's
    peak value is the linear interpolation there: an input peak can be cut by up to
    (slope change) x (sample step), a minor-loop tip slightly lower than the recorded
    peak (the continuous-time drive's true peak is not a sample either). The lag instead
    rounds a reversal off and lowers its peak by about :math:`\tau_L` x the slope.

    Trade-offs: for a slowly varying drive, a lag :math:`\tau_L` and a delay
    :math:`d = \tau_L` give nearly the same drive (both shift the response by
    :math:`\tau_L`; they differ at the reversals and in the amplitude of fast
    components), so ``lag_tau`` and ``lag_delay`` are strongly correlated, separated by
    the reversals' shape. Neither is a reparametrisation of the GPI (rate independent:
    no GPI parameter moves a branch in time). Measured Jacobian rank on the paper's
    input (``docs/effects.md``).

    The dead time is an optional term (:attr:`Effect.terms` ``dead_time``): a study pins it
    at 0 where the record does not support it (a compensation cannot invert a dead time,
    :mod:`model.inverse`).

    Parameters: ``lag_tau`` [s], ``0 <= lag_tau <= 5``; ``lag_delay`` [s],
    ``0 <= lag_delay <= 0.5``. Off: both 0 (the drive is the current itself).
    """

    name = "lag"
    stage = "input"
    parameters = ParameterSet(
        [
            Parameter("lag_tau", 0.0, 0.0, 5.0, unit="s", description="time constant of the field behind the current"),
            Parameter("lag_delay", 0.0, 0.0, 0.5, unit="s", description="dead time of drive and acquisition"),
        ]
    )
    off = {"lag_tau": 0.0, "lag_delay": 0.0}
    summary = "coil/eddy-current lag plus dead time: tau dv/dt = i - v, the hysteresis sees u(t) = v(t - d)"
    terms = {"dead_time": ("lag_delay",)}
    signature = (
        "the output lags the input by the same time at every cycle and amplitude, so a drive of another "
        "frequency changes the loop's width in proportion"
    )

    @classmethod
    def get_test_parameters(cls):
        return {"lag_tau": 0.05, "lag_delay": 0.0}

    def drive(self, params, time, current):
        """Lagged, delayed drive ``u``, shape ``(W, T)`` [A]; ``current`` may be ``(T,)`` or ``(W, T)``."""
        params = np.asarray(params, dtype=float)
        tau = _column(params, 0)
        delay = _column(params, 1)
        return delayed_lowpass(time, current, tau, delay)


@register_effect
class Training(Effect):
    r"""First-cycle (training) effect: the virgin material responds differently until cycling trains it.

    .. math::

        f_k = e^{-(V_k / V_0)^p}, \qquad V_k = \sum_{m=1}^{k} |i_m - i_{m-1}|, \qquad
        \Delta_k = i_k - i_0,

        u_k = i_0 + \operatorname{sign}(\Delta_k)\,\max(|\Delta_k| - F f_k,\ 0)\,(1 - g f_k),
        \qquad r_{j,k} = r_j (1 + w f_k), \qquad y_k = y_{g,k} + s f_k\,(y_{g,k} - y_{g,0})

    The GPI sees the drive :math:`u` (after ``lag``'s, when both are present: then
    :math:`i` is the lagged drive) with its play thresholds :math:`r_j` widened by
    :math:`1 + w f` (the weights stay those of eq. (8)), and its output :math:`y_g` is
    scaled about its first value (before the output-stage effects). :math:`V` is the drive's accumulated travel
    since the record's start [A] (:func:`accumulated_travel`; the strain part counts the
    commanded current's travel), so the difference fades with the cycling the material has
    done, not with time (a pause does not train it); :math:`f` (:func:`training_fade`) is
    1 on the virgin material and falls to :math:`1/e` after :math:`V_0` of travel. The GPI
    describes the trained material (:math:`f = 0`); the virgin one differs in four ways:
    :math:`i_0` is the drive at the first sample (0 A on the paper's record) and the
    excursion from it is reduced by the extra threshold :math:`F f` (a soft threshold:
    nothing moves until the drive exceeds it) and scaled by :math:`1 - g f`; its hysteresis
    is wider (every play threshold :math:`1 + w f` times the trained one); and the strain
    excursion is :math:`1 + s f` times the trained one. The unenergised start
    (:math:`\Delta = 0`, :math:`y = y_{g,0}`) is untouched.

    Physics: in the virgin (untrained) state the twin boundaries of the MSM crystal must
    first be nucleated or activated, so the first field-induced reorientation needs a
    higher magnetic stress than in the trained material, whose mobile boundaries are
    already there; cycling trains the crystal and the difference fades (training lowers
    the twinning stress of Ni-Mn-Ga: e.g. Chmielus et al., "Effects of surface roughness
    and training on the twinning stress of Ni-Mn-Ga single crystals", Acta Mater. 58,
    2010); a lower twinning stress is a narrower hysteresis, so the loops narrow as the
    material trains. Cycling also changes how much of the crystal reorients per cycle (the twin
    structure coarsens or refines, some variants stop taking part), so the strain
    amplitude drifts from the virgin to the trained value over the first cycles. The paper
    (sec. "Magnetic shape memory materials") reports a first cycle that differs from the
    later ones: the return spring "is not sufficiently large to provide crystal lattice
    reorientation ... thus that after first cycle maximum strain is reduced".
    :math:`F > 0`: an extra field threshold; :math:`g > 0`: the virgin material lacks the
    fraction :math:`g` of the drive (the first rising branch is delayed and stretched);
    :math:`w > 0`: the virgin loops are wider and narrow with cycling. All three are a
    higher twinning stress of the virgin material, so they are never negative (``g, F, w
    >= 0``): a virgin material that needed *less* field than the trained one, or had
    narrower loops, would be no training but another physics (an untrained material does
    not move its twin boundaries more easily). The signs do not make training
    identifiable on their own: on an input that starts with its largest excursion, its
    part of the fit lies almost wholly in the first loading, where a prior state or an
    output gap looks the same (a raised initial memory is still fitted by training with
    these bounds; ``docs/diagnosis.md``, Limits). :math:`s > 0`: the virgin material's
    strain excursion is larger by the fraction :math:`s` and shrinks toward the trained one
    with cycling (the paper's "maximum strain is reduced"), :math:`s < 0`: it grows. The
    fade's shape :math:`p` makes the general form absorb other laws of the same physics: 1
    is exponential in the travel, about 2.4 close to a linear fade to 0 after about
    :math:`1.6 V_0` (fitted to a linear fade over 20 A on the bench: :math:`V_0` =
    12.4-13.1 A, :math:`p` = 2.3-2.4), 8 nearly a step at :math:`V_0` (e.g. at the first
    reversal). :math:`V_0` reaches 50 A, about the paper record's whole travel (47.5 A):
    a training that goes on over several cycles is then seen as a difference that is
    still fading at the record's end.

    What the GPI cannot do: its first (virgin) branch is tied to all later branches by the
    same parameters, and its amplitude is the same on every cycle. Trade-offs: a
    *constant* drive scale or shift, or a constant strain scale, is an exact
    reparametrisation of the GPI (absorbed by the tanh slopes a1, b1, c1, d1, arguments
    a2, b2, c2, d2 and the weights :math:`\rho`, :math:`c_0`, :math:`d_0`), so the effect
    is identified only through its fading: as :math:`V_0 \to 0` (trained at once) and as
    :math:`V_0 \to \infty` (never trained) it stops being identifiable. Within the
    record's travel the fade is seen, and the bounds keep :math:`V_0` there. The strain
    scale :math:`s` and the drive scale :math:`g` trade off partly (both change the
    virgin loops' amplitude; only :math:`g` moves the branches along the current axis);
    the width :math:`w` and the threshold :math:`F` both delay the virgin rising branch,
    but only :math:`w` also advances the falling one. A constant width is an exact
    reparametrisation of the GPI (:math:`\alpha` and :math:`\tau` of eq. (8) take it, or,
    with :math:`\alpha` pinned, the envelopes and weights), so :math:`w` too is identified
    only through its fading.
    Neither the GPI's return-point memory nor ``initial_state`` (an exact
    reparametrisation, wiped out by the first full excursion) represents the effect.
    Measured on the virtual bench (paper input, Table 1, :math:`g = 0.08`,
    :math:`V_0 = 2` A, :math:`p = 1`: 1.94 noise sigmas RMS against the plain GPI at the
    same parameters, sigma = 0.5 um, seed 0), the best plain-GPI refit leaves 1.42 sigma RMS
    over the energised part (a larger share than lag, creep, thermal or drift leave of
    theirs: the GPI cannot bend its first branch away from the later ones).

    Why not the plain drive shift :math:`u = i - F e^{-V/V_0}` (measured first): it moves
    the unenergised start, where :math:`V = 0` and the whole shift acts (F = 0.3 A moved
    the rest level by 23 um, 46 sigmas: a change of the sensor's zero that no field can
    cause), and a negative shift drives a GPI calibrated up to the record's largest current
    beyond it at the first peak (Table 1 leaves its domain above 5 A). The soft threshold
    and the scale about :math:`i_0` leave the rest state alone and, for :math:`g, F \ge 0`,
    keep the drive between :math:`i_0` and :math:`i`.

    Parameters: ``training_deficit`` :math:`g` (dimensionless), ``0 <= g <= 0.5``;
    ``training_threshold`` :math:`F` [A], ``0 <= F <= 2``; ``training_travel`` :math:`V_0`
    [A], ``0.5 <= V_0 <= 50``; ``training_shape`` :math:`p`, ``0.5 <= p <= 8``;
    ``training_gain`` :math:`s` (dimensionless), ``-0.5 <= s <= 0.5``; ``training_width``
    :math:`w` (dimensionless), ``0 <= w <= 1``. Off: ``g = F = s = w = 0`` (the drive is
    the current, the thresholds those of eq. (8) and the output the GPI's, bit for bit,
    whatever :math:`V_0`, :math:`p`).

    Optional terms (:attr:`Effect.terms`): each of the four virgin differences (``drive``
    :math:`g`, ``threshold`` :math:`F`, ``strain`` :math:`s`, ``width`` :math:`w`) and the
    fade's ``shape`` (pinned at :math:`p = 1`, the exponential fade). A record seldom shows
    all four: a gain that decays with the cycles is :math:`s` and :math:`V_0` alone, and
    neither the study's posterior nor the diagnosis's delta BIC should carry the other
    gains (at 0, each of them leaves :math:`V_0` to the rest) or charge for them.
    """

    name = "training"
    stage = "input"
    acts_on_output = True
    first_cycle = True
    terms = {
        "drive": ("training_deficit",),
        "threshold": ("training_threshold",),
        "strain": ("training_gain",),
        "width": ("training_width",),
        "shape": ("training_shape",),
    }
    parameters = ParameterSet(
        [
            Parameter(
                "training_deficit",
                0.0,
                0.0,
                0.5,
                unit="",
                description="fraction of the drive the virgin material lacks (its higher twinning stress)",
            ),
            Parameter(
                "training_threshold",
                0.0,
                0.0,
                2.0,
                unit="A",
                description="extra drive the virgin material needs before it responds at all",
            ),
            Parameter(
                "training_travel",
                2.0,
                0.5,
                50.0,
                unit="A",
                description="accumulated drive travel over which the first-cycle difference fades by 1/e",
            ),
            Parameter(
                "training_shape",
                1.0,
                0.5,
                8.0,
                unit="",
                description="exponent of the fade exp(-(V/V0)^p): 1 exponential, large a step at V0",
            ),
            Parameter(
                "training_gain",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="fraction by which the virgin strain excursion exceeds the trained one (negative: falls "
                "short)",
            ),
            Parameter(
                "training_width",
                0.0,
                0.0,
                1.0,
                unit="",
                description="fraction by which the virgin play width (every threshold) exceeds the trained one",
            ),
        ]
    )
    off = {
        "training_deficit": 0.0,
        "training_threshold": 0.0,
        "training_travel": 2.0,
        "training_shape": 1.0,
        "training_gain": 0.0,
        "training_width": 0.0,
    }
    summary = (
        "first-cycle training: excursion soft-thresholded by F f and scaled by 1 - g f, play width "
        "1 + w f, strain excursion scaled by 1 + s f, f = exp(-(V/V0)^p)"
    )
    signature = (
        "the response changes with the cycling the material has done (the drive's accumulated travel), "
        "not with time or power, and never comes back"
    )

    @classmethod
    def get_test_parameters(cls):
        return {
            "training_deficit": 0.2,
            "training_threshold": 0.0,
            "training_travel": 2.0,
            "training_shape": 1.0,
            "training_gain": 0.0,
            "training_width": 0.0,
        }

    @staticmethod
    def _check(params):
        params = np.asarray(params, dtype=float)
        threshold, travel_scale, shape = params[:, 1], params[:, 2], params[:, 3]
        bad = ~(np.isfinite(params).all(axis=1) & (travel_scale > 0) & (shape > 0) & (threshold >= 0))
        if bad.any():
            raise ValueError(
                "training: the parameters must be finite, training_threshold >= 0 and training_travel, "
                f"training_shape > 0; parameter set(s) {np.flatnonzero(bad)[:5].tolist()} are not "
                f"({params[bad][:3].tolist()})"
            )
        return params

    @staticmethod
    def _fade(params, drive):
        """The fade ``f`` of the travel of ``drive`` (shape ``(T,)`` or ``(W, T)``), shape ``(W, T)``.

        On one drive row the fade depends on a set's ``(V0, p)`` only, so it is computed
        once per distinct pair (a Jacobian's batch varies them in two rows of its P + 1):
        the same values, element by element."""
        travel = accumulated_travel(drive)
        if travel.shape[0] != 1 or params.shape[0] == 1:
            return training_fade(travel, params[:, 2:3], params[:, 3:4])
        pairs, row_of = np.unique(params[:, 2:4], axis=0, return_inverse=True)
        return training_fade(travel, pairs[:, 0:1], pairs[:, 1:2])[row_of.reshape(-1)]

    def drive(self, params, time, current):
        """Drive with the fading first-cycle difference, shape ``(W, T)`` [A]; ``current`` may be ``(T,)`` or ``(W,
        T)``."""
        params = self._check(params)
        deficit, threshold = params[:, 0:1], params[:, 1:2]
        drive = np.atleast_2d(np.asarray(current, dtype=float))
        if drive.shape[0] not in (1, params.shape[0]):
            raise ValueError(f"training: the drive has {drive.shape[0]} rows for {params.shape[0]} parameter sets")
        fade = self._fade(params, drive)
        excursion = drive - drive[:, 0:1]
        # soft threshold: the excursion less F f toward the start (0 inside the threshold)
        kept = np.sign(excursion) * np.maximum(np.abs(excursion) - threshold * fade, 0.0)
        # u = i - (excursion - kept (1 - g f)); every term 0 when g = F = 0, so u == i bit for bit
        return drive - (excursion - kept * (1.0 - deficit * fade))

    def threshold_scale(self, params, time, drive):
        """The play width in force, ``1 + w f`` on every threshold, shape ``(W, T)``; None where ``w = 0``."""
        params = self._check(params)
        width = params[:, 5:6]
        if not width.any():
            return None
        return 1.0 + width * self._fade(params, drive)

    def output(self, params, time, current, displacement):
        """The GPI's output with the virgin strain excursion scaled by ``1 + s f``, shape ``(W, T)`` [um]."""
        params = self._check(params)
        y = np.atleast_2d(np.asarray(displacement, dtype=float))
        gain = params[:, 4:5]
        if not gain.any():  # off: the displacement itself, bit for bit
            return y
        return y + gain * self._fade(params, current) * (y - y[:, 0:1])


def drive_rate(time, drive):
    """The drive's rate over each sample step, ``|u_k - u_{k-1}| / (t_k - t_{k-1})`` [A/s], 0 at the first sample.

    The play operators' update at sample ``k`` moves the drive from ``u_{k-1}`` to ``u_k``;
    for a drive linear between samples this is its rate during that step, exactly, with the
    actual time steps. ``drive`` may be ``(T,)`` or ``(W, T)``; the result is ``(W, T)``."""
    time = np.asarray(time, dtype=float)
    drive = np.atleast_2d(np.asarray(drive, dtype=float))
    rate = np.zeros_like(drive)
    rate[:, 1:] = np.abs(np.diff(drive, axis=1)) / np.diff(time)[None, :]
    return rate


def rate_threshold_scale(rate, coefficient, saturation=0.0):
    r"""The factor on every play threshold at a drive rate, shape of ``rate`` broadcast with the parameters.

    With :math:`g(r) = \ln(1 + c\,r)/c` (:math:`g(r) = r` at :math:`c = 0`, its limit):
    :math:`1 + b\,g(|\dot u|)` for :math:`b \ge 0` and :math:`1 / (1 + |b|\,g(|\dot u|))` for
    :math:`b < 0`: positive for every rate, continuous with a continuous derivative in
    :math:`b` at 0 (both branches are :math:`1 + b\,g + O(b^2)`), and the two signs are each
    other's reciprocal, so a narrowing is as general as a widening. ``saturation``
    :math:`c \ge 0` [s/A] bends the law from linear (below :math:`1/c`) to logarithmic
    (above it)."""
    coefficient = np.asarray(coefficient, dtype=float)
    saturation = np.asarray(saturation, dtype=float)
    cr = saturation * rate
    # ln(1 + c r) / c, written to be exact (r itself) at c = 0 and accurate for small c r
    bent = np.where(saturation > 0.0, np.log1p(cr) / np.where(saturation > 0.0, saturation, 1.0), rate)
    grow = 1.0 + np.abs(coefficient) * bent
    return np.where(coefficient >= 0.0, grow, 1.0 / grow)


@register_effect
class RateWidth(Effect):
    r"""Rate-dependent hysteresis: every play threshold changes with the drive's rate.

    .. math::

        r_{j,k} = r_j\, s_k, \qquad s_k = \begin{cases} 1 + b\,g(|\dot u_k|) & b \ge 0 \\
        1 / (1 + |b|\,g(|\dot u_k|)) & b < 0 \end{cases}, \qquad
        g(r) = \frac{\ln(1 + c\,r)}{c}, \qquad
        |\dot u_k| = \frac{|u_k - u_{k-1}|}{t_k - t_{k-1}}

    The GPI's thresholds :math:`r_j = \alpha j` of eq. (8) are scaled at each sample by a
    factor that depends on the drive's rate during the step into it (:func:`drive_rate`:
    exact for a drive linear between samples, with the actual time steps); the drive
    itself, the envelopes and the weights are unchanged. :math:`u` is the drive the GPI
    sees (after ``lag``'s, when both are present: the rate of the field, not of the
    recorded current). Physics: the twin boundaries of an MSM crystal move against a
    friction that grows with their velocity (a viscous twinning stress on top of the
    static one), and their velocity follows the field's rate, so a faster drive needs a
    larger field change before the strain follows: the hysteresis is rate dependent, and
    the loops of the same amplitude differ between frequencies (e.g. Henry, Bono,
    Feuchtwanger, Allen and O'Handley, "ac field-induced actuation of Ni-Mn-Ga", J. Appl.
    Phys. 91, 2002; rate-dependent Prandtl-Ishlinskii operators with thresholds that are
    functions of the input rate: Ang, Khosla and Riviere, IEEE/ASME Trans. Mechatronics
    12, 2007; Al Janaideh, Rakheja and Su, Mechatronics 19, 2009). The paper drives at
    0.1 Hz, where a rate-independent GPI fits; on its decaying sine the rate falls with the
    amplitude, so a rate-dependent width shows itself as loops that change shape within
    a cycle (widest where the drive crosses zero fastest) and from cycle to cycle.

    The law of the rate: :math:`g(r) = r` (:math:`c = 0`, the limit) is a friction linear
    in the boundaries' velocity (viscous); :math:`c > 0` bends it to a logarithm above the
    rate :math:`1/c`, the kinetic relation of a thermally activated motion, whose velocity
    grows exponentially with the driving stress, so the stress grows with the logarithm of
    the velocity (twin-wall kinetics in Ni-Mn-Ga: Faran and Shilo, J. Mech. Phys. Solids
    59, 2011): a rate dependence that levels off at fast drives. The bend is an optional
    term (:attr:`Effect.terms` ``saturation``): while it is 0 the law is the linear one.

    Sign: with the paper's negative thresholds (:math:`\alpha < 0`) the loop is the
    envelopes' gap less :math:`2|r_j|`, so a threshold that grows (:math:`b > 0`) narrows
    the loop; with the classical positive thresholds it widens it. :math:`b` is therefore
    signed, and the narrowing branch is the reciprocal of the widening one, so the factor
    stays positive at every rate and the model is smooth in :math:`b` through 0.

    What the GPI cannot do: it is rate independent (its output depends on the drive's
    path, not on its speed). Trade-offs: a *constant* factor on every threshold is an
    exact reparametrisation of the GPI (:math:`\alpha` takes it, or, with :math:`\alpha`
    pinned, the envelopes and weights), so :math:`b` is identified only through the
    rate's variation within a cycle and between cycles. ``lag`` also makes the loop depend
    on the rate (a delayed drive shifts every branch in time, and so in current by the
    rate times the delay), but it moves every branch by the same time, reversals included,
    where this effect changes the operators' widths and leaves the reversals in place; on
    one record at one frequency the two are correlated, and a drive of another frequency
    separates them. A heating that follows :math:`i^2` with a fast time constant is, on a
    pure sine, an affine function of :math:`\dot i^2` (:math:`\dot i^2 = \omega^2 (A^2 -
    i^2)`), so the two are correlated there too; the heating acts on the strain's gain and
    offset, this effect on the loop's width. The rate is read from the drive as recorded:
    a drive measured with noise gives a noisy rate (a low-pass ``lag`` on the drive
    smooths it).

    Trade-offs within the effect: :math:`b` and :math:`c` trade off where the record's rates
    are all below :math:`1/c` (the law is linear there whatever :math:`c`) or all far above
    it (a logarithm's scale and offset); while :math:`b = 0`, :math:`c` does nothing.

    Parameters: ``rate_width_coefficient`` :math:`b` [s/A], ``-2 <= b <= 2``;
    ``rate_width_saturation`` :math:`c` [s/A], ``0 <= c <= 20`` (at 20 the bend starts at
    0.05 A/s). Off: ``b = 0`` (every threshold that of eq. (8), bit for bit, whatever
    :math:`c`).
    """

    name = "rate_width"
    stage = "input"
    parameters = ParameterSet(
        [
            Parameter(
                "rate_width_coefficient",
                0.0,
                -2.0,
                2.0,
                unit="s/A",
                description="relative change of every play threshold per unit drive rate (negative: the reciprocal)",
            ),
            Parameter(
                "rate_width_saturation",
                0.0,
                0.0,
                20.0,
                unit="s/A",
                description="bend of the rate law, ln(1 + c r)/c: linear below the rate 1/c, logarithmic above it",
            ),
        ]
    )
    off = {"rate_width_coefficient": 0.0, "rate_width_saturation": 0.0}
    terms = {"saturation": ("rate_width_saturation",)}
    summary = (
        "rate-dependent thresholds: r_j (1 + b g) for b >= 0, r_j / (1 + |b| g) for b < 0, "
        "g = ln(1 + c |du/dt|)/c (|du/dt| at c = 0)"
    )
    signature = (
        "the loop's width changes with the drive's rate, within a cycle and with the amplitude, and leaves the "
        "reversals where they are"
    )

    @classmethod
    def get_test_parameters(cls):
        return {"rate_width_coefficient": 0.1, "rate_width_saturation": 0.0}

    def drive(self, params, time, current):
        """The drive itself (this effect changes only the thresholds), shape ``(1 or W, T)`` [A]."""
        return np.atleast_2d(np.asarray(current, dtype=float))

    def threshold_scale(self, params, time, drive):
        """The factor on every threshold at each sample, shape ``(W, T)``; None where ``b = 0`` for every set."""
        params = np.asarray(params, dtype=float)
        coefficient, saturation = params[:, 0:1], params[:, 1:2]
        bad = ~(np.isfinite(params).all(axis=1) & (params[:, 1] >= 0.0))
        if bad.any():
            raise ValueError(
                "rate_width: the parameters must be finite and rate_width_saturation >= 0; parameter set(s) "
                f"{np.flatnonzero(bad)[:5].tolist()} are not ({params[bad][:3].tolist()})"
            )
        if not coefficient.any():
            return None
        return rate_threshold_scale(drive_rate(time, drive), coefficient, saturation)


@register_effect
class InitialState(Effect):
    r"""First-cycle state: the memory the record starts from, left by the sample's history.

    Before the record the sample was driven (a previous test, the mounting, a magnet
    nearby): its operators start with the memory that history left. A PI model's memory is
    a staircase of the past extremes the later motion has not wiped out; the record's own
    first large excursion wipes the narrow operators, so what can outlast it is the *last
    reversal before the record*; a history outside the drive can leave more. This effect
    is that history in three parts:

    * a **level** :math:`z^0` every operator's memory is clamped from (the state before
      any excursion):

      .. math::  z_j^c = \max\big(\gamma_\uparrow(v_0) - r_j,\ \min(\gamma_\downarrow(v_0) + r_j,\ z^0)\big);

    * a **prior excursion** :math:`e`: the drive went from :math:`v_0` to :math:`v_0 + e`
      and back before :math:`t_0`, and the play law carried the memory along (for
      :math:`e > 0`):

      .. math::  z_j(t_0) = \min\big(\gamma_\downarrow(v_0) + r_j,\ \max(z_j^c,\ \gamma_\uparrow(v_0 + e) - r_j)\big),

      and the mirror image for :math:`e < 0` (:func:`model.gpi.gpi`'s
      ``initial_memory`` and ``initial_excursion``). The narrow operators end on the
      return branch, the middle ones keep the excursion's peak, the widest keep the level:
      a memory profile over the widths that no level alone gives.

    * a **held memory** :math:`h_j = h + s\, j/N` added after the clamp and the excursion,
      not clamped (:func:`model.gpi.gpi`'s ``initial_held``). A history outside the drive (a
      pre-strain when the sample was mounted, a test at another pre-stress or temperature,
      a magnet nearby) can leave the lattice in a state the drive cannot leave at
      :math:`v_0`: a memory beyond its bounds. The play law moves a memory only when a bound
      passes it, so a memory above its upper bound is kept through the first loading and
      cut at the first unloading (below its lower bound: the mirror). The first loading then
      rides on extra strain that the first unloading gives back. The level :math:`h` and the
      slope :math:`s` over the operators' widths (the wide operators keeping more, or less,
      of that history) are the first two terms of any held profile.

    The paper: the pre-tensioned return spring "is not sufficiently large to provide
    crystal lattice reorientation ... thus that after first cycle maximum strain is
    reduced", i.e. the first loading of a sample differs from later ones; what the first
    cycle starts from is the history before it. :math:`z^0 \to -\infty`, :math:`e = 0`,
    :math:`h = s = 0` resets every operator to its lower bound (fully virgin); all 0 is the
    paper's state.

    **Identifiability.** The level alone is *not identifiable next to a GPI with free
    offsets* (any input, any size): shifting both envelope offsets (``a3``, ``b3``) by
    :math:`s` shifts every bound and memory by :math:`s`; lowering both :math:`\Omega`
    offsets (``c3``, ``d3``) by :math:`s \sum_j p_j` restores the output; with
    :math:`s = -z^0` (clipped to the bounds' range) the plain GPI's level 0 gives exactly
    the same output (:data:`identify.diagnosis.diagnose.GPI_EQUIVALENTS`; measured: z0 = -20,
    293 noise sigmas against the plain GPI at the same parameters, is fitted by a plain GPI
    to ~1e-13 sigma). So ``initial_state_memory`` is **pinned by default**
    (``vary=False``); free it (``Model.with_parameters``) only where those offsets are
    pinned or carry another parametrisation (e.g. a peer's fit, whose operators start above
    their upper bounds). The excursion is not such a shift (it moves some operators and not
    others); it trades off with the thresholds' scale (which operators the excursion
    reaches) and, at small sizes, with the first cycle's shape (``training``,
    ``incomplete_reset``), and it saturates where the envelopes do (beyond the record's
    drive range larger :math:`|e|` changes nothing). The held level :math:`h` **is** the
    pinned level wherever every memory stays inside its bounds (Table 1 at 0 A: all twelve
    operators start inside; ``benchmarks/effects_identifiability.py``: 6.8e-11, round-off):
    only its part beyond an operator's bound is information, carried by the operators that
    start clamped and by sizes that take memories past their bounds (measured: a uniform
    :math:`h = 0.3` on the paper's input with two GPIs whose wide operators start clamped,
    5.7 noise sigmas visible, leaves 5.6 and 1.05 sigmas after a plain GPI refit). The
    slope is not a shift (1e-2). :math:`h` and :math:`s` trade off with each other and with the excursion
    (all three move the first loading), and with ``incomplete_reset`` and ``training``;
    a record with one first loading tells them apart only by the shape of that loading
    and of the first unloading. The paper's training effect, a maximum
    strain reduced *after* the first cycle, is a ratchet on the largest excursion so far,
    which no initial memory represents.

    Parameters: ``initial_state_memory`` [A, envelope units], ``-20 <= z0 <= 20``, pinned;
    ``initial_state_excursion`` [A, drive units], ``-20 <= e <= 20``;
    ``initial_state_held`` and ``initial_state_held_slope`` [A, envelope units],
    ``-10 <= h, s <= 10``; off: all 0.
    """

    name = "initial_state"
    stage = "state"
    first_cycle = True
    parameters = ParameterSet(
        [
            Parameter(
                "initial_state_memory",
                0.0,
                -20.0,
                20.0,
                unit="A",
                vary=False,
                description="level the operators' initial memory is clamped from (0: paper; very negative: virgin); "
                "pinned: an exact reparametrisation next to free GPI offsets",
            ),
            Parameter(
                "initial_state_excursion",
                0.0,
                -20.0,
                20.0,
                unit="A",
                description="the last reversal before the record: the drive went to v0 + e and back (0: none)",
            ),
            Parameter(
                "initial_state_held",
                0.0,
                -10.0,
                10.0,
                unit="A",
                description="memory held beyond the bounds at the start, every operator (0: none); "
                "kept until the first motion against it",
            ),
            Parameter(
                "initial_state_held_slope",
                0.0,
                -10.0,
                10.0,
                unit="A",
                description="the held memory's growth from the narrowest to the widest operator: h_j = h + s j/N",
            ),
        ]
    )
    off = {
        "initial_state_memory": 0.0,
        "initial_state_excursion": 0.0,
        "initial_state_held": 0.0,
        "initial_state_held_slope": 0.0,
    }
    summary = (
        "first-cycle state: initial operator memory from a level z0, a prior excursion to v0 + e and a memory "
        "held beyond the bounds h + s j/N (all 0 = paper)"
    )
    signature = "only the first cycles differ from the later ones, as if the sample had been driven before the record"

    @classmethod
    def get_test_parameters(cls):
        return {"initial_state_memory": -0.5}

    def initial_memory(self, params):
        """The level :math:`z^0`, shape ``(W,)`` [A]."""
        return _column(params, 0)

    def initial_excursion(self, params):
        """The prior excursion :math:`e`, shape ``(W,)`` [A]."""
        return _column(params, 1)

    def initial_held(self, params, n_operators):
        r"""The held memory :math:`h_j = h + s\, j/N`, shape ``(W, N)`` [A]."""
        width = np.arange(1, n_operators + 1) / n_operators
        return _column(params, 2)[:, None] + _column(params, 3)[:, None] * width[None, :]


@register_effect
class IncompleteReset(Effect):
    r"""First-cycle strain: extra strain on the virgin loading, partly kept after unloading.

    With :math:`e_k = |y_{g,k} - y_{g,0}|` the strain's excursion from its first value (the
    GPI's output: the reorientation the field has done), :math:`E = \max_k e_k` the
    record's largest, :math:`M_k = \max_{m \le k} e_m` the largest so far, and
    :math:`S_k` the excursion levels set by the virgin loading and not reset since,
    updated at every sample (:math:`|\cdot|` the total length of a set of levels):

    .. math::

        \text{new excursion } (e_k > M_{k-1}):\quad
            S \leftarrow S \cup (M_{k-1}, e_k]

        \text{unloading } (e_k < e_{k-1}):\quad
            \delta = \frac{|S \cap (e_k, \infty)|}{E},\quad S \leftarrow S \cap [0, e_k],\quad
            q \leftarrow q + R\,\delta

        q \leftarrow q\, e^{-\lambda |i_k - i_{k-1}|}, \qquad
        y = y_g + A\,\Big(\frac{|S|}{E} + q\Big)

    (:math:`S` empty, :math:`q = 0` at the start). So the virgin loading adds the extra
    strain :math:`A` (at the record's largest excursion, in proportion to the strain
    before it: the extra reorientation goes with the reorientation) to the GPI's response.
    Each level of it is reset when the strain comes back below that level (the spring
    pushes the lattice back that far), except the fraction :math:`R`, which stays
    (:math:`q`); a level is reset once. The extra strain is thus a function of the
    strain's state (how far it went, how low it has come back since), not of its travel:
    later cycles within the range already reached add no extra strain and ride on the
    retained :math:`R A` (plus the virgin levels below the lowest strain since, which no
    unloading has reached), fixed (:math:`\lambda = 0`) or fading with the drive's further
    travel (:math:`\lambda > 0` per unit of drive: cycling and the spring progressively
    reset the lattice). Only an excursion beyond the largest so far (virgin territory)
    adds extra strain again.

    Physics, the paper's first-cycle effect (sec. "Magnetic shape memory materials"): in
    the spring-returned mode the pretensioned spring must reorient the variants after
    the field is removed, but its "compressive force is not sufficiently large to provide
    crystal lattice reorientation which was deformed in magnetic field thus that after
    first cycle maximum strain is reduced". On the virgin loading the field reorients
    more of the crystal than on later cycles (the as-received sample starts fully
    compressed, :math:`R = 0` of the variants left over); the spring resets only part
    of it when the field goes, so the strain stays raised by the retained fraction and
    later cycles span a reduced range on top of it. This lives on the strain side (an
    incomplete reset of the lattice), unlike :class:`Training`, which changes the drive
    the virgin material needs.

    What the GPI cannot do: its first branch is tied to the later ones, and its rest
    level after the first cycle is set by the same operators. A raised level after the
    first cycle is partly within the GPI's reach (its initial memory already makes the
    virgin curve differ from later ones; :class:`InitialState` is an exact
    reparametrisation of it), so :math:`A R` trades off with the GPI's rest level
    (the Omega offsets c3, d3 and the envelope offsets) where the first cycle starts from
    rest; the transient part :math:`A (1 - R)` on the first loading does not. Within the
    effect, :math:`A` and :math:`R` are separated by the first loading (only :math:`A`
    acts there); :math:`\lambda` trades off with :math:`R` when the retained strain fades
    fast (a retained part that fades within a cycle looks like a smaller :math:`R`).
    Measured Jacobian rank with the GPI on the paper's input: ``docs/effects.md``.

    Parameters: ``incomplete_reset_strain`` :math:`A` [um] (-50-50), the extra strain of
    the virgin loading at the record's largest excursion; ``incomplete_reset_retained``
    :math:`R` (0-1), the fraction of it the unloading does not reset;
    ``incomplete_reset_fade`` :math:`\lambda` [1/A] (0-2), how fast the retained strain
    fades with the drive's travel (0: fixed). Off: :math:`A = 0`.
    """

    name = "incomplete_reset"
    stage = "output"
    first_cycle = True
    parameters = ParameterSet(
        [
            Parameter(
                "incomplete_reset_strain",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="extra strain of the virgin loading at the record's largest excursion",
            ),
            Parameter(
                "incomplete_reset_retained",
                0.5,
                0.0,
                1.0,
                unit="",
                description="fraction of the virgin extra strain that the unloading does not reset",
            ),
            Parameter(
                "incomplete_reset_fade",
                0.0,
                0.0,
                2.0,
                unit="1/A",
                description="fading of the retained strain per unit of drive travel (0: fixed)",
            ),
        ]
    )
    off = {"incomplete_reset_strain": 0.0, "incomplete_reset_retained": 0.5, "incomplete_reset_fade": 0.0}
    summary = (
        "first-cycle strain: extra strain A on the virgin loading, fraction R kept after unloading (fading with travel)"
    )
    signature = (
        "the first loading reaches further than the later ones and part of it stays after unloading; the "
        "later cycles ride on that raised level"
    )

    @classmethod
    def get_test_parameters(cls):
        return {"incomplete_reset_strain": 6.0, "incomplete_reset_retained": 0.5, "incomplete_reset_fade": 0.0}

    def output(self, params, time, current, displacement):
        """Displacement plus the first-cycle extra strain, shape ``(W, T)`` [um]."""
        params = np.asarray(params, dtype=float)
        displacement = np.atleast_2d(np.asarray(displacement, dtype=float))
        if not params[:, 0].any():  # off: the displacement itself, bit for bit
            return displacement
        extra = incomplete_reset_strain(current, displacement, params[:, 0], params[:, 1], params[:, 2])
        return displacement + extra


def incomplete_reset_strain(current, displacement, strain, retained, fade):
    """The extra strain :math:`A (n + q)` of :class:`IncompleteReset`, shape ``(W, T)`` [um].

    Parameters
    ----------
    current : array_like, shape (T,)
        Drive [A] (its travel fades the retained part).
    displacement : array_like, shape (T,) or (W, T)
        The strain the effect acts on [um] (the GPI's output): its excursion from its first
        value is the reorientation that adds the virgin extra strain.
    strain, retained, fade : array_like, shape (W,)
        :math:`A` [um], :math:`R`, :math:`\\lambda` [1/A].
    """
    current = np.ascontiguousarray(current, dtype=float)
    strain = np.ascontiguousarray(np.atleast_1d(strain), dtype=float)
    retained = np.broadcast_to(np.asarray(retained, dtype=float), strain.shape)  # the kernel call makes them
    fade = np.broadcast_to(np.asarray(fade, dtype=float), strain.shape)  # contiguous and writeable
    y = np.atleast_2d(np.asarray(displacement, dtype=float))
    if y.shape[0] not in (1, strain.size) or y.shape[1] != current.size:
        raise ValueError(
            f"incomplete_reset: the displacement has shape {y.shape} for {strain.size} parameter sets and "
            f"{current.size} samples"
        )
    excursion = np.ascontiguousarray(np.abs(y - y[:, :1]))
    out = np.zeros((strain.size, current.size))
    if current.size:
        _incomplete_reset_kernel(
            kernel_array(current), excursion, kernel_array(strain), kernel_array(retained), kernel_array(fade), out
        )
    return out


@register_effect
class Creep(Effect):
    r"""Creep: slow continued motion of the twin boundaries after the input stops or reverses.

    Two general forms met in actuators, each with an exact off setting, on top of the
    hysteretic value :math:`y_g`:

    .. math::

        y = y_g - A \Big(y_g - \frac1M \sum_{m=1}^{M} s_m\Big)
              + \gamma\, \sum_{j=1}^{J} \tfrac12\,\big(l_j - y_g(t_0)\big),

        \tau_m \dot s_m = y_g - s_m, \quad \tau_m = \tau\, 10^{\,d\,(m/(M-1) - 1/2)}, \qquad
        \tau^{\log}_j \dot l_j = y_g - l_j, \quad \tau^{\log}_j = t_0\, 10^{j/2}

    **Saturating creep** (:math:`A`, :math:`\tau`, :math:`d`; :math:`M` =
    :data:`CREEP_MODES`): after a step :math:`\Delta` of :math:`y_g` the output jumps by
    :math:`(1-A)\Delta` and creeps the rest as
    :math:`A\Delta\,(1 - \frac1M\sum_m e^{-t/\tau_m})`; the static gain is 1 (the final
    value is the GPI's), so it does not trade off with the GPI's scale. ``d = 0`` is a
    single exponential, a wide spectrum (2-4 decades) is logarithmic *within* its span.
    This is the linear creep operator of Krejci and Kuhnen (IEE Proc. Control Theory
    Appl., 2001), with the weights tied to one amplitude and a width. :math:`A` is signed,
    like :math:`\gamma`: :math:`A < 0` is the relaxation of the other sign, an output that
    moves :math:`(1 + |A|)\Delta` at once and relaxes back by :math:`|A|\Delta` over the
    spectrum (anelastic recovery: the spring and the sample's elastic part give back some
    of a fast change); as with :math:`A > 0` the final value is the GPI's.

    **Logarithmic creep** (:math:`\gamma`, :math:`t_0`): after a step :math:`\Delta` the
    output keeps growing by :math:`\gamma\Delta` per decade of elapsed time,
    :math:`\gamma\Delta \log_{10}(1 + t/t_0)` (the classical law of piezo and smart
    actuators, e.g. Jung and Gweon, Rev. Sci. Instrum. 2000), after *each* change of the
    output, superposed: a Prony series of :math:`J` modes half a decade apart reaching ten
    times the record's length (:func:`log_creep_time_constants`; within 0.05 decade-units
    of the logarithm for :math:`t \ge 10 t_0`), so it never saturates within a record.
    **When each change starts to creep** (:math:`q`, ``creep_log_hold``): the part
    :math:`q` of each leg's change starts its logarithmic creep at the leg's end instead of
    with the change, so the logarithmic modes follow :math:`(1-q)\,y_g + q\,h` instead of
    :math:`y_g`, with :math:`h` the output at the end of the last completed leg (a reversal
    or a stop of :math:`y_g`, known one sample after it). :math:`q = 0` superposes the creep
    of every increment (Boltzmann superposition); :math:`q = 1` lets the twin boundaries
    creep only once the drive stops advancing them, each leg's change :math:`\Delta_m`
    creeping by :math:`\gamma\Delta_m` per decade from its end: thermally activated motion
    takes over where the driven motion stops. A step and a hold creep the same way under
    both (from the stop); on a sine they differ by when the growth starts.
    Its instantaneous response is :math:`y_g` itself and it moves the output beyond the
    GPI's value, so over a record it trades off partly with the GPI's gain (``rho`` and
    the envelope amplitudes: a part that has grown by the same amount at every peak looks
    like a larger gain); the growth with time since each reversal separates them.
    In MSMA the twin boundaries keep moving under the constant field and spring force
    until the twinning stress balances them; thermally activated boundary motion gives
    the logarithmic law.

    Trade-offs with the other effects: a fast saturating creep (:math:`\tau` of a few sample
    steps) acts like a lag of the output (:math:`A > 0`) or a lead (:math:`A < 0`). Trade-offs
    within the effect: :math:`\tau` with :math:`d` (a wide spectrum with a shorter centre
    resembles a narrower one with a longer centre over a record), and :math:`A` with
    :math:`\gamma` where the saturating spectrum is wide (both logarithmic within the span), and
    :math:`q` with :math:`t_0` (both delay the growth after a reversal; :math:`q` has no effect
    while :math:`\gamma = 0`). Measured Jacobian rank with the GPI on the paper's input:
    ``docs/effects.md``.

    Parameters: ``creep_amplitude`` (fraction of a step that creeps, -0.5-0.5; < 0
    relaxes back),
    ``creep_tau`` [s] (central time constant, 0.01-100), ``creep_decades`` (spectrum
    width, 0-4), ``creep_log_rate`` :math:`\gamma` (fraction of a step per decade of time,
    -0.1-0.1), ``creep_log_onset`` :math:`t_0` [s] (0.001-10), ``creep_log_hold`` :math:`q`
    (part of each leg's change that creeps from the leg's end, 0-1). Off:
    ``creep_amplitude = 0`` and ``creep_log_rate = 0``; ``creep_log_hold = 0`` is the
    superposed form. The saturating and the logarithmic parts are alternative forms
    (:attr:`Effect.forms`): each is an optional term (:attr:`Effect.terms`), so a record of
    one is not charged for the other, and a fit keeps at least one.
    """

    name = "creep"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter(
                "creep_amplitude",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="fraction of a displacement step that creeps (< 0: that relaxes back after an overshoot)",
            ),
            Parameter(
                "creep_tau", 1.0, 0.01, 100.0, unit="s", description="central creep time constant (geometric mean)"
            ),
            Parameter(
                "creep_decades", 1.0, 0.0, 4.0, unit="decades", description="width of the log-spaced creep spectrum"
            ),
            Parameter(
                "creep_log_rate",
                0.0,
                -0.1,
                0.1,
                unit="",
                description="logarithmic creep: fraction of a step added per decade of elapsed time",
            ),
            Parameter(
                "creep_log_onset",
                0.1,
                0.001,
                10.0,
                unit="s",
                description="logarithmic creep: time after a change from which it grows logarithmically",
            ),
            Parameter(
                "creep_log_hold",
                0.0,
                0.0,
                1.0,
                unit="",
                description="logarithmic creep: fraction of each leg's change that starts creeping at the leg's end "
                "(a reversal or a stop)",
            ),
        ]
    )
    off = {
        "creep_amplitude": 0.0,
        "creep_tau": 1.0,
        "creep_decades": 1.0,
        "creep_log_rate": 0.0,
        "creep_log_onset": 0.1,
        "creep_log_hold": 0.0,
    }
    summary = (
        "creep: saturating log-spaced modes, y_g - A (y_g - mean s_m), plus logarithmic creep gamma per decade "
        "after each change (a part q from the end of its leg)"
    )
    signature = (
        "follows the strain: after each reversal the output keeps moving the way it last changed, also while "
        "the input is held, and stops when the strain does not change"
    )
    terms = {
        "saturating": ("creep_amplitude", "creep_tau", "creep_decades"),
        "logarithmic": ("creep_log_rate", "creep_log_onset"),
        "after_reversal": ("creep_log_hold",),
    }
    forms = ("saturating", "logarithmic")

    @classmethod
    def get_test_parameters(cls):
        return {
            "creep_amplitude": 0.05,
            "creep_tau": 2.0,
            "creep_decades": 2.0,
            "creep_log_rate": 0.0,
            "creep_log_onset": 0.1,
            "creep_log_hold": 0.0,
        }

    def output(self, params, time, current, displacement):
        """Displacement after creep, shape ``(W, T)`` [um]."""
        params = np.asarray(params, dtype=float)
        time = np.ascontiguousarray(time, dtype=float)
        amplitude = _column(params, 0)
        taus = np.ascontiguousarray(creep_time_constants(params[:, 1], params[:, 2]))
        log_rate = _column(params, 3)
        duration = float(time[-1] - time[0]) if time.size else 0.0
        log_taus, counts = log_creep_time_constants(params[:, 4], duration)
        hold = _column(params, 5)
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        _creep_kernel(
            kernel_array(time),
            kernel_array(displacement),
            kernel_array(amplitude),
            kernel_array(taus),
            kernel_array(log_rate),
            kernel_array(log_taus),
            kernel_array(counts),
            kernel_array(hold),
            out,
        )
        return out


@register_effect
class Thermal(Effect):
    r"""Joule heating of the coils changing the strain response over the run: a two-node thermal network.

    The coils dissipate :math:`i^2 R`; the coil (node 1) warms through its own time
    constant, and the sample with the core (node 2) warms from the coil through theirs:

    .. math::

        \tau_T \dot\vartheta_1 = \Big(\frac{i}{i_\mathrm{ref}}\Big)^2 - \vartheta_1, \quad
        \tau_2 \dot\vartheta_2 = \vartheta_1 - \vartheta_2, \quad
        \vartheta_{1,2}(t_0) = 0,

        y = y_g\,(1 - S\,\vartheta_1 - S_2\,\vartheta_2) + E\,\vartheta_1 + E_2\,\vartheta_2

    with :math:`i_\mathrm{ref}` = :data:`REFERENCE_CURRENT` = 5 A (the paper's excitation),
    so :math:`\vartheta = 1` is a node's steady rise under a constant 5 A. :math:`S, S_2`
    are the relative losses of field-induced strain per unit rise of each node (the
    magnetocrystalline anisotropy, hence the MSM strain, falls as the alloy warms toward
    its transformation temperatures; e.g. Heczko and Straka, J. Appl. Phys. 2003; the
    sample sits in the core, node 2, but a fast node is also what a thin sample close to
    the coil sees), :math:`E, E_2` [um] the thermal expansion seen by the sensor (coil
    former and frame follow the coil, rod and core follow node 2). :math:`\vartheta = 0`
    before the coils are energised, so the quiet start is untouched. Any linear two-node
    network (coil and sample/core, each with a heat capacity, coupled to each other and to
    the ambient) has a response of this two-pole form with two gains per output term;
    :math:`S_2 = E_2 = 0` is the one-pole form (exactly: node 2 is not computed), and a
    one-pole heating through either time constant is a special case.

    Discretised exactly for the heating linear between samples (node 1) and with node 1
    taken as linear between samples in node 2's step (error of order
    :math:`(h/\tau)^2` of a step, below 1e-6 of the rise for :math:`\tau \ge 1` s at 100 Hz).

    Symmetry: the network's output depends on the two time constants only through the
    pair :math:`\{\tau_T, \tau_2\}`: by partial fractions :math:`\vartheta_2 =
    (\tau_T \vartheta_1 - \tau_2 \vartheta_1')/(\tau_T - \tau_2)` with
    :math:`\vartheta_1'` the one-pole rise through :math:`\tau_2`, so swapping the time
    constants and mapping each gain pair :math:`(G_1, G_2) \to (G_1 \tau_2/\tau_T,\;
    G_2 + G_1 (1 - \tau_2/\tau_T))` (for :math:`G = S` and :math:`G = E`) gives the same
    output exactly (:meth:`swap_nodes`). The canonical labelling, the physical one, has
    the coil faster than the core, :math:`\tau_T \le \tau_2`; the least squares maps
    its result there and the posterior's support is that half (when all six parameters
    vary), so the posterior has one mode, not two mirror images.

    Trade-offs: the gains of a node trade off with its time constant where the record is
    much shorter than it (a rise that is still linear in time fixes only the product
    gain/tau); when node 2's gains are 0 its time constant does nothing, and a one-pole
    heating is then also node 2 behind a fast node 1 without gains (the study pins the
    core node off where the record does not support it: :attr:`terms`); the sensitivities
    scale the GPI's output, but with a rise that changes over the record, so they are not
    a reparametrisation of its gain (``rho``). Measured Jacobian rank with the GPI on the
    paper's input: ``docs/effects.md``.

    Parameters: ``thermal_tau`` [s] (1-2000), ``thermal_sensitivity`` (-0.5-0.5),
    ``thermal_expansion`` [um] (-50-50) for node 1 (the coil); ``thermal_tau_core`` [s]
    (1-5000), ``thermal_sensitivity_core`` (-0.5-0.5), ``thermal_expansion_core`` [um]
    (-50-50) for node 2 (sample and core). Off: every sensitivity and expansion 0.
    """

    name = "thermal"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter(
                "thermal_tau", 30.0, 1.0, 2000.0, unit="s", description="thermal time constant of the coil (node 1)"
            ),
            Parameter(
                "thermal_sensitivity",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="relative strain loss per unit normalised temperature rise of node 1",
            ),
            Parameter(
                "thermal_expansion",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="displacement from thermal expansion at unit normalised rise of node 1",
            ),
            Parameter(
                "thermal_tau_core",
                300.0,
                1.0,
                5000.0,
                unit="s",
                description="thermal time constant of sample and core (node 2, heated by node 1)",
            ),
            Parameter(
                "thermal_sensitivity_core",
                0.0,
                -0.5,
                0.5,
                unit="",
                description="relative strain loss per unit normalised temperature rise of node 2",
            ),
            Parameter(
                "thermal_expansion_core",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="displacement from thermal expansion at unit normalised rise of node 2",
            ),
        ]
    )
    off = {
        "thermal_tau": 30.0,
        "thermal_sensitivity": 0.0,
        "thermal_expansion": 0.0,
        "thermal_tau_core": 300.0,
        "thermal_sensitivity_core": 0.0,
        "thermal_expansion_core": 0.0,
    }
    summary = (
        "Joule heating through coil and core: tau th1' = (i/5 A)^2 - th1, tau2 th2' = th1 - th2, y = y_g (1 - "
        "S th1 - S2 th2) + E th1 + E2 th2"
    )
    signature = (
        "follows the drive's power, not the strain: builds up while current flows and decays with its time "
        "constants once the drive stops (a record that ends with the drive off for a few time constants shows it)"
    )
    terms = {"core": ("thermal_tau_core", "thermal_sensitivity_core", "thermal_expansion_core")}

    @staticmethod
    def swap_nodes(values: dict[str, float]) -> dict[str, float]:
        """The other labelling of the same output: time constants swapped, gains mapped
        (class docstring, "Symmetry"). Its own inverse; needs distinct time constants."""
        tau1, tau2 = values["thermal_tau"], values["thermal_tau_core"]
        ratio = tau2 / tau1
        out = dict(values)
        out["thermal_tau"], out["thermal_tau_core"] = tau2, tau1
        for g1, g2 in (
            ("thermal_sensitivity", "thermal_sensitivity_core"),
            ("thermal_expansion", "thermal_expansion_core"),
        ):
            out[g1] = values[g1] * ratio
            out[g2] = values[g2] + values[g1] * (1.0 - ratio)
        return out

    @classmethod
    def canonical(cls, values):
        """Node 1 (the coil) the faster: :meth:`swap_nodes` when ``thermal_tau > thermal_tau_core``."""
        return cls.swap_nodes(values) if values["thermal_tau"] > values["thermal_tau_core"] else values

    @classmethod
    def in_canonical_domain(cls, params):
        params = np.atleast_2d(params)
        return params[:, 0] <= params[:, 3]

    @classmethod
    def reduced_starts(cls, values, term):
        """The one-node form from a two-node fit: node 2 off, and also node 1 taking node 2's
        time constant and gains. A one-pole heating is fitted equally well by node 1 alone and
        by a fast node 1 without gains feeding node 2, so a two-node fit may have put it on
        either node."""
        starts = super().reduced_starts(values, term)
        moved = {
            "thermal_tau": values["thermal_tau_core"],
            "thermal_sensitivity": values["thermal_sensitivity_core"],
            "thermal_expansion": values["thermal_expansion_core"],
        }
        return starts + [{**starts[0], **moved}]  # the caller clips a start to the model's bounds

    @classmethod
    def term_reductions(cls, term):
        """Node 2 off, or node 1 without gains at its fastest (1 s): a one-pole heating fitted
        on node 2 behind a fast node 1, the second labelling of the one-node form (up to node
        1's residual lag of 1 s)."""
        fastest = cls.parameters["thermal_tau"].lower
        return super().term_reductions(term) + [
            {"thermal_tau": fastest, "thermal_sensitivity": 0.0, "thermal_expansion": 0.0}
        ]

    @classmethod
    def get_test_parameters(cls):
        return {
            "thermal_tau": 20.0,
            "thermal_sensitivity": 0.08,
            "thermal_expansion": 3.0,
            "thermal_tau_core": 300.0,
            "thermal_sensitivity_core": 0.0,
            "thermal_expansion_core": 0.0,
        }

    def output(self, params, time, current, displacement):
        """Displacement with the heating's effect, shape ``(W, T)`` [um]."""
        time = np.ascontiguousarray(time, dtype=float)
        heating = np.ascontiguousarray((np.asarray(current, dtype=float) / REFERENCE_CURRENT) ** 2)
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        columns = [_column(params, c) for c in range(6)]
        _thermal_kernel(
            kernel_array(time), heating, *(kernel_array(c) for c in columns), kernel_array(displacement), out
        )
        return out


@register_effect
class SensorDrift(Effect):
    r"""Slow additive drift of the displacement sensor, present even with the coils off.

    .. math::

        y = y_g + D_1 s + D_2 s^2 + D_w \big(1 - e^{-(t - t_0)/\tau_w}\big)
            + A_s \sin \omega (t - t_0) + A_c \big(1 - \cos \omega (t - t_0)\big),

        s = \frac{t - t_0}{t_{T-1} - t_0} \in [0, 1], \qquad \omega = 2\pi / P_a

    so the drift is 0 at the first sample. Physics: warm-up and temperature drift of the
    sensor electronics and of the sensor's mount (laser triangulation or LVDT),
    independent of the drive; the paper's quiet first 10 s show the sensor's behaviour
    without excitation. The polynomial is a drift that keeps going over the record
    (per record: normalised time); the exponential is a warm-up that *settles*: an offset
    :math:`D_w` approached with the time constant :math:`\tau_w` (a sensor switched on
    shortly before the record); the periodic part follows the room: a laboratory's air
    temperature cycles with its air conditioning or heating (periods of a minute to many
    minutes), and the sensor and its mount, a linear thermal system, follow a periodic
    ambient at the same period with their own lag and attenuation, so their reading
    drifts by a sinusoid of period :math:`P_a`, whatever its phase (:math:`A_s, A_c`
    together are its amplitude and phase, started at 0).

    Trade-offs: for :math:`\tau_w` much longer than the record the settling term is
    nearly a line plus a parabola (its cubic remainder is :math:`(T/\tau_w)^3/6` of
    :math:`D_w`), so :math:`D_w, \tau_w` trade off with :math:`D_1, D_2` there (a near, not
    exact, degeneracy: the bound :math:`\tau_w \le 500` s keeps the remainder above 5e-5
    of :math:`D_w` on a 70 s record); the same holds for an ambient period much longer
    than the record (:math:`\sin` is then nearly the line, :math:`1 - \cos` the parabola;
    the bound :math:`P_a \le 500` s keeps their remainders, :math:`(\omega T)^2/6` and
    :math:`(\omega T)^2/12`, above 6 % on a 70 s record), and the ambient and settling
    terms trade off with each other over part of a period. The lower bound
    :math:`P_a \ge 30` s, three of the paper's drive periods, keeps the sinusoid away from
    the drive's own frequency, where it would stand in for the loops (a sensor's thermal
    mass does not follow faster ambient changes anyway). A drift is additive and present
    while the drive is off, so it is no reparametrisation of the GPI (whose offsets act at
    every sample alike). Measured Jacobian rank with the GPI on the paper's input:
    ``docs/effects.md``.

    Parameters: ``sensor_drift_linear`` and ``sensor_drift_quadratic`` [um], each
    -50-50; ``sensor_drift_settling`` :math:`D_w` [um] (-50-50);
    ``sensor_drift_settling_tau`` :math:`\tau_w` [s] (0.5-500); ``sensor_drift_ambient_sine``
    :math:`A_s` and ``sensor_drift_ambient_cosine`` :math:`A_c` [um] (-50-50);
    ``sensor_drift_ambient_period`` :math:`P_a` [s] (30-500). Off: the five amplitudes 0.
    """

    name = "sensor_drift"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter("sensor_drift_linear", 0.0, -50.0, 50.0, unit="um", description="linear drift over the record"),
            Parameter(
                "sensor_drift_quadratic", 0.0, -50.0, 50.0, unit="um", description="quadratic drift over the record"
            ),
            Parameter(
                "sensor_drift_settling", 0.0, -50.0, 50.0, unit="um", description="offset a settling warm-up approaches"
            ),
            Parameter(
                "sensor_drift_settling_tau", 10.0, 0.5, 500.0, unit="s", description="time constant of the warm-up"
            ),
            Parameter(
                "sensor_drift_ambient_sine",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="sine part of the drift that follows a periodic ambient",
            ),
            Parameter(
                "sensor_drift_ambient_cosine",
                0.0,
                -50.0,
                50.0,
                unit="um",
                description="1 - cosine part of the drift that follows a periodic ambient",
            ),
            Parameter(
                "sensor_drift_ambient_period", 120.0, 30.0, 500.0, unit="s", description="period of the ambient's cycle"
            ),
        ]
    )
    off = {
        "sensor_drift_linear": 0.0,
        "sensor_drift_quadratic": 0.0,
        "sensor_drift_settling": 0.0,
        "sensor_drift_settling_tau": 10.0,
        "sensor_drift_ambient_sine": 0.0,
        "sensor_drift_ambient_cosine": 0.0,
        "sensor_drift_ambient_period": 120.0,
    }
    summary = (
        "sensor drift: y = y_g + D1 s + D2 s^2 + Dw (1 - exp(-t/tau_w)) + As sin(w t) + Ac (1 - cos(w t)), "
        "s = normalised record time, w = 2 pi / P"
    )
    signature = "is there while the coils are off too (the quiet start, a quiet end), whatever the drive does"
    terms = {
        "settling": ("sensor_drift_settling", "sensor_drift_settling_tau"),
        "ambient": ("sensor_drift_ambient_sine", "sensor_drift_ambient_cosine", "sensor_drift_ambient_period"),
    }

    @classmethod
    def get_test_parameters(cls):
        return {
            "sensor_drift_linear": 2.0,
            "sensor_drift_quadratic": 1.5,
            "sensor_drift_settling": 0.0,
            "sensor_drift_settling_tau": 10.0,
            "sensor_drift_ambient_sine": 0.0,
            "sensor_drift_ambient_cosine": 0.0,
            "sensor_drift_ambient_period": 120.0,
        }

    def output(self, params, time, current, displacement):
        """Displacement plus drift, shape ``(W, T)`` [um].

        The drift does not depend on the displacement, so it is computed once per distinct
        parameter row (a finite-difference Jacobian's rows that move the GPI or another
        effect share one drift) and added to every row that has it."""
        params = np.atleast_2d(np.asarray(params, dtype=float))
        if params.shape[0] > 1:
            distinct, row_of = np.unique(params, axis=0, return_inverse=True)
            if distinct.shape[0] < params.shape[0]:
                return displacement + self.drift(distinct, time)[row_of.reshape(-1)]
        return displacement + self.drift(params, time)

    def drift(self, params, time):
        r"""The drift alone, shape ``(W, T)`` [um], for parameter rows ``(W, 7)``; 0 at the first sample.

        The settling curve depends on :math:`\tau_w` alone and the ambient's sine and cosine
        on :math:`P_a` alone, so each is computed once per distinct value (a Jacobian's rows
        share them but for the one row that moves it) and weighted per row: the same values."""
        params = np.asarray(params, dtype=float)
        time = np.asarray(time, dtype=float)
        span = time[-1] - time[0]
        elapsed = time - time[0]
        s = elapsed / span if span > 0 else np.zeros_like(time)
        drift = params[:, 0:1] * s + params[:, 1:2] * s**2
        settling = params[:, 2:3]
        if np.any(settling != 0.0):
            taus, tau_of = np.unique(params[:, 3], return_inverse=True)
            drift += settling * (-np.expm1(-elapsed / taus[:, None]))[tau_of.reshape(-1)]
        sine, cosine = params[:, 4:5], params[:, 5:6]
        if np.any(sine != 0.0) or np.any(cosine != 0.0):
            periods, period_of = np.unique(params[:, 6], return_inverse=True)
            phase = (2.0 * np.pi / periods[:, None]) * elapsed
            period_of = period_of.reshape(-1)
            drift += sine * np.sin(phase)[period_of]
            drift += cosine * (1.0 - np.cos(phase))[period_of]
        return drift
