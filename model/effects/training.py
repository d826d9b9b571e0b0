"""``training`` (input stage, and the strain): the virgin material responds differently until cycling trains it.

Holds :class:`Training` and its fade: :func:`accumulated_travel` (the drive's travel) and
:func:`training_fade` (:math:`f = e^{-(V/V_0)^p}`).
"""

from __future__ import annotations

import numpy as np

from ..parameters import Parameter, ParameterSet
from .base import Effect

__all__ = ["Training", "accumulated_travel", "training_fade"]


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

    @classmethod
    def _check(cls, params):
        """The parameters by name (:meth:`Effect.values`), after checking them."""
        params = np.asarray(params, dtype=float)
        p = cls.values(params)
        bad = ~(np.isfinite(params).all(axis=1) & (p.travel > 0) & (p.shape > 0) & (p.threshold >= 0))
        if bad.any():
            raise ValueError(
                "training: the parameters must be finite, training_threshold >= 0 and training_travel, "
                f"training_shape > 0; parameter set(s) {np.flatnonzero(bad)[:5].tolist()} are not "
                f"({params[bad][:3].tolist()})"
            )
        return p

    @staticmethod
    def _fade(p, drive):
        """The fade ``f`` of the travel of ``drive`` (shape ``(T,)`` or ``(W, T)``), shape ``(W, T)``,
        for the parameters ``p`` (:meth:`Effect.values`).

        On one drive row the fade depends on a set's ``(V0, p)`` only, so it is computed
        once per distinct pair (a Jacobian's batch varies them in two rows of its P + 1):
        the same values, element by element."""
        travel = accumulated_travel(drive)
        if travel.shape[0] != 1 or p.travel.shape[0] == 1:
            return training_fade(travel, p.travel[:, None], p.shape[:, None])
        pairs, row_of = np.unique(np.column_stack([p.travel, p.shape]), axis=0, return_inverse=True)
        return training_fade(travel, pairs[:, 0:1], pairs[:, 1:2])[row_of.reshape(-1)]

    def drive(self, params, time, current):
        """Drive with the fading first-cycle difference, shape ``(W, T)`` [A]; ``current`` may be ``(T,)`` or ``(W,
        T)``."""
        p = self._check(params)
        deficit, threshold = p.deficit[:, None], p.threshold[:, None]
        drive = np.atleast_2d(np.asarray(current, dtype=float))
        if drive.shape[0] not in (1, deficit.shape[0]):
            raise ValueError(f"training: the drive has {drive.shape[0]} rows for {deficit.shape[0]} parameter sets")
        fade = self._fade(p, drive)
        excursion = drive - drive[:, 0:1]
        # soft threshold: the excursion less F f toward the start (0 inside the threshold)
        kept = np.sign(excursion) * np.maximum(np.abs(excursion) - threshold * fade, 0.0)
        # u = i - (excursion - kept (1 - g f)); every term 0 when g = F = 0, so u == i bit for bit
        return drive - (excursion - kept * (1.0 - deficit * fade))

    def threshold_scale(self, params, time, drive):
        """The play width in force, ``1 + w f`` on every threshold, shape ``(W, T)``; None where ``w = 0``."""
        p = self._check(params)
        width = p.width[:, None]
        if not width.any():
            return None
        return 1.0 + width * self._fade(p, drive)

    def output(self, params, time, current, displacement):
        """The GPI's output with the virgin strain excursion scaled by ``1 + s f``, shape ``(W, T)`` [um]."""
        p = self._check(params)
        y = np.atleast_2d(np.asarray(displacement, dtype=float))
        gain = p.gain[:, None]
        if not gain.any():  # off: the displacement itself, bit for bit
            return y
        return y + gain * self._fade(p, current) * (y - y[:, 0:1])
