r"""Library of physical effects that can be added to the GPI model (see :mod:`model.composite`).

Every effect registers itself in :data:`model.composite.EFFECTS` with
:func:`~model.composite.register_effect`, names its parameters ``<effect>_<what>`` with
physical units and bounds, has an exact ``off`` setting (the model is then the plain GPI
bit for bit) and a typical "on" setting (:meth:`get_test_parameters`).

==================  =======  ==================================================================
name                stage    equation (one line)
==================  =======  ==================================================================
``lag``             input    :math:`\tau_L \dot u = i - u`, the GPI sees the drive :math:`u`
``training``        input    excursion :math:`i - i_0` less :math:`F f`, times :math:`1 - g f`, :math:`f = e^{-(V/V_0)^p}`, :math:`V` the drive's travel
``initial_state``   state    operators' initial memory clamped from :math:`z^0` instead of 0
``creep``           output   :math:`y = y_g - A\,(y_g - \tfrac1M \sum_m s_m)`, :math:`\tau_m \dot s_m = y_g - s_m`
``thermal``         output   :math:`\tau_T \dot\vartheta = (i/i_\mathrm{ref})^2 - \vartheta`, :math:`y = y_g (1 - S\vartheta) + E\vartheta`
``sensor_drift``    output   :math:`y = y_g + D_1 s + D_2 s^2`, :math:`s = (t - t_0)/(t_{T-1} - t_0)`
==================  =======  ==================================================================

Output-stage effects act in the order creep, thermal, sensor drift (the registration
order): creep belongs to the hysteretic strain, temperature scales the strain and adds
expansion, and the sensor drifts on top of everything.

All first-order filters use the actual sample times (no assumed sampling rate) and the
exact solution of :math:`\tau \dot u = x - u` for an input that is linear between
samples (:func:`first_order_lowpass`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .composite import Effect, register_effect
from .parameters import Parameter, ParameterSet

__all__ = [
    "Lag",
    "Training",
    "InitialState",
    "Creep",
    "Thermal",
    "SensorDrift",
    "first_order_lowpass",
    "creep_time_constants",
    "thermal_rise",
    "accumulated_travel",
    "training_fade",
    "REFERENCE_CURRENT",
    "CREEP_MODES",
]

#: Current [A] at which the normalised heating (i / i_ref)^2 is 1: the paper's 5 A excitation.
REFERENCE_CURRENT = 5.0
#: Number of relaxation modes spanning the creep spectrum.
CREEP_MODES = 9


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


@njit(parallel=True, cache=True)
def _creep_kernel(time, displacement, amplitude, taus, out):
    """Creep of each row of ``displacement`` through ``taus.shape[1]`` equal-weight modes."""
    n_sets = displacement.shape[0]
    n_samples = displacement.shape[1]
    n_modes = taus.shape[1]
    for w in prange(n_sets):
        modes = np.empty(n_modes)
        for m in range(n_modes):
            modes[m] = displacement[w, 0]  # at rest at the start: every mode at equilibrium
        out[w, 0] = displacement[w, 0]
        for k in range(1, n_samples):
            step = time[k] - time[k - 1]
            y_prev = displacement[w, k - 1]
            y_now = displacement[w, k]
            total = 0.0
            for m in range(n_modes):
                modes[m] = _lowpass_step(modes[m], y_prev, y_now, step, taus[w, m])
                total += modes[m]
            out[w, k] = y_now - amplitude[w] * (y_now - total / n_modes)


@njit(parallel=True, cache=True)
def _thermal_kernel(time, heating, tau, sensitivity, expansion, displacement, out):
    """``out = displacement (1 - S rise) + E rise`` with ``rise`` the low-passed ``heating`` (from 0)."""
    n_sets = displacement.shape[0]
    n_samples = displacement.shape[1]
    for w in prange(n_sets):
        rise = 0.0
        out[w, 0] = displacement[w, 0] * (1.0 - sensitivity[w] * rise) + expansion[w] * rise
        for k in range(1, n_samples):
            rise = _lowpass_step(rise, heating[k - 1], heating[k], time[k] - time[k - 1], tau[w])
            out[w, k] = displacement[w, k] * (1.0 - sensitivity[w] * rise) + expansion[w] * rise


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
        raise ValueError(f"time must be (T,) and signal (T,) or (W, T) with the same T; got {time.shape}, {np.shape(signal)}")
    tau = np.atleast_1d(np.asarray(tau, dtype=float))
    n_sets = max(signal2.shape[0], tau.size)
    if signal2.shape[0] not in (1, n_sets) or tau.size not in (1, n_sets):
        raise ValueError(f"signal has {signal2.shape[0]} rows and tau {tau.size} values: they must match or be 1")
    tau = np.ascontiguousarray(np.broadcast_to(tau, (n_sets,)))
    if initial is None:
        initial = signal2[:, 0]
    initial = np.ascontiguousarray(np.broadcast_to(np.asarray(initial, dtype=float), (n_sets,)))
    out = np.empty((n_sets, time.size))
    _lowpass_kernel(time, signal2, tau, initial, out)
    return out


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
    r"""Normalised temperature rise :math:`\vartheta`: :math:`\tau \dot\vartheta = (i/i_\mathrm{ref})^2 - \vartheta`, :math:`\vartheta(t_0) = 0`.

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
    r"""Rate dependence: the field-equivalent drive lags the coil current.

    .. math::  \tau_L \frac{du}{dt} = i(t) - u(t), \qquad u(t_0) = i(t_0)

    and the GPI sees :math:`u` instead of :math:`i`. Physics: the magnetic field in the
    air gap is set by the flux, which follows the current through the magnetic
    circuit's inductance and, in a solid (non-laminated) steel core such as the paper's
    S215, through eddy currents that oppose flux changes; to first order both give a
    first-order lag (e.g. the eddy-current time constant of a solid core). Discretised
    exactly for a current linear between samples, with the actual time steps.

    Parameters: ``lag_tau`` [s], ``0 <= lag_tau <= 5``; off: ``lag_tau = 0`` (the drive
    is the current itself).
    """

    name = "lag"
    stage = "input"
    parameters = ParameterSet(
        [Parameter("lag_tau", 0.0, 0.0, 5.0, unit="s", description="time constant of the field behind the current")]
    )
    off = {"lag_tau": 0.0}
    summary = "coil/eddy-current lag: tau du/dt = i - u, the hysteresis sees u"

    @classmethod
    def get_test_parameters(cls):
        return {"lag_tau": 0.05}

    def drive(self, params, time, current):
        """Lagged drive ``u``, shape ``(W, T)`` [A]; ``current`` may be ``(T,)`` or ``(W, T)``."""
        tau = _column(params, 0)
        return first_order_lowpass(time, current, tau)


