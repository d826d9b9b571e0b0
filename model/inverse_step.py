"""The inverse's model, one sample at a time: the forward step :mod:`model.inverse` searches on.

:func:`evaluate_step` is the model's output at one sample for a trial current, from the state
of the previous sample (the input stage: lag, training; the GPI's operators and Omega; the
output stage: training's strain part, creep, thermal, sensor drift); :func:`commit_step`
advances that state with the current found; :func:`drive_step`, their input stage alone, tells the
side a trial current moves the drive to. They repeat :class:`model.Model`'s arithmetic
for these effects sample for sample, so the current found reproduces the target through the
model itself (``tests/test_inverse.py``). :func:`filter_coefficients` is the exact step of a
first-order filter, shared with the search's set-up. The root search that calls these is in
:mod:`model.inverse_search`; the method is stated in :mod:`model.inverse`'s docstring.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .effects._filters import leg_end_level
from .effects.creep import LOG_CREEP_MODE_WEIGHT
from .gpi_kernels import initial_operator_memory

__all__ = ["filter_coefficients", "drive_step", "evaluate_step", "creep_prepare", "commit_step"]


@njit(cache=True)
def filter_coefficients(step, tau):
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
def drive_step(i, first, st, lag_c, has_training, tr):
    """The input stage at the present sample for current ``i``: ``(u1, u, travel, fade)``.

    ``u1`` the lag's output, ``u`` the drive the hysteresis sees (after training), ``travel``
    the drive's travel so far and ``fade`` training's fading factor at it (1 without training).
    Alone it tells the side of a trial current (the sign of ``u`` minus the previous drive) for
    a few operations, without the hysteresis's envelopes.
    """
    if first:
        u1 = i
    else:
        u1 = _filter_step(st[1], st[0], i, lag_c[0], lag_c[1], lag_c[2] > 0.5)
    travel = 0.0
    fade = 1.0
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
    return u1, u, travel, fade


@njit(cache=True)
def evaluate_step(
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
    creep_affine,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """Model output at the present sample for current ``i``, from the committed state.

    ``g``: the 16 envelope/Omega coefficients (rising env 0-3, falling env 4-7, Omega c
    8-11, Omega d 12-15). ``st``: scalar state (see the kernel). ``tr``: training's six
    parameters. ``cp``: creep's saturating amplitude, number of saturating modes, logarithmic
    rate, number of logarithmic modes, the part held to the leg's end; ``creep_affine`` its modes
    advanced to this sample as sums affine in the strain (:func:`creep_prepare`). ``th``:
    thermal's node-1 time constant, sensitivity, expansion, the reference current, node 2's time
    constant, sensitivity, expansion, the nodes' rises at the record's start; ``thermal_c`` the
    two nodes' step coefficients. ``drift``: the sensor drift at this sample.
    Before the first sample is committed, ``memory`` holds the initial memory held beyond
    the bounds (``initial_state``'s :math:`h_j`), which the first sample adds to the clamped
    memory. Returns ``(y, y_gpi, u1, u, travel, side, y_strain, width, y_stage)``; ``side`` +1 on Omega's c
    branch (the drive last moved up), -1 on d; ``y_strain`` the strain after training's strain part (the
    output stage's input); ``width`` the factor on the thresholds in force; ``y_stage`` the thermal
    stage's input (after creep).
    """
    u1, u, travel, fade = drive_step(i, first, st, lag_c, has_training, tr)
    # the play width in force (training's virgin width)
    width = 1.0
    if has_training and tr[5] != 0.0:
        width = 1.0 + tr[5] * fade
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
        travel_i = st[10] + abs(i - st[0])  # the drive's travel itself without a lag
        fade_i = fade if travel_i == travel else math.exp(-((travel_i / tr[2]) ** tr[3]))
        y_strain = y_gpi + tr[4] * fade_i * (y_gpi - st[11])
    y = y_strain
    if creep_on and not first:  # the modes' filter steps, summed ahead (creep_prepare)
        if cp[0] != 0.0:
            y = y - cp[0] * (y_strain - (creep_affine[0] * y_strain + creep_affine[1]) / cp[1])
        if cp[2] != 0.0 and cp[3] > 0.0:
            x_now = (1.0 - cp[4]) * y_strain + cp[4] * creep_affine[4] if cp[4] != 0.0 else y_strain
            y = y + cp[2] * LOG_CREEP_MODE_WEIGHT * (creep_affine[2] * x_now + creep_affine[3])
    y_stage = y  # the thermal stage's input
    if thermal_on:
        if first:
            rise = th[7]  # the nodes' rises at the record's start
            rise2 = th[8]
        else:
            heating = (i / th[3]) ** 2
            rise = _filter_step(st[7], st[9], heating, thermal_c[0], thermal_c[1], thermal_c[2] > 0.5)
            rise2 = _filter_step(st[13], st[7], rise, thermal_c[3], thermal_c[4], thermal_c[5] > 0.5)
        if th[5] != 0.0 or th[6] != 0.0:
            y = y * (1.0 - th[1] * rise - th[5] * rise2) + th[2] * rise + th[6] * rise2
        else:
            y = y * (1.0 - th[1] * rise) + th[2] * rise
    y = y + drift
    return y, y_gpi, u1, u, travel, side, y_strain, width, y_stage


@njit(cache=True)
def creep_prepare(st, cp, modes, creep_gain, creep_decay, creep_active, out):
    """Creep's modes advanced to the present sample, as sums affine in the strain there.

    Each mode is one filter step of the strain (the logarithmic ones of their input) from the
    committed state, so their sums are ``out[0] y + out[1]`` (the saturating modes) and
    ``out[2] x + out[3]`` (the logarithmic ones, less their level at the first sample); ``out[4]``
    the strain held at the last leg's end. Computed once per sample instead of at every model
    step of the search (``evaluate_step`` reads them).
    """
    n_sat = int(cp[1])
    n_log = int(cp[3])
    out[:] = 0.0
    for m in range(n_sat):
        if creep_active[m]:
            out[0] += 1.0 - creep_gain[m]
            out[1] += creep_gain[m] * st[12] + creep_decay[m] * (modes[m] - st[12])
        else:
            out[0] += 1.0
    x_prev = st[12]
    if cp[4] != 0.0:
        out[4], _ = leg_end_level(st[12], st[15], st[17], st[16])
        x_prev = st[18]
    for m in range(n_sat, n_sat + n_log):
        if creep_active[m]:
            out[2] += 1.0 - creep_gain[m]
            out[3] += creep_gain[m] * x_prev + creep_decay[m] * (modes[m] - x_prev)
        else:
            out[2] += 1.0
        out[3] -= st[11]


@njit(cache=True)
def commit_step(
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
    creep_affine,
    thermal_on,
    th,
    thermal_c,
    drift,
):
    """Advance the state with the chosen current ``i``; returns the output."""
    y, y_gpi, u1, u, travel, side, y_strain, width, _ = evaluate_step(
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
        creep_affine,
        thermal_on,
        th,
        thermal_c,
        drift,
    )
    if first:
        rising_env, falling_env, excursion_env = _initial_envelopes(g, u, st[14])
        for j in range(n_ops):
            memory[j] = (  # before the first commit ``memory`` holds the held part (see evaluate_step)
                initial_operator_memory(st[8], thresholds[j], rising_env, falling_env, st[14], excursion_env)
                + memory[j]
            )
        for m in range(modes.shape[0]):
            modes[m] = y_gpi
        st[15] = y_strain
        st[16] = 0.0
        st[17] = y_strain
        st[18] = y_strain
        st[7] = th[7]
        st[13] = th[8]
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
