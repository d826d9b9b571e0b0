"""``sensor_drift`` (output stage): drift of the displacement sensor, settling warm-up and the room's cycle.

Holds :class:`SensorDrift` (additive, independent of the drive: computed once per distinct
parameter row).
"""

from __future__ import annotations

import numpy as np

from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["SensorDrift"]


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
        p = self.values(params)
        time = np.asarray(time, dtype=float)
        span = time[-1] - time[0]
        elapsed = time - time[0]
        s = elapsed / span if span > 0 else np.zeros_like(time)
        drift = p.linear[:, None] * s + p.quadratic[:, None] * s**2
        settling = p.settling[:, None]
        if np.any(settling != 0.0):
            taus, tau_of = np.unique(p.settling_tau, return_inverse=True)
            drift += settling * (-np.expm1(-elapsed / taus[:, None]))[tau_of.reshape(-1)]
        sine, cosine = p.ambient_sine[:, None], p.ambient_cosine[:, None]
        if np.any(sine != 0.0) or np.any(cosine != 0.0):
            periods, period_of = np.unique(p.ambient_period, return_inverse=True)
            phase = (2.0 * np.pi / periods[:, None]) * elapsed
            period_of = period_of.reshape(-1)
            drift += sine * np.sin(phase)[period_of]
            drift += cosine * (1.0 - np.cos(phase))[period_of]
        return drift