@register_effect
class Training(Effect):
    r"""First-cycle (training) effect: the virgin material needs more field, less once cycled.

    .. math::

        f_k = e^{-(V_k / V_0)^p}, \qquad V_k = \sum_{m=1}^{k} |i_m - i_{m-1}|, \qquad
        \Delta_k = i_k - i_0,

        u_k = i_0 + \operatorname{sign}(\Delta_k)\,\max(|\Delta_k| - F f_k,\ 0)\,(1 - g f_k)

    and the GPI sees the drive :math:`u` (after ``lag``'s, when both are present: then
    :math:`i` is the lagged drive). :math:`V` is the drive's accumulated travel since the
    record's start [A] (:func:`accumulated_travel`), so the difference fades with the
    cycling the material has done, not with time (a pause does not train it);
    :math:`f` (:func:`training_fade`) is 1 on the virgin material and falls to :math:`1/e`
    after :math:`V_0` of travel. :math:`i_0` is the drive at the first sample (0 A on the
    paper's record): the excursion from it is reduced by the extra threshold :math:`F f`
    (a soft threshold: nothing moves until the drive exceeds it) and scaled by
    :math:`1 - g f`. The unenergised start (:math:`\Delta = 0`) is untouched.

    Physics: in the virgin (untrained) state the twin boundaries of the MSM crystal must
    first be nucleated or activated, so the first field-induced reorientation needs a
    higher magnetic stress than in the trained material, whose mobile boundaries are
    already there; cycling trains the crystal and the difference fades (training lowers
    the twinning stress of Ni-Mn-Ga: e.g. Chmielus et al., "Effects of surface roughness
    and training on the twinning stress of Ni-Mn-Ga single crystals", Acta Mater. 58,
    2010). The paper (sec. "Magnetic shape memory materials") reports a first cycle that
    differs from the later ones: the return spring "is not sufficiently large to provide
    crystal lattice reorientation ... thus that after first cycle maximum strain is
    reduced". :math:`F > 0`: an extra field threshold; :math:`g > 0`: the virgin material
    lacks the fraction :math:`g` of the drive (the first rising branch is delayed and
    stretched); :math:`g < 0`: the first cycle sees more drive and reaches a larger strain
    than the later ones. The fade's shape :math:`p` makes the general form absorb other
    laws of the same physics: 1 is exponential in the travel, about 2.4 close to a linear
    fade to 0 after about :math:`1.6 V_0` (fitted to a linear fade over 20 A on the bench:
    :math:`V_0` = 12.4-13.1 A, :math:`p` = 2.3-2.4), 8 nearly a step at :math:`V_0` (e.g. at
    the first reversal).

    What the GPI cannot do: its first (virgin) branch is tied to all later branches by the
    same parameters. A *constant* drive scale or shift, however, is an exact
    reparametrisation of the GPI (absorbed by the tanh slopes a1, b1, c1, d1 and arguments
    a2, b2, c2, d2), so as :math:`V_0 \to \infty` the effect stops being identifiable; the
    bounds keep the transient fading within a record (the paper's input has 47.5 A of total
    travel over 70 s, 10 A per early cycle: at :math:`V_0 = 15` A and :math:`p \ge 1` at
    most :math:`e^{-3.17} = 4\,\%` of it is left at the end). Neither the GPI's return-point
    memory nor ``initial_state`` (an exact reparametrisation, wiped out by the first full
    excursion) represents it. Measured on the virtual bench (paper input, Table 1,
    :math:`g = 0.08`, :math:`V_0 = 2` A, :math:`p = 1`: 1.94 noise sigmas RMS against the
    plain GPI at the same parameters, sigma = 0.5 um, seed 0), the best plain-GPI refit leaves
    1.42 sigma RMS over the energised part (a larger share than lag, creep, thermal or drift
    leave of theirs: the GPI cannot bend its first branch away from the later ones).

    Why not the plain drive shift :math:`u = i - F e^{-V/V_0}` (measured first): it moves
    the unenergised start, where :math:`V = 0` and the whole shift acts (F = 0.3 A moved
    the rest level by 23 um, 46 sigmas: a change of the sensor's zero that no field can
    cause), and a negative shift drives a GPI calibrated up to the record's largest current
    beyond it at the first peak (Table 1 leaves its domain above 5 A). The soft threshold
    and the scale about :math:`i_0` leave the rest state alone and, for :math:`g, F \ge 0`,
    keep the drive between :math:`i_0` and :math:`i`.

    Parameters: ``training_deficit`` :math:`g` (dimensionless), ``-0.5 <= g <= 0.5``;
    ``training_threshold`` :math:`F` [A], ``0 <= F <= 2``; ``training_travel`` :math:`V_0`
    [A], ``0.5 <= V_0 <= 15``; ``training_shape`` :math:`p`, ``0.5 <= p <= 8``. Off:
    ``g = F = 0`` (the drive is the current itself, bit for bit, whatever :math:`V_0`, :math:`p`).
    """

    name = "training"
    stage = "input"
    parameters = ParameterSet(
        [
            Parameter(
                "training_deficit", 0.0, -0.5, 0.5, unit="",
                description="fraction of the drive the virgin material lacks (negative: has in excess)",
            ),
            Parameter(
                "training_threshold", 0.0, 0.0, 2.0, unit="A",
                description="extra drive the virgin material needs before it responds at all",
            ),
            Parameter(
                "training_travel", 2.0, 0.5, 15.0, unit="A",
                description="accumulated drive travel over which the first-cycle difference fades by 1/e",
            ),
            Parameter(
                "training_shape", 1.0, 0.5, 8.0, unit="",
                description="exponent of the fade exp(-(V/V0)^p): 1 exponential, large a step at V0",
            ),
        ]
    )  # fmt: skip
    off = {"training_deficit": 0.0, "training_threshold": 0.0, "training_travel": 2.0, "training_shape": 1.0}
    summary = "first-cycle training: excursion soft-thresholded by F f and scaled by 1 - g f, f = exp(-(V/V0)^p)"

    @classmethod
    def get_test_parameters(cls):
        return {"training_deficit": 0.2, "training_threshold": 0.0, "training_travel": 2.0, "training_shape": 1.0}

    def drive(self, params, time, current):
        """Drive with the fading first-cycle difference, shape ``(W, T)`` [A]; ``current`` may be ``(T,)`` or ``(W, T)``."""
        params = np.asarray(params, dtype=float)
        deficit, threshold, travel_scale, shape = (params[:, c : c + 1] for c in range(4))
        bad = ~(np.isfinite(params).all(axis=1) & (travel_scale[:, 0] > 0) & (shape[:, 0] > 0) & (threshold[:, 0] >= 0))
        if bad.any():
            raise ValueError(
                "training: the parameters must be finite, training_threshold >= 0 and training_travel, "
                f"training_shape > 0; parameter set(s) {np.flatnonzero(bad)[:5].tolist()} are not "
                f"({params[bad][:3].tolist()})"
            )
        drive = np.atleast_2d(np.asarray(current, dtype=float))
        if drive.shape[0] not in (1, params.shape[0]):
            raise ValueError(f"training: the drive has {drive.shape[0]} rows for {params.shape[0]} parameter sets")
        fade = training_fade(accumulated_travel(drive), travel_scale, shape)
        excursion = drive - drive[:, 0:1]
        # soft threshold: the excursion less F f toward the start (0 inside the threshold)
        kept = np.sign(excursion) * np.maximum(np.abs(excursion) - threshold * fade, 0.0)
        # u = i - (excursion - kept (1 - g f)); every term 0 when g = F = 0, so u == i bit for bit
        return drive - (excursion - kept * (1.0 - deficit * fade))


