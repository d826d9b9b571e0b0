r"""The effects' shared numerical core: the exact first-order filter, its per-step coefficients
and their table, and the leg-end rule of the output (private to :mod:`model.effects`).

All first-order filters of the library (``lag``, ``thermal``'s nodes, ``creep``'s modes) use
the actual sample times (no assumed sampling rate) and the exact solution of
:math:`\tau \dot u = x - u` for an input that is linear between samples
(:func:`lowpass_step`, :func:`first_order_lowpass`); a kernel that runs many modes or
parameter sets tabulates the coefficients once per distinct sample step
(:func:`distinct_steps`, :func:`lowpass_table`), bit for bit the direct step.
:func:`leg_end_level` is the output at the end of the last completed leg, shared by
``creep``'s kernel and :mod:`model.inverse_step`. :func:`first_order_lowpass` is public as
:func:`model.effects.first_order_lowpass`; the rest serves the effects' modules and
:mod:`model.inverse_step`, which import it from here.

numba's on-disk cache does not see a change in another file: a kernel compiled with
``cache=True`` that inlines a function of this module (every effect's kernel, and
:mod:`model.inverse_step`'s) keeps the old code after an edit here until its cache is cleared
(``find model -name '*.nb[ic]' -delete``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..gpi_kernels import kernel_array

__all__ = [
    "MAX_DISTINCT_STEPS",
    "distinct_steps",
    "first_order_lowpass",
    "leg_end_level",
    "lowpass_coefficients",
    "lowpass_step",
    "lowpass_table",
]


@njit(cache=True, inline="always")
def lowpass_step(state, x_prev, x_now, step, tau):
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


@njit(parallel=True, cache=True, nogil=True)
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
            state = lowpass_step(state, signal[row, k - 1], signal[row, k], time[k] - time[k - 1], tau[w])
            out[w, k] = state


@njit(cache=True, inline="always")
def lowpass_coefficients(step, tau):
    """``(decay, gain)`` of :func:`lowpass_step` for one step (``tau > 0``)."""
    ratio = step / tau
    decay = math.exp(-ratio)
    if ratio > 1e-3:
        gain = (1.0 - decay) / ratio
    else:
        gain = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)))
    return decay, gain


#: Most distinct sample steps for which the filters tabulate their coefficients
#: (:func:`distinct_steps`); a record with more computes them at every sample.
MAX_DISTINCT_STEPS = 64


@njit(cache=True)
def distinct_steps(time, max_distinct, hold=0.0):
    """``(steps, index)``: the distinct values of ``time[k] - time[k-1]`` (first
    occurrence order) and, for ``k >= 1``, ``index[k]`` with ``steps[index[k]]`` that
    step (exactly: equal floats); ``index[0] = 0``. Empty ``steps`` when there are more
    than ``max_distinct`` (then no table pays).

    ``hold > 0``: a step is kept while the sample step differs from it by at most ``hold``
    of itself (the creep kernel's rule, :data:`model.effects.creep.CREEP_STEP_HOLD`), and
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
def lowpass_table(steps, tau, decay, gain):
    """Fill ``decay[m], gain[m]`` with :func:`lowpass_step`'s coefficients for ``steps[m]``
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
def leg_end_level(y_prev, y_before, held, last_direction):
    """``(held, direction)`` after the sample ``y_prev`` (the one before it ``y_before``): the
    output at the end of the last completed leg, a stop (``y_prev == y_before``) or a reversal
    (the change's direction flips: the leg ended at ``y_before``), known once the sample after
    it is; ``held`` and ``last_direction`` (+1, -1, 0 before any change) are the values so far.
    The creep kernel and :mod:`model.inverse` (``creep_log_hold``) share it."""
    change = y_prev - y_before
    if change == 0.0:
        return y_prev, last_direction
    direction = 1.0 if change > 0.0 else -1.0
    if last_direction != 0.0 and direction != last_direction:
        held = y_before
    return held, direction


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
