"""``creep`` (output stage): saturating spectrum and logarithmic creep of the strain.

Holds :class:`Creep`, its kernel (the saturating modes and the logarithmic modes, a part of
each leg's change held from the leg's end), the mode constants and
:func:`creep_time_constants`, :func:`log_creep_time_constants`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..gpi_kernels import kernel_array
from ..parameters import Parameter, ParameterSet
from ._filters import MAX_DISTINCT_STEPS, distinct_steps, leg_end_level, lowpass_coefficients
from .base import Effect

__all__ = [
    "Creep",
    "creep_time_constants",
    "log_creep_time_constants",
    "CREEP_MODES",
    "CREEP_STEP_HOLD",
    "LOG_CREEP_MODES_PER_DECADE",
    "LOG_CREEP_MODE_WEIGHT",
]

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
#: The creep kernel keeps a step's coefficients until the sample step changes by more than
#: this share of itself.
CREEP_STEP_HOLD = 1e-12


@njit(parallel=True, cache=True, nogil=True)
def _creep_kernel(time, displacement, amplitude, taus, log_rate, log_taus, n_log, hold, out):
    """Creep of each row of ``displacement``: ``taus.shape[1]`` equal-weight saturating modes
    (amplitude ``amplitude[w]``) plus ``n_log[w]`` logarithmic-creep modes ``log_taus[w, :n_log[w]]``
    of weight :data:`LOG_CREEP_MODE_WEIGHT` decades each (rate ``log_rate[w]`` per decade),
    which follow ``(1 - hold[w])`` times the displacement plus ``hold[w]`` times the
    displacement at the end of the last completed leg (``creep_log_hold``).
    A part whose amplitude is 0 is skipped. The per-step decay is recomputed only when the step
    changes by more than :data:`CREEP_STEP_HOLD` (1e-12) of itself (uniform sampling: once per mode). With at most
    :data:`MAX_DISTINCT_STEPS` distinct steps under that rule (:func:`distinct_steps`; a CSV
    record at 1 kHz changes its step in the last bits at most samples but has about 16
    distinct steps) each mode's coefficients are computed once per distinct step and
    parameter set instead of at every change (a change then copies the step's row), the
    same values bit for bit."""
    n_sets = displacement.shape[0]
    n_samples = displacement.shape[1]
    n_modes = taus.shape[1]
    n_log_max = log_taus.shape[1]
    steps, index = distinct_steps(time, MAX_DISTINCT_STEPS, CREEP_STEP_HOLD)
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
                    a, g = lowpass_coefficients(steps[i], taus[w, m])
                    decay_table[i, m] = a
                    gain_table[i, m] = g
            for m in range(n_log[w]):
                a, g = lowpass_coefficients(steps[i], log_taus[w, m])
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
                            a, g = lowpass_coefficients(step, taus[w, m])
                            decay[m] = a
                            gain[m] = g
                    for m in range(n_log[w]):
                        a, g = lowpass_coefficients(step, log_taus[w, m])
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
                    held, last_direction = leg_end_level(y_prev, y_before, held, last_direction)
                    x_before, x_now = x_prev, (1.0 - hold[w]) * y_now + hold[w] * held
                    x_prev = x_now
                grown = 0.0
                for m in range(n_log[w]):
                    j = n_modes + m
                    logs[m] = x_now - (x_now - x_before) * gain[j] + decay[j] * (logs[m] - x_before)
                    grown += logs[m] - y0
                value += log_rate[w] * LOG_CREEP_MODE_WEIGHT * grown
            out[w, k] = value


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
        p = self.values(params)
        time = np.ascontiguousarray(time, dtype=float)
        taus = np.ascontiguousarray(creep_time_constants(p.tau, p.decades))
        duration = float(time[-1] - time[0]) if time.size else 0.0
        log_taus, counts = log_creep_time_constants(p.log_onset, duration)
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        _creep_kernel(
            kernel_array(time),
            kernel_array(displacement),
            kernel_array(p.amplitude),
            kernel_array(taus),
            kernel_array(p.log_rate),
            kernel_array(log_taus),
            kernel_array(counts),
            kernel_array(p.log_hold),
            out,
        )
        return out