@register_effect
class InitialState(Effect):
    r"""First-cycle (training) effect: the memory the record starts from.

    Every operator's initial memory is clamped from the level :math:`z^0` instead of 0:

    .. math::  z_j(t_0) = \max\big(\gamma_\uparrow(v_0) - r_j,\ \min(\gamma_\downarrow(v_0) + r_j,\ z^0)\big)

    (:func:`model.gpi.gpi`'s ``initial_memory``). The paper: the pre-tensioned return
    spring "is not sufficiently large to provide crystal lattice reorientation ... thus
    that after first cycle maximum strain is reduced", i.e. the virgin first loading
    differs from later cycles. :math:`z^0 \to -\infty` resets every operator to its
    lower bound (fully virgin: all variants reset); 0 is the paper's state; a positive
    value leaves operators raised (variants left over from earlier excitation). The
    first large excursion wipes the memory out, as the physics demands.

    **Not identifiable next to a GPI with free offsets** (any input, any size). Shifting
    both envelope offsets (``a3``, ``b3``) by :math:`s` shifts every operator bound and
    memory by :math:`s`; lowering both :math:`\Omega` offsets (``c3``, ``d3``) by
    :math:`s \sum_j p_j` restores the output; with :math:`s = -z^0` (clipped to the
    bounds' range) the plain GPI's initial level 0 gives exactly this effect's output.
    So the plain GPI already has a free initial state (where 0 lies between its bounds),
    and this effect adds nothing to it (:data:`identify.diagnose.GPI_EQUIVALENTS`; measured
    on the virtual bench: z0 = -20, 293 noise sigmas RMS against the plain GPI at the same
    parameters, is fitted by a plain GPI to ~1e-13 sigma, round-off). The effect matters only where
    those offsets are pinned or carry another parametrisation (e.g. a peer's fit, whose
    operators start above their upper bounds). The paper's training effect, a maximum
    strain reduced *after* the first cycle, is a ratchet on the largest excursion so far,
    which no initial memory of a GPI represents (the first full excursion wipes it).

    Parameters: ``initial_state_memory`` [A, envelope units], ``-20 <= z0 <= 20``; off: 0.
    """

    name = "initial_state"
    stage = "state"
    parameters = ParameterSet(
        [
            Parameter(
                "initial_state_memory", 0.0, -20.0, 20.0, unit="A",
                description="level the operators' initial memory is clamped from (0: paper; very negative: virgin)",
            )
        ]
    )  # fmt: skip
    off = {"initial_state_memory": 0.0}
    summary = "first-cycle state: initial operator memory clamped from z0 (0 = paper, -inf = virgin)"

    @classmethod
    def get_test_parameters(cls):
        return {"initial_state_memory": -0.5}

    def initial_memory(self, params):
        """The level :math:`z^0`, shape ``(W,)`` [A]."""
        return _column(params, 0)


