"""``rate_width`` (input stage): rate-dependent hysteresis, every play threshold a function of the drive's rate.

Holds :class:`RateWidth`, :func:`drive_rate` (the rate over each sample step) and
:func:`rate_threshold_scale` (the factor on the thresholds).
"""

from __future__ import annotations

import numpy as np

from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["RateWidth", "drive_rate", "rate_threshold_scale"]


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
        p = self.values(params)
        coefficient, saturation = p.coefficient[:, None], p.saturation[:, None]
        bad = ~(np.isfinite(params).all(axis=1) & (p.saturation >= 0.0))
        if bad.any():
            raise ValueError(
                "rate_width: the parameters must be finite and rate_width_saturation >= 0; parameter set(s) "
                f"{np.flatnonzero(bad)[:5].tolist()} are not ({params[bad][:3].tolist()})"
            )
        if not coefficient.any():
            return None
        return rate_threshold_scale(drive_rate(time, drive), coefficient, saturation)
