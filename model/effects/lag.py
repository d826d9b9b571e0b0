"""``lag`` (input stage): the field behind the coil current, first order plus dead time.

Holds :class:`Lag`, its dead-time kernel and :func:`delayed_lowpass` (the lag read at
:math:`t - d` by an exact partial step); the lag itself is :func:`first_order_lowpass`
(:mod:`model.effects._filters`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..gpi_kernels import kernel_array
from ..parameters import Parameter, ParameterSet
from ._filters import first_order_lowpass, lowpass_step
from .base import Effect

__all__ = ["Lag", "delayed_lowpass"]


@njit(parallel=True, cache=True, nogil=True)
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
            out[w, k] = lowpass_step(lagged[w, m], signal[row, m], x_target, part, tau[w])


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
        p = self.values(params)
        return delayed_lowpass(time, current, p.tau, p.delay)