@register_effect
class Creep(Effect):
    r"""Creep: slow continued motion of the twin boundaries after the input stops or reverses.

    The displacement relaxes toward the hysteretic value :math:`y_g` through a spectrum
    of :math:`M` = :data:`CREEP_MODES` equally weighted first-order relaxation modes:

    .. math::

        \tau_m \dot s_m = y_g - s_m, \qquad
        y = y_g - A \Big(y_g - \frac1M \sum_m s_m\Big), \qquad
        \tau_m = \tau\, 10^{\,d\,(m/(M-1) - 1/2)}

    After a step :math:`\Delta` of :math:`y_g` the output jumps by :math:`(1-A)\Delta` and
    creeps the rest as :math:`A\Delta\,(1 - \frac1M\sum_m e^{-t/\tau_m})`. The static gain
    is 1 (the final value is the GPI's), so creep does not trade off with the GPI's
    scale. ``d = 0`` is a single exponential; a wide spectrum (``d`` of 2-4 decades,
    log-uniform) reproduces logarithmic creep :math:`\propto \log t` for
    :math:`\tau 10^{-d/2} \ll t \ll \tau 10^{d/2}`. This is the linear creep operator of
    Krejci and Kuhnen (IEE Proc. Control Theory Appl., 2001), a superposition of
    first-order elements with log-spaced time constants, with the weights tied to one
    amplitude and a width so the form stays general with three parameters; logarithmic
    creep of smart actuators is described e.g. by Jung and Gweon (Rev. Sci. Instrum.,
    2000). In MSMA the twin boundaries keep moving under the constant field and spring
    force until the twinning stress balances them.

    Parameters: ``creep_amplitude`` (fraction of a step that creeps, 0-0.5),
    ``creep_tau`` [s] (central time constant, 0.01-100), ``creep_decades`` (spectrum
    width, 0-4). Off: ``creep_amplitude = 0``.
    """

    name = "creep"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter("creep_amplitude", 0.0, 0.0, 0.5, unit="", description="fraction of a displacement step that creeps"),
            Parameter("creep_tau", 1.0, 0.01, 100.0, unit="s", description="central creep time constant (geometric mean)"),
            Parameter("creep_decades", 1.0, 0.0, 4.0, unit="decades", description="width of the log-spaced creep spectrum"),
        ]
    )
    off = {"creep_amplitude": 0.0, "creep_tau": 1.0, "creep_decades": 1.0}
    summary = "creep: y relaxes to the GPI value through log-spaced modes, y = y_g - A (y_g - mean_m s_m)"

    @classmethod
    def get_test_parameters(cls):
        return {"creep_amplitude": 0.05, "creep_tau": 2.0, "creep_decades": 2.0}

    def output(self, params, time, current, displacement):
        """Displacement after creep, shape ``(W, T)`` [um]."""
        params = np.asarray(params, dtype=float)
        amplitude = _column(params, 0)
        taus = np.ascontiguousarray(creep_time_constants(params[:, 1], params[:, 2]))
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        _creep_kernel(np.ascontiguousarray(time, dtype=float), displacement, amplitude, taus, out)
        return out


@register_effect
class Thermal(Effect):
    r"""Joule heating of the coils changing the strain response over the run.

    The coils dissipate :math:`i^2 R`; through the thermal time constant of coil and
    core the normalised temperature rise :math:`\vartheta` follows

    .. math::

        \tau_T \dot\vartheta = \Big(\frac{i}{i_\mathrm{ref}}\Big)^2 - \vartheta, \quad
        \vartheta(t_0) = 0, \qquad
        y = y_g\,(1 - S\,\vartheta) + E\,\vartheta

    with :math:`i_\mathrm{ref}` = :data:`REFERENCE_CURRENT` = 5 A (the paper's excitation),
    so :math:`\vartheta = 1` is the steady rise under a constant 5 A. :math:`S` is the
    relative loss of field-induced strain per unit rise (the magnetocrystalline
    anisotropy, hence the MSM strain, falls as the alloy warms toward its transformation
    temperatures; e.g. Heczko and Straka, J. Appl. Phys. 2003), :math:`E` [um] the
    thermal expansion of rod, core and frame seen by the sensor. :math:`\vartheta = 0`
    before the coils are energised, so the quiet start is untouched.

    Parameters: ``thermal_tau`` [s] (1-2000), ``thermal_sensitivity`` (-0.5-0.5),
    ``thermal_expansion`` [um] (-50-50). Off: sensitivity = expansion = 0.
    """

    name = "thermal"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter("thermal_tau", 30.0, 1.0, 2000.0, unit="s", description="thermal time constant of coil and core"),
            Parameter(
                "thermal_sensitivity", 0.0, -0.5, 0.5, unit="",
                description="relative strain loss per unit normalised temperature rise",
            ),
            Parameter(
                "thermal_expansion", 0.0, -50.0, 50.0, unit="um",
                description="displacement from thermal expansion at unit normalised temperature rise",
            ),
        ]
    )  # fmt: skip
    off = {"thermal_tau": 30.0, "thermal_sensitivity": 0.0, "thermal_expansion": 0.0}
    summary = "Joule heating: tau dth/dt = (i/5 A)^2 - th, y = y_g (1 - S th) + E th"

    @classmethod
    def get_test_parameters(cls):
        return {"thermal_tau": 20.0, "thermal_sensitivity": 0.08, "thermal_expansion": 3.0}

    def output(self, params, time, current, displacement):
        """Displacement with the heating's effect, shape ``(W, T)`` [um]."""
        time = np.ascontiguousarray(time, dtype=float)
        heating = np.ascontiguousarray((np.asarray(current, dtype=float) / REFERENCE_CURRENT) ** 2)
        displacement = np.ascontiguousarray(np.atleast_2d(displacement), dtype=float)
        out = np.empty_like(displacement)
        _thermal_kernel(time, heating, _column(params, 0), _column(params, 1), _column(params, 2), displacement, out)
        return out


@register_effect
class SensorDrift(Effect):
    r"""Slow additive drift of the displacement sensor, present even with the coils off.

    .. math::  y = y_g + D_1 s + D_2 s^2, \qquad s = \frac{t - t_0}{t_{T-1} - t_0} \in [0, 1]

    so :math:`D_1 + D_2` is the drift accumulated over the record and the drift is 0 at
    the first sample. Physics: warm-up and temperature drift of the sensor electronics
    and of the sensor's mount (laser triangulation or LVDT), independent of the drive;
    the paper's quiet first 10 s show the sensor's behaviour without excitation.

    Parameters: ``sensor_drift_linear`` and ``sensor_drift_quadratic`` [um], each
    -50-50. Off: both 0. Note they are per record (normalised time).
    """

    name = "sensor_drift"
    stage = "output"
    parameters = ParameterSet(
        [
            Parameter("sensor_drift_linear", 0.0, -50.0, 50.0, unit="um", description="linear drift over the record"),
            Parameter("sensor_drift_quadratic", 0.0, -50.0, 50.0, unit="um", description="quadratic drift over the record"),
        ]
    )
    off = {"sensor_drift_linear": 0.0, "sensor_drift_quadratic": 0.0}
    summary = "sensor drift: y = y_g + D1 s + D2 s^2, s = normalised record time"

    @classmethod
    def get_test_parameters(cls):
        return {"sensor_drift_linear": 2.0, "sensor_drift_quadratic": 1.5}

    def output(self, params, time, current, displacement):
        """Displacement plus drift, shape ``(W, T)`` [um]."""
        params = np.asarray(params, dtype=float)
        time = np.asarray(time, dtype=float)
        span = time[-1] - time[0]
        s = (time - time[0]) / span if span > 0 else np.zeros_like(time)
        return displacement + (params[:, 0:1] * s + params[:, 1:2] * s**2)
