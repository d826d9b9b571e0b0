"""Tests of the effects library (the package model/effects/) and of composing effects with the GPI.

``test_every_registered_effect`` iterates over the whole registry, and
``test_every_effect_has_a_signature_test`` fails when an effect has no signature test
below, so no effect can be added untested. Analytic references are derived in the
comments next to them; tolerances are a few hundred ulps of the values compared.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import model
from model import EFFECTS, TABLE1, Effect, Model, gpi, paper_current
from model.effects import (
    CREEP_MODES,
    LOG_CREEP_MODES_PER_DECADE,
    REFERENCE_CURRENT,
    SensorDrift,
    accumulated_travel,
    creep_time_constants,
    delayed_lowpass,
    first_order_lowpass,
    incomplete_reset_strain,
    log_creep_time_constants,
    thermal_rise,
    training_fade,
)
from model.parameters import Parameter, ParameterSet

RTOL = 1e-12  # exact discretisations: only rounding separates them from the analytic solution


@pytest.fixture(scope="module")
def paper_input():
    return paper_current(fs=100.0)


@pytest.fixture(scope="module")
def plain_gpi(paper_input):
    time, current = paper_input
    return gpi(TABLE1, current)


def _theta(m: Model, values: dict) -> np.ndarray:
    return m.theta_from_dict(values)


# -- the whole registry -----------------------------------------------------------------


def test_registry_holds_the_required_effects():
    assert {"lag", "training", "creep", "thermal", "sensor_drift", "initial_state", "incomplete_reset"} <= set(EFFECTS)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_registered_effect(name, paper_input, plain_gpi):
    """Protocol, off == plain GPI bit for bit, test parameters in bounds and visible, batch == single."""
    time, current = paper_input
    cls = EFFECTS[name]
    effect = cls()
    # Protocol and documentation.
    assert cls.name == name and cls.stage in model.composite.STAGES
    assert cls.summary.strip(), f"{name}: empty summary"
    assert cls.__doc__ and "math::" in cls.__doc__, f"{name}: the docstring must state the equation"
    assert len(cls.parameters) >= 1
    for p in cls.parameters:
        assert p.name.startswith(name + "_") and p.description and p.lower <= cls.off[p.name] <= p.upper
    # off is the declared values; the parameters are read by name, without the prefix
    assert cls.off == {p.name: p.value for p in cls.parameters}
    rows = np.array([[p.lower for p in cls.parameters], [p.upper for p in cls.parameters]])
    view = cls.values(rows)
    assert view._fields == tuple(n.removeprefix(name + "_") for n in cls.parameters.names)
    assert all(np.array_equal(column, rows[:, i]) and column.flags.c_contiguous for i, column in enumerate(view))
    with pytest.raises(ValueError, match="shape"):
        cls.values(rows[:, :-1])
    m = Model([name])
    assert m.names[-len(cls.parameters) :] == cls.parameters.names

    # Off: exactly the plain GPI.
    y_off = m(m.default_theta(), time, current)
    assert np.array_equal(y_off, plain_gpi), f"{name}: off differs from the plain GPI"

    # Test parameters: within bounds, and they change the output clearly (RMS above 1 um,
    # twice the bench's default sensor noise of 0.5 um).
    test = cls.get_test_parameters()
    assert set(test) <= set(cls.parameters.names)
    theta_on = _theta(m, test)
    assert m.in_bounds(theta_on).all(), f"{name}: test parameters out of bounds"
    y_on = m(theta_on, time, current)
    rms_change = float(np.sqrt(np.mean((y_on - plain_gpi) ** 2)))
    assert rms_change > 1.0, f"{name}: test parameters change the output by only {rms_change:.3g} um RMS"

    # Batch: W rows with different parameters == W single evaluations, bit for bit.
    rng = np.random.default_rng(20240607)
    n_sets = 6
    sl = m.effect_slice(name)
    off = np.array([cls.off[n] for n in cls.parameters.names])
    on = np.array([test.get(n, cls.off[n]) for n in cls.parameters.names])
    batch = np.tile(m.default_theta(), (n_sets, 1))
    mix = rng.uniform(0.0, 1.5, size=(n_sets, 1))
    batch[:, sl] = np.clip(off + mix * (on - off), cls.parameters.lower, cls.parameters.upper)
    batch[0, sl] = off
    y_batch = m(batch, time, current)
    assert y_batch.shape == (n_sets, time.size)
    for w in range(n_sets):
        assert np.array_equal(y_batch[w], m(batch[w], time, current)), f"{name}: batch row {w} differs"
    assert np.array_equal(y_batch[0], plain_gpi)
    assert isinstance(effect, Effect)


@pytest.mark.parametrize("names", [[name] for name in EFFECTS] + [list(EFFECTS)], ids=lambda n: "+".join(n))
def test_finite_difference_batch_is_each_rows_own_output(names, paper_input):
    """A Jacobian's batch (each parameter alone perturbed, and exact repeats) through a model
    with its effects on: every row is its own single evaluation, bit for bit. The model runs
    each stage once per distinct input, so this is what keeps that sharing exact."""
    time, current = paper_input[0][::4], paper_input[1][::4]
    m = Model(names)
    theta = m.default_theta()
    for name in names:
        for key, value in EFFECTS[name].get_test_parameters().items():
            theta[m.names.index(key)] = value
    _assert_jacobian_batch_rows_are_single(m, theta, time, current, repeats=(0, theta.size))


def test_sensor_drift_with_every_term_on_batch_is_each_rows_own_output(paper_input):
    """The drift is computed once per distinct parameter row and added to every row that has
    it (rows that move the GPI share one drift): with the settling and ambient terms on too,
    a Jacobian's batch still gives every row its own single evaluation, bit for bit."""
    time, current = paper_input[0][::4], paper_input[1][::4]
    m = Model(["sensor_drift"])
    theta = m.default_theta()
    on = {
        "sensor_drift_linear": 2.0,
        "sensor_drift_quadratic": -1.0,
        "sensor_drift_settling": 1.5,
        "sensor_drift_settling_tau": 12.0,
        "sensor_drift_ambient_sine": 0.4,
        "sensor_drift_ambient_cosine": -0.3,
        "sensor_drift_ambient_period": 90.0,
    }
    for key, value in on.items():
        theta[m.names.index(key)] = value
    y = _assert_jacobian_batch_rows_are_single(m, theta, time, current, repeats=(0, 3, theta.size))
    drift = m.effects[0].drift(theta[m.effect_slice("sensor_drift")][None, :], time)[0]
    assert np.ptp(drift) > 1.0 and drift[0] == 0.0
    assert np.array_equal(y[0], m(m.default_theta(), time, current) + drift)  # the drift's defaults: off


def _assert_jacobian_batch_rows_are_single(m, theta, time, current, repeats):
    """A Jacobian's batch of ``theta`` (each parameter alone perturbed, then exact repeats of
    the rows ``repeats``) through ``m``: every row equals its own single evaluation, bit for
    bit. Returns the batch's output."""
    n_par = theta.size
    rows = np.repeat(theta[None, :], n_par + 1 + len(repeats), axis=0)
    rows[np.arange(1, n_par + 1), np.arange(n_par)] += 1e-6 * np.maximum(np.abs(theta), 0.01)
    for k, row in enumerate(repeats):
        rows[n_par + 1 + k] = rows[row]
    y, valid = m.evaluate(rows, time, current)
    assert valid.all() and y.shape == (rows.shape[0], time.size)
    for w in range(rows.shape[0]):
        assert np.array_equal(y[w], m(rows[w], time, current)), (
            f"{m!r}: row {w} ({m.names[w - 1] if 0 < w <= n_par else 'repeat'})"
        )
    return y


def test_all_effects_off_together_is_the_plain_gpi(paper_input, plain_gpi):
    time, current = paper_input
    m = Model(list(EFFECTS))
    assert np.array_equal(m(m.default_theta(), time, current), plain_gpi)


# -- signatures -----------------------------------------------------------------------


def _irregular_time(n=400, seed=5):
    """Strictly increasing times with steps of 5-15 ms: the filters must use the real steps."""
    steps = np.random.default_rng(seed).uniform(0.005, 0.015, size=n - 1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def signature_lag(paper_input, plain_gpi):
    """Drive = analytic first-order response to a ramp-and-hold current; GPI sees that drive."""
    time = _irregular_time()
    t_hold = time[200]
    slope = 2.0  # A/s
    current = slope * np.minimum(time, t_hold)
    tau = 0.3
    m = Model(["lag"])
    drive = m.effects[0].drive(np.array([[tau, 0.0]]), time, current)[0]
    # tau u' = i - u, u(0) = 0, i = s t: u = s (t - tau (1 - exp(-t/tau))).
    # After t_h the current holds at i_h: u = i_h - s tau (1 - exp(-t_h/tau)) exp(-(t - t_h)/tau).
    ramp = time <= t_hold
    expected = np.where(
        ramp,
        slope * (time - tau * -np.expm1(-time / tau)),
        slope * t_hold - slope * tau * -np.expm1(-t_hold / tau) * np.exp(-(time - t_hold) / tau),
    )
    np.testing.assert_allclose(drive, expected, rtol=RTOL, atol=1e-13)
    # Through the model: the GPI of that drive, exactly.
    time_p, current_p = paper_input
    theta = _theta(m, {"lag_tau": 0.05})
    drive_p = first_order_lowpass(time_p, current_p, 0.05)[0]
    assert np.array_equal(m(theta, time_p, current_p), gpi(TABLE1, drive_p))


def signature_creep(paper_input, plain_gpi):
    """After the GPI output stops moving, the output keeps creeping by A * step with the stated modes."""
    time = _irregular_time(n=3000)  # about 30 s
    i_start, i_stop = 100, 110
    t_a, t_b = time[i_start], time[i_stop]
    step = 50.0  # um
    # y_g: 0, then linear from 0 to step over [t_a, t_b], then constant.
    y_g = step * np.clip((time - t_a) / (t_b - t_a), 0.0, 1.0)
    amplitude, tau, decades = 0.1, 1.5, 2.0
    creep = EFFECTS["creep"]()
    y = creep.output(np.array([[amplitude, tau, decades, 0.0, 0.1, 0.0]]), time, np.zeros_like(time), y_g[None, :])[0]
    taus = creep_time_constants(tau, decades)[0]
    # Each mode s_m (tau_m s' = y_g - s): 0 before t_a; on the ramp (slope k = step/(t_b - t_a))
    # s = k (t' - tau_m (1 - exp(-t'/tau_m))), t' = t - t_a; after t_b it relaxes to step:
    # s = step - (step - s(t_b)) exp(-(t - t_b)/tau_m).
    k = step / (t_b - t_a)
    modes = []
    for tau_m in taus:
        dt = np.clip(time - t_a, 0.0, None)
        on_ramp = k * (dt - tau_m * -np.expm1(-dt / tau_m))
        at_stop = k * ((t_b - t_a) - tau_m * -math.expm1(-(t_b - t_a) / tau_m))
        after = step - (step - at_stop) * np.exp(-(time - t_b) / tau_m)
        modes.append(np.where(time <= t_b, on_ramp, after))
    expected = y_g - amplitude * (y_g - np.mean(modes, axis=0))
    np.testing.assert_allclose(y, expected, rtol=1e-11, atol=1e-11)
    # The stated amount: after the input stops the output still moves by A * mean_m(step - s_m(t_b)),
    # close to A * step for a ramp much shorter than the modes.
    still_to_creep = step - y[i_stop]
    assert 0.8 * amplitude * step < still_to_creep <= amplitude * step
    assert abs(y[-1] - y[i_stop]) > 0.5 * still_to_creep  # most of it happens within the record
    assert np.all(np.diff(y[i_stop:]) > 0)  # monotone approach
    # A signed amplitude: A < 0 overshoots by |A| times what is still to creep and relaxes back,
    # the same modes with the other sign (the deviation from y_g is exactly antisymmetric in A)
    y_back = creep.output(
        np.array([[-amplitude, tau, decades, 0.0, 0.1, 0.0]]), time, np.zeros_like(time), y_g[None, :]
    )[0]
    np.testing.assert_allclose(y_back - y_g, -(y - y_g), rtol=1e-12, atol=1e-11)
    assert y_back[i_stop] > step and np.all(np.diff(y_back[i_stop:]) < 0)  # beyond the step, then back
    assert abs(y_back[-1] - step) < abs(y_back[i_stop] - step)
    # The time constants: log-spaced, geometric mean tau, span 10**decades; decades=0 -> single.
    assert taus.size == CREEP_MODES
    np.testing.assert_allclose(np.exp(np.mean(np.log(taus))), tau, rtol=1e-12)
    np.testing.assert_allclose(taus[-1] / taus[0], 10.0**decades, rtol=1e-12)
    np.testing.assert_allclose(creep_time_constants(3.0, 0.0)[0], 3.0, rtol=0)
    # Static gain 1 on the paper input too: the creep output stays close to the GPI's.
    time_p, current_p = paper_input
    m = Model(["creep"])
    y_p = m(_theta(m, {"creep_amplitude": 0.05, "creep_tau": 0.5, "creep_decades": 0.0}), time_p, current_p)
    quiet = time_p < 10.0
    assert np.array_equal(y_p[quiet], plain_gpi[quiet])
    assert np.max(np.abs(y_p - plain_gpi)) < 0.05 * np.ptp(plain_gpi)


def signature_thermal(paper_input, plain_gpi):
    """Zero change while not energised; the change follows the first-order heating law exactly."""
    time = _irregular_time(n=2000)
    t_on = time[300]
    rate = 0.05  # 1/s: heating (i/i_ref)^2 = rate * (t - t_on), exact for i = i_ref sqrt(rate (t - t_on))
    current = REFERENCE_CURRENT * np.sqrt(rate * np.clip(time - t_on, 0.0, None))
    tau, sensitivity, expansion = 8.0, 0.1, 4.0
    y_g = 100.0 + 30.0 * np.sin(time)
    thermal = EFFECTS["thermal"]()
    y = thermal.output(
        np.array([[tau, sensitivity, expansion, 300.0, 0.0, 0.0, 0.0, 0.0]]), time, current, y_g[None, :]
    )[0]
    # tau th' = rate (t - t_on) - th, th(t_on) = 0: th = rate ((t - t_on) - tau (1 - exp(-(t - t_on)/tau))).
    dt = np.clip(time - t_on, 0.0, None)
    rise = rate * (dt - tau * -np.expm1(-dt / tau))
    np.testing.assert_allclose(thermal_rise(time, current, tau)[0], rise, rtol=1e-11, atol=1e-14)
    np.testing.assert_allclose(y - y_g, -sensitivity * rise * y_g + expansion * rise, rtol=1e-10, atol=1e-12)
    assert np.array_equal(y[time <= t_on], y_g[time <= t_on])  # zero before energising
    # On the paper input: nothing in the quiet 10 s, then a change that grows with heating.
    time_p, current_p = paper_input
    m = Model(["thermal"])
    test = EFFECTS["thermal"].get_test_parameters()
    change = m(_theta(m, test), time_p, current_p) - plain_gpi
    quiet = time_p < 10.0
    assert np.array_equal(change[quiet], np.zeros(quiet.sum()))
    rise_p = thermal_rise(time_p, current_p, test["thermal_tau"])[0]
    np.testing.assert_allclose(
        change,
        -test["thermal_sensitivity"] * rise_p * plain_gpi + test["thermal_expansion"] * rise_p,
        rtol=1e-12,
        atol=1e-12,
    )
    # Heating grows: the mean rise over the second energised period exceeds the first.
    assert rise_p[(time_p >= 20) & (time_p < 30)].mean() > rise_p[(time_p >= 10) & (time_p < 20)].mean()


def signature_sensor_drift(paper_input, plain_gpi):
    """The quiet segment moves by D1 s + D2 s^2; the record's end by D1 + D2."""
    time, current = paper_input
    linear, quadratic = 2.0, -1.5
    m = Model(["sensor_drift"])
    change = (
        m(_theta(m, {"sensor_drift_linear": linear, "sensor_drift_quadratic": quadratic}), time, current) - plain_gpi
    )
    s = time / 70.0
    np.testing.assert_allclose(change, linear * s + quadratic * s**2, rtol=1e-9, atol=1e-12)
    assert change[0] == 0.0
    quiet_end = np.flatnonzero(time < 10.0)[-1]
    np.testing.assert_allclose(change[quiet_end], linear * s[quiet_end] + quadratic * s[quiet_end] ** 2, rtol=1e-9)
    np.testing.assert_allclose(change[-1], linear + quadratic, rtol=1e-9)


def signature_initial_state(paper_input, plain_gpi):
    """Differs before the first peak only; exactly zero after the first full excursion."""
    time, current = paper_input
    first_peak = int(np.argmax(current >= current.max() - 1e-12))  # t = 15 s, 5 A
    assert abs(time[first_peak] - 15.0) < 1e-9
    m = Model(["initial_state"])
    for z0 in (-20.0, -0.5, 5.0):
        y = m(_theta(m, {"initial_state_memory": z0}), time, current)
        assert np.array_equal(y[first_peak:], plain_gpi[first_peak:]), f"z0={z0}: differs after the first peak"
        assert np.max(np.abs(y[:first_peak] - plain_gpi[:first_peak])) > 1.0, f"z0={z0}: no first-cycle change"
    # Fully virgin (z0 far below every lower bound) = every operator on its lower bound at t_0.
    y_virgin = m(_theta(m, {"initial_state_memory": -20.0}), time, current)
    assert np.array_equal(y_virgin, gpi(TABLE1, current, initial_memory=-1e9))


def signature_training(paper_input, plain_gpi):
    """The drive follows the soft threshold and scale of the fading first-cycle difference
    analytically; the quiet start is untouched; the first rising branch is delayed (g, F > 0)
    or advanced (g < 0: outside the fitting bounds, which keep g >= 0, but the equation holds);
    late in the record the output is the plain GPI's; V0 and p set the fade."""
    time, current = paper_input
    m = Model(["training"])
    effect = m.effects[0]
    names = ("training_deficit", "training_threshold", "training_travel", "training_shape")
    # Paper input (literal): 0 A until 10 s, then 2.5 - 2.5 cos(0.2 pi (t - 10)) (eq. (15) with
    # -pi/2), undamped until 20 s: rising 0 -> 5 A over 10-15 s, falling to 0 A at 20 s. So the
    # accumulated travel is V = i on the first rising branch and V = 10 A - i on the first falling one.
    first_rise = (time >= 10.0) & (time <= 15.0)
    first_fall = (time > 15.0) & (time <= 20.0)
    travel = accumulated_travel(current)[0]
    np.testing.assert_allclose(travel[first_rise], current[first_rise], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(travel[first_fall], 10.0 - current[first_fall], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(travel[-1], np.sum(np.abs(np.diff(current))), rtol=1e-12)
    settings = ((0.2, 0.0, 2.0, 1.0), (0.3, 0.0, 0.8, 3.0), (-0.05, 0.0, 4.0, 1.0), (0.0, 0.4, 3.0, 2.0))
    for deficit, threshold, scale, shape in settings:
        values = dict(zip(names, (deficit, threshold, scale, shape)))
        drive = effect.drive(np.array([[deficit, threshold, scale, shape, 0.0, 0.0]]), time, current)[0]
        fade = np.exp(-((travel / scale) ** shape))
        # i0 = 0 A and i >= 0: u = max(i - F f, 0) (1 - g f)
        expected = np.maximum(current - threshold * fade, 0.0) * (1.0 - deficit * fade)
        np.testing.assert_allclose(drive, expected, rtol=1e-13, atol=1e-14)
        # V0 is read back from the drive where the travel has reached about V0 (on the first
        # rising branch, V = i): f = exp(-(V / V0)^p) there
        k = int(np.argmin(np.abs(travel - scale)))
        if threshold == 0.0:
            fade_k = (current[k] - drive[k]) / (deficit * current[k])
        else:
            fade_k = (current[k] - drive[k]) / threshold
        np.testing.assert_allclose(travel[k] / (-math.log(fade_k)) ** (1.0 / shape), scale, rtol=1e-8)
        y = m(_theta(m, values), time, current)
        assert np.array_equal(y[time < 10.0], plain_gpi[time < 10.0])  # the unenergised start is untouched
        change = y - plain_gpi
        # on the first rising branch the GPI output rises with the drive: less drive, less output
        sign = -1.0 if deficit < 0 else 1.0
        assert np.all(sign * change[first_rise] <= 1e-9) and np.max(np.abs(change[first_rise])) > 0.1
        # late in the record (t > 50 s, V > 35.5 A): the change of the drive is below 5e-5 A for
        # these settings and does not change the input's direction, so the output moves along the
        # same branch, whose slope is below 400 um/A (measured: 312 um/A within a branch on the
        # paper input at 1 kHz): the change is below 0.02 um (measured: < 1e-6 um)
        late = time > 50.0
        assert np.max(np.abs(drive[late] - current[late])) < 5e-5
        assert np.array_equal(np.sign(np.diff(drive[late])), np.sign(np.diff(current[late])))
        assert np.max(np.abs(change[late])) < 0.02
    # A threshold F: nothing moves on the first rise until the current exceeds F (f = 1 at V = 0)
    drive = effect.drive(np.array([[0.0, 0.4, 3.0, 2.0, 0.0, 0.0]]), time, current)[0]
    below = first_rise & (current > 0) & (current < 0.4 * np.exp(-((current / 3.0) ** 2)))
    assert below.sum() > 5 and np.all(drive[below] == 0.0)
    # V0 controls how fast it fades: a longer travel scale leaves more of the difference later on
    second_cycle = (time > 20.0) & (time < 30.0)
    fast = m(_theta(m, {"training_deficit": 0.2, "training_travel": 1.0}), time, current) - plain_gpi
    slow = m(_theta(m, {"training_deficit": 0.2, "training_travel": 4.0}), time, current) - plain_gpi
    assert np.max(np.abs(slow[second_cycle])) > 10.0 * np.max(np.abs(fast[second_cycle]))
    # p shapes it: at the same V0 = 5 A (the first peak), p = 8 keeps nearly all of the
    # difference until V0 and almost none after 1.5 V0 (f(0.8 V0) = 0.846, f(1.5 V0) = 7.6e-12)
    step_like = training_fade(travel, 5.0, 8.0)
    early = first_rise & (current <= 4.0)
    np.testing.assert_allclose(step_like[early], np.exp(-((current[early] / 5.0) ** 8)), rtol=1e-14)
    assert np.all(step_like[early] > 0.84) and np.all(step_like[travel >= 7.5] < 1e-11)
    # Chained after lag: the difference acts on the lagged drive (and its travel).
    m2 = Model(["training", "lag"])
    assert m2.effect_names == ("lag", "training")
    lagged = first_order_lowpass(time, current, 0.05)[0]
    params = np.array([[0.2, 0.1, 2.0, 1.5, 0.0, 0.0]])
    y2 = m2(_theta(m2, {"lag_tau": 0.05, **dict(zip(names, params[0]))}), time, current)
    assert np.array_equal(y2, gpi(TABLE1, effect.drive(params, time, lagged)[0]))
    lagged_fade = np.exp(-((accumulated_travel(lagged)[0] / 2.0) ** 1.5))
    expected_drive = np.maximum(lagged - 0.1 * lagged_fade, 0.0) * (1.0 - 0.2 * lagged_fade)
    np.testing.assert_allclose(effect.drive(params, time, lagged)[0], expected_drive, rtol=1e-13, atol=1e-14)


def signature_lag_dead_time(paper_input, plain_gpi):
    """The dead time: a whole number of samples shifts the lagged drive by exactly those
    samples; a fractional one equals the lag computed on a 1 ms grid at t - d; the output is
    continuous in d; before t0 + d the drive is at rest."""
    time, current = paper_input
    m = Model(["lag"])
    shifted = delayed_lowpass(time, current, 0.1, 0.05)[0]  # 5 samples at 100 Hz
    lagged = first_order_lowpass(time, current, 0.1)[0]
    np.testing.assert_allclose(shifted[5:], lagged[:-5], rtol=0, atol=1e-12)
    assert np.all(shifted[:6] == current[0])
    # fractional: against the exact lag on a fine grid (current linear between the samples)
    fine = np.arange(0.0, 70.0 + 5e-4, 1e-3)
    lagged_fine = first_order_lowpass(fine, np.interp(fine, time, current), 0.1)[0]
    delay = 0.0537
    exact = np.interp(time - delay, fine, lagged_fine, left=current[0])
    np.testing.assert_allclose(delayed_lowpass(time, current, 0.1, delay)[0], exact, rtol=0, atol=2e-6)
    # a pure delay reads the current by linear interpolation
    np.testing.assert_allclose(
        delayed_lowpass(time, current, 0.0, delay)[0],
        np.interp(time - delay, time, current, left=current[0]),
        atol=1e-12,
    )
    # continuous in the delay: d and d + 1e-7 s differ by about slope x 1e-7 (slope <= 3.2 A/s here)
    a, b = delayed_lowpass(time, current, [0.1, 0.1], [delay, delay + 1e-7])
    assert np.max(np.abs(a - b)) < 5e-7
    # through the model: the GPI of that drive (rate independent: a pure delay shifts its output)
    y = m(m.theta_from_dict({"lag_delay": 0.05}), time, current)
    np.testing.assert_allclose(y[5:], plain_gpi[:-5], rtol=0, atol=1e-9)
    # the batch mixes delays and rows without delay (bit for bit the lag alone there)
    both = delayed_lowpass(time, current, [0.1, 0.1], [0.0, 0.02])
    assert np.array_equal(both[0], lagged)


def _incomplete_reset_reference(current, y_g, A, R, fade):
    """The recursion of IncompleteReset's docstring, written out sample by sample: the set
    S of virgin levels not yet reset is a plain list of unit-free level intervals."""
    e = np.abs(y_g - y_g[0])
    E = e.max()
    intervals: list[list[float]] = []
    q = reached = 0.0
    out = np.zeros_like(y_g)
    for k in range(1, y_g.size):
        q *= math.exp(-fade * abs(current[k] - current[k - 1]))
        if e[k] > reached:
            intervals.append([reached, e[k]])
            reached = e[k]
        elif e[k] < e[k - 1]:
            above = sum(max(0.0, hi - max(lo, e[k])) for lo, hi in intervals)
            intervals = [[lo, min(hi, e[k])] for lo, hi in intervals if lo < e[k]]
            q += R * above / E
        out[k] = A * (sum(hi - lo for lo, hi in intervals) / E + q)
    return out


def test_incomplete_reset_on_a_drive_with_holds_follows_its_formulas():
    """Where the strain repeats itself (holds, the drive off) the kernels reuse the level and the
    fade they computed at the sample before: the levels are still S((e/E)^p) of the mixed
    excursion, and the extra strain with a fade the recursion written out."""
    from model.effects.incomplete_reset import loading_levels
    from model.signals import hold_current

    time, current = hold_current(fs=10.0)
    y_g = 20.0 * np.tanh(current / 2.0)  # a strain that holds where the drive holds
    assert np.mean(np.diff(y_g) == 0.0) > 0.3
    share, p, c, k = 0.3, 0.6, 0.4, 5.0
    excursion = np.abs(y_g - y_g[0])
    drive = np.abs(current - current[0])
    u = ((1 - share) * excursion / excursion.max() + share * drive / drive.max()) ** p
    expected = (np.tanh(k * (u - c)) + np.tanh(k * c)) / (np.tanh(k * (1.0 - c)) + np.tanh(k * c))
    levels = loading_levels(current, excursion[None, :], np.array([share]), np.array([p]), np.array([c]), np.array([k]))
    np.testing.assert_allclose(levels[0], expected, rtol=1e-13, atol=1e-15)
    faded = incomplete_reset_strain(current, y_g, [6.0], [0.4], [0.3])[0]
    np.testing.assert_allclose(faded, _incomplete_reset_reference(current, y_g, 6.0, 0.4, 0.3), rtol=1e-12, atol=1e-12)


def signature_incomplete_reset(paper_input, plain_gpi):
    """On the paper's input (0 A, a first peak of 5 A at 15 s = the largest excursion, then
    smaller peaks): the extra strain grows with the GPI's strain excursion to A at the first
    peak, falls toward R A as the strain comes back (proportionally), stays or fades with the
    drive's travel, and is 0 in the quiet start; the whole record follows the recursion."""
    time, current = paper_input
    m = Model(["incomplete_reset"])
    A, R = 6.0, 0.4
    change = (
        m(m.theta_from_dict({"incomplete_reset_strain": A, "incomplete_reset_retained": R}), time, current) - plain_gpi
    )
    np.testing.assert_allclose(change[time < 10.0], 0.0, atol=1e-12)
    excursion = np.abs(plain_gpi - plain_gpi[0])
    E = excursion.max()
    peak = int(np.argmax(excursion))  # just after the first reversal at 15 s (Omega's branch switch)
    assert 15.0 <= time[peak] <= 15.1
    first_rise = np.arange(np.searchsorted(time, 10.0), peak + 1)
    assert np.all(np.diff(excursion[first_rise]) >= 0)  # all new (virgin) territory
    # the virgin loading: the extra strain is A times the strain's share of the largest excursion
    np.testing.assert_allclose(change[first_rise], A * excursion[first_rise] / E, rtol=1e-12, atol=1e-12)
    # while the strain comes back monotonically after the peak, the share (1 - R) of what
    # it gives back is reset: A (e / E) + R A (1 - e / E)
    falling = np.arange(peak + 1, peak + 400)
    back = falling[np.cumsum(np.diff(excursion[peak : falling[-1] + 1]) > 0) == 0]
    assert back.size > 100
    e_back = excursion[back]
    np.testing.assert_allclose(change[back], A * e_back / E + R * A * (1.0 - e_back / E), rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(change, _incomplete_reset_reference(current, plain_gpi, A, R, 0.0), rtol=1e-9, atol=1e-9)
    for a, r, fade in ((A, R, 0.0), (A, R, 0.05), (A, 1.0, 0.0), (-3.0, 0.0, 0.0)):
        got = incomplete_reset_strain(current, plain_gpi, [a], [r], [fade])[0]
        np.testing.assert_allclose(
            got, _incomplete_reset_reference(current, plain_gpi, a, r, fade), rtol=1e-11, atol=1e-11
        )
    # R = 1: nothing is reset (A from the peak on); a fade lets the retained part decay with the travel
    full = incomplete_reset_strain(current, plain_gpi, [A], [1.0], [0.0])[0]
    np.testing.assert_allclose(full[peak:], A, rtol=1e-12)
    faded = incomplete_reset_strain(current, plain_gpi, [A], [1.0], [0.05])[0]
    assert 0 < faded[-1] < A * math.exp(-0.05 * 30.0)
    # an excursion beyond the largest so far (an increasing-amplitude strain) adds extra strain again
    i2 = np.concatenate([np.linspace(0, 2, 101), np.linspace(2, 0, 100)[1:], np.linspace(0, 4, 201)[1:], [4.0]])
    y2 = 10.0 * i2  # a strain proportional to the drive
    extra = incomplete_reset_strain(i2, y2, [A], [0.0], [0.0])[0]
    assert extra[100] == pytest.approx(A * 0.5) and abs(extra[199]) < 1e-12
    assert extra[-1] == pytest.approx(A * 0.5, rel=1e-9)  # only the new 2 A of virgin territory
    # the state, not the travel: a second cycle within the range already unloaded resets
    # nothing more (no ratchet); coming back lower than before resets the levels in between
    y3 = np.array([0.0, 5.0, 10.0, 6.0, 3.0, 6.0, 10.0, 6.0, 3.0, 2.0, 1.0])
    extra3 = incomplete_reset_strain(np.zeros_like(y3), y3, [A], [R], [0.0])[0]
    after_first = A * (0.3 + R * 0.7)  # levels 0-3 still set, 3-10 reset with R kept
    np.testing.assert_allclose(extra3[4:9], after_first, rtol=1e-12)
    np.testing.assert_allclose(extra3[10], A * (0.1 + R * 0.9), rtol=1e-12)
    # a batch of displacements: row by row
    both = incomplete_reset_strain(current, np.vstack([plain_gpi, 2.0 * plain_gpi]), [A, A], [R, R], [0.0, 0.0])
    np.testing.assert_allclose(both[0], both[1], rtol=1e-12, atol=1e-12)  # the shares, not the sizes, matter
    with pytest.raises(ValueError, match="incomplete_reset: the displacement has shape"):
        incomplete_reset_strain(current, plain_gpi[:-1], [A], [R], [0.0])


def signature_incomplete_reset_loading_shape(paper_input, plain_gpi):
    """The virgin loading's general form: the extra strain follows A (e/E)^p of a loading
    variable that mixes the strain's and the drive's excursion (share m). A = 0 is the plain
    GPI bit for bit whatever m and p; m = 0, p = 1 is the strain-proportional form bit for bit
    (and the general computation's limit there); p < 1 front-loads the extra strain (an early
    overshoot), p > 1 delays it, m = 1 makes it follow the drive; the first unloading resets
    the same shape (the phi-measure of the levels it passes), keeping the fraction R."""
    time, current = paper_input
    m = Model(["incomplete_reset"])
    A, R = 6.0, 0.4

    def change(**values):
        theta = m.theta_from_dict({"incomplete_reset_strain": A, "incomplete_reset_retained": R, **values})
        return m(theta, time, current) - plain_gpi

    # off exact whatever the shape; the special case bit for bit, and the general path's limit
    off = m.theta_from_dict({"incomplete_reset_drive": 1.0, "incomplete_reset_shape": 0.3})
    assert np.array_equal(m(off, time, current), plain_gpi)
    proportional = change()
    assert np.array_equal(proportional, change(incomplete_reset_drive=0.0, incomplete_reset_shape=1.0))
    assert np.array_equal(
        proportional + plain_gpi, plain_gpi + incomplete_reset_strain(current, plain_gpi, [A], [R], [0.0])[0]
    )
    near = incomplete_reset_strain(current, plain_gpi, [A], [R], [0.0], drive=[1e-300])[0]  # general path
    np.testing.assert_allclose(near, proportional, rtol=0, atol=1e-12)

    excursion = np.abs(plain_gpi - plain_gpi[0])
    E = excursion.max()
    peak = int(np.argmax(excursion))
    first_rise = np.arange(np.searchsorted(time, 10.0), peak + 1)
    share = excursion[first_rise] / E
    for p in (0.4, 2.5):
        shaped = change(incomplete_reset_shape=p)
        # the virgin loading adds A (e/E)^p
        np.testing.assert_allclose(shaped[first_rise], A * share**p, rtol=1e-12, atol=1e-12)
        # the recursion on the levels l = (e/E)^p (the reference run on them as its "strain")
        levels = (excursion / E) ** p
        np.testing.assert_allclose(shaped, _incomplete_reset_reference(current, levels, A, R, 0.0), atol=1e-9)
    # front-loaded (p < 1): at a quarter of the largest excursion more than a quarter of A;
    # late (p > 1): less
    quarter = first_rise[np.searchsorted(share, 0.25)]
    assert change(incomplete_reset_shape=0.4)[quarter] > 1.5 * proportional[quarter] > 0
    assert 0 < change(incomplete_reset_shape=2.5)[quarter] < 0.5 * proportional[quarter]
    # m = 1: the extra strain follows the drive's excursion (to A at the drive's largest), not the strain's
    drive_share = np.abs(current - current[0]) / np.abs(current - current[0]).max()
    by_drive = change(incomplete_reset_drive=1.0)
    top = int(np.argmax(drive_share))
    rising = np.arange(np.searchsorted(time, 10.0), top + 1)
    np.testing.assert_allclose(by_drive[rising], A * drive_share[rising], rtol=1e-12, atol=1e-12)
    assert not np.allclose(by_drive[rising], proportional[rising], atol=0.1)
    np.testing.assert_allclose(by_drive, _incomplete_reset_reference(current, drive_share, A, R, 0.0), atol=1e-9)
    # a mix: the level of (1 - m) e/E_y + m |i - i0|/E_i
    mixed = 0.3 * excursion / E + 0.7 * drive_share
    levels = (mixed / mixed.max()) ** 0.6
    np.testing.assert_allclose(
        change(incomplete_reset_drive=0.7, incomplete_reset_shape=0.6),
        _incomplete_reset_reference(current, levels, A, R, 0.0),
        atol=1e-9,
    )
    # a Jacobian's batch with the general form on: every row its own single evaluation
    theta = m.theta_from_dict(
        {"incomplete_reset_strain": A, "incomplete_reset_drive": 0.3, "incomplete_reset_shape": 0.6}
    )
    _assert_jacobian_batch_rows_are_single(m, theta, time[::4], current[::4], repeats=(0,))
    with pytest.raises(ValueError, match="incomplete_reset_shape finite and > 0"):
        incomplete_reset_strain(current, plain_gpi, [A], [R], [0.0], shape=[0.0])


def signature_incomplete_reset_step(paper_input, plain_gpi):
    """The virgin reorientation setting in with a step: the level u = (e/E)^p becomes
    S(u) = (tanh(k (u - c)) + tanh(k c)) / (tanh(k (1 - c)) + tanh(k c)). k = 0 is the level
    itself bit for bit (whatever c), and the general path's limit; with the drive's excursion
    (m = 1) the virgin loading adds A S(i / i_max); a large k puts almost all of it past c."""
    time, current = paper_input
    m = Model(["incomplete_reset"])
    A, R = 6.0, 0.4

    def change(**values):
        theta = m.theta_from_dict({"incomplete_reset_strain": A, "incomplete_reset_retained": R, **values})
        return m(theta, time, current) - plain_gpi

    by_drive = change(incomplete_reset_drive=1.0)
    assert np.array_equal(by_drive, change(incomplete_reset_drive=1.0, incomplete_reset_onset=0.2))
    near = change(incomplete_reset_drive=1.0, incomplete_reset_sharpness=1e-4)
    np.testing.assert_allclose(near, by_drive, rtol=0, atol=1e-6)
    u = np.abs(current - current[0]) / np.abs(current - current[0]).max()
    k, c = 12.0, 0.55
    step = (np.tanh(k * (u - c)) + np.tanh(k * c)) / (np.tanh(k * (1.0 - c)) + np.tanh(k * c))
    stepped = change(incomplete_reset_drive=1.0, incomplete_reset_onset=c, incomplete_reset_sharpness=k)
    top = int(np.argmax(u))
    rising = np.arange(np.searchsorted(time, 10.0), top + 1)
    np.testing.assert_allclose(stepped[rising], A * step[rising], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(stepped, _incomplete_reset_reference(current, step, A, R, 0.0), atol=1e-9)
    below, above = rising[u[rising] < c - 0.2], rising[u[rising] > c + 0.2]
    assert np.all(stepped[below] < 0.1 * A) and np.all(stepped[above] > 0.9 * A)
    with pytest.raises(ValueError, match="incomplete_reset_onset within"):
        incomplete_reset_strain(current, plain_gpi, [A], [R], [0.0], drive=[1.0], onset=[1.0], sharpness=[5.0])


def signature_incomplete_reset_stroke(paper_input, plain_gpi):
    """The retained strain narrowing the later strokes: y = y_g + A (|S| + q (1 - b x)), x the
    strain's excursion over its largest. b = 0 is the form without it bit for bit; the virgin
    loading (nothing retained yet) is untouched by b; after a first cycle that resets nothing
    (R = 1, no fade) b = 1 leaves the top of a later stroke that reaches the largest excursion
    where the GPI has it and raises the rest level by A; b = 2 lowers that top by A."""
    time, current = paper_input
    m = Model(["incomplete_reset"])
    A = 6.0

    def change(**values):
        theta = m.theta_from_dict({"incomplete_reset_strain": A, **values})
        return m(theta, time, current) - plain_gpi

    assert np.array_equal(
        change(incomplete_reset_retained=0.4), change(incomplete_reset_retained=0.4, incomplete_reset_stroke=0.0)
    )
    off = m.theta_from_dict({"incomplete_reset_stroke": 2.0})
    assert np.array_equal(m(off, time, current), plain_gpi)
    # a drive that goes to its largest, back to 0 and to the same largest again
    i2 = np.concatenate([np.linspace(0, 2, 101), np.linspace(2, 0, 101)[1:], np.linspace(0, 2, 101)[1:]])
    y2 = 10.0 * i2
    x = y2 / y2.max()
    for b in (0.0, 1.0, 2.0):
        extra = incomplete_reset_strain(i2, y2, [A], [1.0], [0.0], stroke=[b])[0]
        np.testing.assert_allclose(extra[:101], A * x[:101], rtol=1e-12, atol=1e-12)  # virgin: no retained yet
        # the first unloading: the levels above x reset and all retained (q = 1 - x), the rest still set
        back = slice(101, 201)
        expected = A * (x[back] + (1.0 - x[back]) * (1.0 - b * x[back]))
        np.testing.assert_allclose(extra[back], expected, rtol=1e-12, atol=1e-12)
        # the second stroke, within the range reached: q = 1, nothing set
        np.testing.assert_allclose(extra[201:], A * (1.0 - b * x[201:]), rtol=1e-12, atol=1e-12)
    top = incomplete_reset_strain(i2, y2, [A], [1.0], [0.0], stroke=[1.0])[0]
    assert top[200] == pytest.approx(A) and abs(top[-1]) < 1e-12  # rest raised by A, the top where it was
    # with the general loading shape the narrowing still follows the strain's own excursion
    shaped = incomplete_reset_strain(i2, y2, [A], [0.5], [0.0], shape=[0.5], stroke=[1.0])[0]
    unshaped = incomplete_reset_strain(i2, y2, [A], [0.5], [0.0], shape=[0.5])[0]
    kept = A * 0.5  # the whole first stroke unloaded: the retained half of A
    np.testing.assert_allclose(unshaped[201:] - shaped[201:], kept * x[201:], rtol=1e-12, atol=1e-12)
    # a batch row by row, and a Jacobian's batch with the term on
    rows = incomplete_reset_strain(i2, y2, [A, A], [1.0, 1.0], [0.0, 0.0], stroke=[0.0, 1.0])
    np.testing.assert_array_equal(rows[1], top)
    theta = m.theta_from_dict({"incomplete_reset_strain": A, "incomplete_reset_stroke": 1.5})
    _assert_jacobian_batch_rows_are_single(m, theta, time[::4], current[::4], repeats=(0,))
    with pytest.raises(ValueError, match="incomplete_reset_stroke finite"):
        incomplete_reset_strain(i2, y2, [A], [1.0], [0.0], stroke=[np.nan])


def signature_thermal_two_nodes(paper_input, plain_gpi):
    """Node 2 follows node 1 through its own time constant: against the analytic two-pole
    response to a constant heating switched on at t_on; node 2's gains 0 is the one-node form bit for bit."""
    time = np.linspace(0.0, 400.0, 40001)
    t_on = 10.0
    current = np.where(time >= t_on, REFERENCE_CURRENT, 0.0)
    current[np.searchsorted(time, t_on)] = REFERENCE_CURRENT  # step at a sample
    tau1, tau2 = 5.0, 60.0
    thermal = EFFECTS["thermal"]()
    y_g = np.full((1, time.size), 100.0)
    params = np.array([[tau1, 0.0, 0.0, tau2, 0.0, 1.0, 0.0, 0.0]])  # node 2 expansion only: y - y_g = theta2
    y = thermal.output(params, time, current, y_g)[0] - 100.0
    dt = np.clip(time - t_on, 0.0, None)
    # theta1 = 1 - exp(-t/tau1) (after a ramp over one 10 ms sample); theta2 = 1 - (tau2 e^{-t/tau2} - tau1
    # e^{-t/tau1})/(tau2 - tau1)
    theta2 = 1.0 - (tau2 * np.exp(-dt / tau2) - tau1 * np.exp(-dt / tau1)) / (tau2 - tau1)
    late = time > t_on + 1.0
    np.testing.assert_allclose(y[late], theta2[late], rtol=0, atol=2e-3)
    # one-node form: node 2 gains 0 -> exactly the old kernel's formula
    time_p, current_p = paper_input
    m = Model(["thermal"])
    test = EFFECTS["thermal"].get_test_parameters()
    assert test["thermal_sensitivity_core"] == 0.0 and test["thermal_expansion_core"] == 0.0
    rise = thermal_rise(time_p, current_p, test["thermal_tau"])[0]
    change = m(_theta(m, test), time_p, current_p) - plain_gpi
    np.testing.assert_allclose(
        change,
        -test["thermal_sensitivity"] * rise * plain_gpi + test["thermal_expansion"] * rise,
        rtol=1e-12,
        atol=1e-12,
    )
    # node 2 rises more slowly than node 1
    values = dict(
        test, thermal_sensitivity=0.0, thermal_expansion=0.0, thermal_expansion_core=3.0, thermal_tau_core=100.0
    )
    slow = m(_theta(m, values), time_p, current_p) - plain_gpi
    assert np.all(slow[time_p < 10.0] == 0.0)
    assert 0 < slow[time_p <= 30.0][-1] < 3.0 * rise[time_p <= 30.0][-1]


def signature_log_creep(paper_input, plain_gpi):
    """After a step, logarithmic creep keeps growing by gamma step per decade of time (within
    0.05 decade-units of log10(1 + t/t0) for t >= 10 t0), without saturating within the record."""
    time = np.linspace(0.0, 200.0, 200001)
    step = 50.0
    y_g = np.where(time >= 1.0, step, 0.0)[None, :]
    creep = EFFECTS["creep"]()
    gamma, onset = 0.02, 0.01
    y = creep.output(np.array([[0.0, 1.0, 1.0, gamma, onset, 0.0]]), time, np.zeros_like(time), y_g)[0]
    after = time - 1.0
    window = (after >= 10 * onset) & (after <= 100.0)
    grown = (y - y_g[0])[window] / (gamma * step)
    assert np.max(np.abs(grown - np.log10(1.0 + after[window] / onset))) < 0.06
    assert (y[-1] - y[time.searchsorted(101.0)]) > 0.25 * gamma * step  # still growing at 100-199 s
    taus, counts = log_creep_time_constants(np.array([onset]), 200.0)
    assert counts[0] == math.ceil(LOG_CREEP_MODES_PER_DECADE * math.log10(2000.0 / onset))
    # combined with the saturating spectrum: the sum of both parts
    both = creep.output(np.array([[0.05, 2.0, 2.0, gamma, onset, 0.0]]), time, np.zeros_like(time), y_g)[0]
    saturating = creep.output(np.array([[0.05, 2.0, 2.0, 0.0, onset, 0.0]]), time, np.zeros_like(time), y_g)[0]
    np.testing.assert_allclose(both - saturating, y - y_g[0], rtol=1e-9, atol=1e-9)


def signature_log_creep_after_leg(paper_input, plain_gpi):
    """creep_log_hold q: the part q of each leg's change starts its logarithmic creep at the
    leg's end (a reversal or a stop) instead of with the change. q = 1 on a ramp, a reversal
    and a hold: nothing creeps during the first leg, then each leg's change dY_m creeps by
    gamma dY_m per decade from its end t_m; q = 0.5 is halfway between q = 0 and q = 1."""
    time = np.linspace(0.0, 200.0, 200001)
    step = 50.0
    rise = np.clip((time - 1.0) / 2.0, 0.0, 1.0) * step  # a leg up over 1-3 s
    fall = np.clip((time - 3.0) / 2.0, 0.0, 1.0) * 0.5 * step  # back by half over 3-5 s, then held
    y_g = (rise - fall)[None, :]
    creep = EFFECTS["creep"]()
    gamma, onset = 0.02, 0.01

    def out(hold):
        return creep.output(np.array([[0.0, 1.0, 1.0, gamma, onset, hold]]), time, np.zeros_like(time), y_g)[0]

    from_change, from_end, half = out(0.0), out(1.0), out(0.5)
    during_first_leg = time <= 3.0
    assert np.array_equal(from_end[during_first_leg], y_g[0][during_first_leg])  # waits for the leg's end
    assert from_change[time.searchsorted(3.0)] - step > 0.01 * gamma * step  # creeps with the change
    ends, changes = (3.0, 5.0), (step, -0.5 * step)
    window = time >= 5.0 + 10 * onset
    expected = sum(dy * np.log10(1.0 + np.maximum(time[window] - t_m, 0.0) / onset) for t_m, dy in zip(ends, changes))
    grown = (from_end - y_g[0])[window] / gamma
    assert np.max(np.abs(grown - expected)) < 0.06 * step
    np.testing.assert_allclose(half, 0.5 * (from_change + from_end), rtol=0, atol=1e-9 * step)
    # a step and a hold: from the stop, the logarithmic law of the plain form
    y_step = np.where(time >= 1.0, step, 0.0)[None, :]
    held = creep.output(np.array([[0.0, 1.0, 1.0, gamma, onset, 1.0]]), time, np.zeros_like(time), y_step)[0]
    after = time - 1.0
    window = (after >= 10 * onset) & (after <= 100.0)
    grown = (held - y_step[0])[window] / (gamma * step)
    assert np.max(np.abs(grown - np.log10(1.0 + after[window] / onset))) < 0.06


def signature_training_strain_gain(paper_input, plain_gpi):
    """The strain part of training: the GPI's excursion from its first value times 1 + s f,
    with f the same fade of the drive's travel; the quiet start untouched, a trained record's
    end the plain GPI's; s combines with the drive part (the GPI of the changed drive, then
    scaled)."""
    time, current = paper_input
    m = Model(["training"])
    travel = accumulated_travel(current)[0]
    for gain, scale, shape in ((0.1, 5.0, 1.0), (-0.05, 30.0, 2.0), (0.02, 50.0, 0.5)):
        values = {"training_gain": gain, "training_travel": scale, "training_shape": shape}
        y = m(_theta(m, values), time, current)
        fade = np.exp(-((travel / scale) ** shape))
        expected = plain_gpi + gain * fade * (plain_gpi - plain_gpi[0])
        np.testing.assert_allclose(y, expected, rtol=1e-13, atol=1e-12)
        assert np.array_equal(y[time < 10.0], plain_gpi[time < 10.0])
        # the first peak's strain excursion is 1 + s f(5 A) times the plain one
        peak = int(np.argmax(np.where(time < 20.0, plain_gpi, -np.inf)))
        ratio = (y[peak] - y[0]) / (plain_gpi[peak] - plain_gpi[0])
        np.testing.assert_allclose(ratio, 1.0 + gain * math.exp(-((travel[peak] / scale) ** shape)), rtol=1e-12)
    # trained within the record (V0 = 1 A): the end is the plain GPI's to round-off
    y = m(_theta(m, {"training_gain": 0.2, "training_travel": 1.0, "training_shape": 1.0}), time, current)
    late = time > 40.0
    np.testing.assert_allclose(y[late], plain_gpi[late], rtol=0, atol=1e-9)
    # with the drive part: the GPI of the changed drive, scaled about its first value
    both = {"training_deficit": 0.1, "training_gain": 0.1, "training_travel": 5.0, "training_shape": 1.0}
    drive = m.effects[0].drive(np.array([[0.1, 0.0, 5.0, 1.0, 0.1, 0.0]]), time, current)[0]
    y_drive = gpi(TABLE1, drive)
    fade = np.exp(-travel / 5.0)
    np.testing.assert_allclose(
        m(_theta(m, both), time, current), y_drive + 0.1 * fade * (y_drive - y_drive[0]), rtol=1e-13, atol=1e-12
    )


def signature_training_width(paper_input, plain_gpi):
    """The width part of training: every play threshold times 1 + w f with f the fade of the
    drive's travel, the weights of eq. (8) unchanged; the quiet start untouched (the initial
    memory is clamped with the trained thresholds); the virgin loops differ; trained within
    the record, the end is the plain GPI's."""
    time, current = paper_input
    m = Model(["training"])
    travel = accumulated_travel(current)[0]
    for width, scale, shape in ((0.3, 5.0, 1.0), (-0.2, 30.0, 2.0)):
        values = {"training_width": width, "training_travel": scale, "training_shape": shape}
        y = m(_theta(m, values), time, current)
        expected = gpi(TABLE1, current, threshold_scale=1.0 + width * np.exp(-((travel / scale) ** shape)))
        assert np.array_equal(y, expected)
        assert np.array_equal(y[time < 10.0], plain_gpi[time < 10.0])
    first_rise = (time > 10.5) & (time <= 15.0)
    wider = m(_theta(m, {"training_width": 0.3, "training_travel": 5.0}), time, current)
    assert np.max(np.abs(plain_gpi[first_rise] - wider[first_rise])) > 1.0
    trained = m(_theta(m, {"training_width": 0.5, "training_travel": 1.0}), time, current)
    np.testing.assert_allclose(trained[time > 40.0], plain_gpi[time > 40.0], rtol=0, atol=1e-9)


def signature_settling_drift(paper_input, plain_gpi):
    """The warm-up term settles: D_w (1 - exp(-t / tau_w)), on top of the polynomial."""
    time, current = paper_input
    m = Model(["sensor_drift"])
    values = {"sensor_drift_linear": 0.5, "sensor_drift_settling": 3.0, "sensor_drift_settling_tau": 8.0}
    change = m(_theta(m, values), time, current) - plain_gpi
    np.testing.assert_allclose(change, 0.5 * time / 70.0 + 3.0 * -np.expm1(-time / 8.0), rtol=1e-9, atol=1e-12)


def signature_ambient_drift(paper_input, plain_gpi):
    """The ambient term follows a periodic room temperature: As sin(w t) + Ac (1 - cos(w t)),
    0 at the first sample, present in the quiet start, and periodic."""
    time, current = paper_input
    m = Model(["sensor_drift"])
    values = {
        "sensor_drift_ambient_sine": 1.5,
        "sensor_drift_ambient_cosine": -2.0,
        "sensor_drift_ambient_period": 64.0,
    }
    change = m(_theta(m, values), time, current) - plain_gpi
    phase = 2.0 * np.pi * (time - time[0]) / 64.0
    np.testing.assert_allclose(change, 1.5 * np.sin(phase) - 2.0 * (1.0 - np.cos(phase)), rtol=1e-9, atol=1e-12)
    assert change[0] == 0.0
    quiet = current == 0.0
    assert np.max(np.abs(change[quiet])) > 0.5  # the room does not wait for the drive
    one_period = np.searchsorted(time, time[0] + 64.0)
    assert abs(change[one_period]) < 0.05  # back to the start after one period


def _step_rate(time, drive):
    """|x_k - x_(k-1)| / (t_k - t_(k-1)), 0 at the first sample: the rate the thresholds of sample k see."""
    rate = np.zeros_like(drive)
    rate[1:] = np.abs(np.diff(drive)) / np.diff(time)
    return rate


def signature_rate_width(paper_input, plain_gpi):
    """Every play threshold times 1 + b |du/dt| (b > 0) or 1 / (1 + |b| |du/dt|) (b < 0), the rate
    that of the step into each sample; the quiet start untouched; the loop of a faster drive
    differs from a slower one's on the same path (a rate-independent GPI gives the same
    loop), and with lag the rate is the lagged drive's."""
    time, current = paper_input
    m = Model(["rate_width"])
    rate = _step_rate(time, current)
    for b, scale in ((0.1, 1.0 + 0.1 * rate), (-0.1, 1.0 / (1.0 + 0.1 * rate))):
        y = m(_theta(m, {"rate_width_coefficient": b}), time, current)
        assert np.array_equal(y, gpi(TABLE1, current, threshold_scale=scale))
        assert np.array_equal(y[time < 10.0], plain_gpi[time < 10.0])
        assert np.max(np.abs(y - plain_gpi)) > 1.0
    # the same path at ten times the rate: the rate-independent GPI's output is the same
    # function of the path, this effect's is not
    fast_time = time[0] + (time - time[0]) / 10.0
    slow = m(_theta(m, {"rate_width_coefficient": 0.1}), time, current)
    fast = m(_theta(m, {"rate_width_coefficient": 0.1}), fast_time, current)
    assert np.array_equal(gpi(TABLE1, current), plain_gpi)
    assert np.max(np.abs(fast - slow)) > 5.0 * np.max(np.abs(slow - plain_gpi)) / 10.0
    # after lag: the rate of the lagged drive
    both = Model(["lag", "rate_width"])
    y = both(_theta(both, {"lag_tau": 0.5, "rate_width_coefficient": 0.1}), time, current)
    lagged = first_order_lowpass(time, current, 0.5)[0]
    lag_rate = _step_rate(time, lagged)
    np.testing.assert_allclose(y, gpi(TABLE1, lagged, threshold_scale=1.0 + 0.1 * lag_rate), rtol=1e-12, atol=1e-10)


def signature_rate_width_saturation(paper_input, plain_gpi):
    """The bent rate law: every threshold times 1 + b ln(1 + c r)/c, r the rate of the step into
    each sample; c = 0 is the linear law exactly and a small c is close to it; the bend lowers
    the factor at the fast rates only."""
    time, current = paper_input
    m = Model(["rate_width"])
    rate = _step_rate(time, current)
    y = m(_theta(m, {"rate_width_coefficient": 0.2, "rate_width_saturation": 2.0}), time, current)
    assert np.array_equal(y, gpi(TABLE1, current, threshold_scale=1.0 + 0.2 * np.log1p(2.0 * rate) / 2.0))
    narrowing = m(_theta(m, {"rate_width_coefficient": -0.2, "rate_width_saturation": 2.0}), time, current)
    assert np.array_equal(
        narrowing, gpi(TABLE1, current, threshold_scale=1.0 / (1.0 + 0.2 * np.log1p(2.0 * rate) / 2.0))
    )
    linear = m(_theta(m, {"rate_width_coefficient": 0.2}), time, current)
    near = m(_theta(m, {"rate_width_coefficient": 0.2, "rate_width_saturation": 1e-9}), time, current)
    np.testing.assert_allclose(near, linear, rtol=0, atol=1e-6)
    assert np.max(np.abs(y - linear)) > 1.0


SIGNATURES = {
    "lag": signature_lag,
    "rate_width": signature_rate_width,
    "training": signature_training,
    "creep": signature_creep,
    "thermal": signature_thermal,
    "sensor_drift": signature_sensor_drift,
    "initial_state": signature_initial_state,
    "incomplete_reset": signature_incomplete_reset,
}
#: the general forms' other parts (each effect's extra terms beyond its test parameters)
GENERAL_FORMS = {
    "lag dead time": signature_lag_dead_time,
    "training strain gain": signature_training_strain_gain,
    "training play width": signature_training_width,
    "rate_width saturation": signature_rate_width_saturation,
    "thermal two nodes": signature_thermal_two_nodes,
    "logarithmic creep": signature_log_creep,
    "logarithmic creep after each leg": signature_log_creep_after_leg,
    "settling drift": signature_settling_drift,
    "ambient drift": signature_ambient_drift,
    "incomplete_reset loading shape": signature_incomplete_reset_loading_shape,
    "incomplete_reset step": signature_incomplete_reset_step,
    "incomplete_reset stroke": signature_incomplete_reset_stroke,
}


def test_every_effect_has_a_signature_test():
    assert set(SIGNATURES) == set(EFFECTS), "every registered effect needs a signature test in SIGNATURES"


@pytest.mark.parametrize("form", list(GENERAL_FORMS))
def test_general_form(form, paper_input, plain_gpi):
    GENERAL_FORMS[form](paper_input, plain_gpi)


@pytest.mark.parametrize("name", list(SIGNATURES))
def test_signature(name, paper_input, plain_gpi):
    SIGNATURES[name](paper_input, plain_gpi)


def test_training_drive_batches_and_refusals():
    """A (W, T) drive (after lag) is transformed row by row about each row's first value; bad
    parameters are refused."""
    time = _irregular_time(200)
    drives = np.vstack([1.0 + np.sin(3.0 * time), 0.5 * np.cos(time)])  # start at 1 A and 0.5 A, both directions
    effect = EFFECTS["training"]()
    params = np.array([[0.1, 0.2, 1.0, 1.0, 0.0, 0.0], [-0.2, 0.0, 3.0, 2.0, 0.0, 0.0]])
    both = effect.drive(params, time, drives)
    for w in range(2):
        assert np.array_equal(both[w], effect.drive(params[w : w + 1], time, drives[w])[0])
        # u - i0 = sign(d) max(|d| - F f, 0) (1 - g f), d = i - i0: the soft threshold and the
        # scale act on the excursion from the first value, in both directions
        deficit, threshold, scale, shape = params[w, :4]
        excursion = drives[w] - drives[w, 0]
        fade = training_fade(accumulated_travel(drives[w]), scale, shape)[0]
        kept = np.sign(excursion) * np.maximum(np.abs(excursion) - threshold * fade, 0.0)
        expected = drives[w, 0] + kept * (1.0 - deficit * fade)
        np.testing.assert_allclose(both[w], expected, rtol=1e-13, atol=1e-14)
    assert both[0, 0] == drives[0, 0] and both[1, 0] == drives[1, 0]
    with pytest.raises(ValueError, match="training_travel, training_shape > 0"):
        effect.drive(np.array([[0.1, 0.0, 0.0, 1.0, 0.0, 0.0]]), time, drives[0])
    with pytest.raises(ValueError, match="training_threshold >= 0"):
        effect.drive(np.array([[0.1, -0.1, 1.0, 1.0, 0.0, 0.0]]), time, drives[0])
    with pytest.raises(ValueError, match="2 rows for 3 parameter sets"):
        effect.drive(np.tile(params[:1], (3, 1)), time, drives)
    assert accumulated_travel(np.array([0.0, 1.0, 0.5, 2.0]))[0].tolist() == [0.0, 1.0, 1.5, 3.0]


# -- filters --------------------------------------------------------------------------


def test_first_order_lowpass_shapes_and_pass_through():
    time = _irregular_time(50)
    signal = np.sin(time * 7.0)
    assert np.array_equal(first_order_lowpass(time, signal, 0.0)[0], signal)
    batch = first_order_lowpass(time, signal, [0.0, 0.1, 1.0])
    assert batch.shape == (3, 50)
    for w, tau in enumerate([0.0, 0.1, 1.0]):
        assert np.array_equal(batch[w], first_order_lowpass(time, signal, tau)[0])
    with pytest.raises(ValueError, match="rows"):
        first_order_lowpass(time, np.tile(signal, (2, 1)), [0.1, 0.2, 0.3])


# -- composition ------------------------------------------------------------------------


def test_composition_order_does_not_matter(paper_input):
    time, current = paper_input
    a, b = Model(["thermal", "creep"]), Model(["creep", "thermal"])
    assert a == b and a.names == b.names
    values = {**EFFECTS["thermal"].get_test_parameters(), **EFFECTS["creep"].get_test_parameters()}
    assert np.array_equal(a(_theta(a, values), time, current), b(_theta(b, values), time, current))


def test_add_and_refusals():
    assert Model() + "lag" == Model(["lag"])
    assert Model() + "lag" + "thermal" == Model(["thermal", "lag"])
    with pytest.raises(ValueError, match="given twice"):
        Model(["lag", "lag"])
    with pytest.raises(ValueError, match="given twice"):
        Model(["creep"]) + "creep"
    with pytest.raises(ValueError, match="unknown effect 'heat'.*thermal"):
        Model(["heat"])

    class Sensor(Effect):  # a parameter name clashing with sensor_drift's
        name = "sensor"
        stage = "output"
        parameters = ParameterSet([Parameter("sensor_drift_linear", 0.0, -1.0, 1.0)])
        off = {"sensor_drift_linear": 0.0}

    with pytest.raises(ValueError, match="appears twice"):
        Model([SensorDrift(), Sensor()])
    # A second class under a registered name is refused (and the registry is unchanged).
    before = dict(EFFECTS)
    with pytest.raises(ValueError, match="already registered"):
        model.register_effect(type("OtherLag", (EFFECTS["lag"],), {}))
    assert EFFECTS == before


def test_without_undoes_add_and_keeps_settings():
    m = Model(["thermal", "creep"])
    pinned = m.with_parameters(m.parameters.replace("creep_decades", value=0.5, vary=False))
    assert pinned.without("thermal") + "thermal" == pinned
    assert not pinned.without("thermal").parameters["creep_decades"].vary
    assert Model(["lag"]).without("lag") == Model()
    with pytest.raises(KeyError, match="'lag' is not in this model"):
        m.without("lag")


def test_thermal_tabulated_steps_equal_the_per_sample_filter():
    """The thermal kernel tabulates the filter coefficients per distinct sample step and runs
    four parameter sets in lockstep: bit for bit the per-sample computation of each set
    alone (a step jittered in its last bits is another entry), also with more distinct
    steps than the table holds (then computed at every sample), from cold and warm starts."""
    from model.effects._filters import MAX_DISTINCT_STEPS, distinct_steps, lowpass_step

    rng = np.random.default_rng(3)
    uniform = np.arange(3000) * 0.01  # a handful of distinct float steps
    jittered = np.cumsum(np.r_[0.0, rng.uniform(0.005, 0.015, 2999)])  # all steps distinct
    assert 0 < distinct_steps(uniform, MAX_DISTINCT_STEPS)[0].size <= MAX_DISTINCT_STEPS
    assert distinct_steps(jittered, MAX_DISTINCT_STEPS)[0].size == 0
    current = 5.0 * np.abs(np.sin(uniform))
    # four sets with both nodes on (run in lockstep), four with node 2 off (in lockstep too),
    # then the other cases one by one
    params = np.array(
        [
            [20.0, 0.08, 3.0, 300.0, -0.3, 2.0, 0.0, 0.0],
            [1e6, 0.1, 1.0, 1e-4, 0.2, 1.0, 0.3, -0.1],
            [5.0, 0.05, 1.0, 50.0, 0.1, 0.3, 0.0, 0.5],
            [0.5, 0.2, 2.0, 3000.0, 0.05, 0.4, 1.2, 0.7],
            [20.0, 0.08, 3.0, 300.0, 0.0, 0.0, 0.0, 0.0],
            [1e6, 0.1, 1.0, 0.0, 0.0, 0.0, 0.3, 0.2],
            [5.0, -0.05, 1.0, 50.0, 0.0, 0.0, 0.9, 0.0],
            [0.5, 0.2, 2.0, 3000.0, 0.0, 0.0, 1.2, 0.7],
            [0.0, 0.1, 1.0, 5.0, 0.0, 0.0, 0.4, 0.0],
            [7.0, 0.1, 1.0, 0.0, 0.1, 0.5, 0.0, 0.2],
            [3.0, 0.1, 1.0, 10.0, 0.0, 0.0, 0.0, 0.0],
        ]
    )
    y_g = rng.normal(size=(params.shape[0], uniform.size)).cumsum(axis=1)
    thermal = EFFECTS["thermal"]()
    for time in (uniform, jittered):
        y = thermal.output(params, time, current, y_g)
        heating = (current / REFERENCE_CURRENT) ** 2
        for w, (tau, s, e, tau2, s2, e2, start, start2) in enumerate(params):
            rise, rise2 = start, start2  # the nodes' rises at the record's start
            if s2 != 0.0 or e2 != 0.0:
                expected = [y_g[w, 0] * (1.0 - s * rise - s2 * rise2) + e * rise + e2 * rise2]
            else:
                expected = [y_g[w, 0] * (1.0 - s * rise) + e * rise]
            for k in range(1, time.size):
                step, previous = time[k] - time[k - 1], rise
                rise = lowpass_step.py_func(rise, heating[k - 1], heating[k], step, tau)
                if s2 != 0.0 or e2 != 0.0:
                    rise2 = lowpass_step.py_func(rise2, previous, rise, step, tau2)
                    expected.append(y_g[w, k] * (1.0 - s * rise - s2 * rise2) + e * rise + e2 * rise2)
                else:
                    expected.append(y_g[w, k] * (1.0 - s * rise) + e * rise)
            np.testing.assert_array_equal(y[w], expected)


def test_creep_tabulated_steps_equal_the_per_change_coefficients(monkeypatch):
    """The creep kernel computes each mode's coefficients once per distinct held step
    (:func:`model.effects._filters.distinct_steps` with ``CREEP_STEP_HOLD``): bit for bit its direct
    rule (recompute whenever the step changes by more than 1e-12 of itself), on a grid as a 1
    kHz CSV gives (steps that differ in their last bits at most samples) with genuinely
    different steps in it, for the saturating spectrum, the logarithmic modes and the part held
    from a leg's end."""
    from model.effects import creep as creep_module
    from model.effects._filters import MAX_DISTINCT_STEPS, distinct_steps
    from model.effects.creep import CREEP_STEP_HOLD

    rng = np.random.default_rng(5)
    steps = np.where((np.arange(2999) // 400) % 3 == 1, 0.003, 0.001)  # 1 ms with 3 ms stretches
    time = np.array([float(f"{t:.3f}") for t in np.r_[0.0, np.cumsum(steps)]])  # read back from text
    diffs = np.diff(time)
    assert np.unique(diffs).size > 2 and np.count_nonzero(np.diff(diffs)) > 100  # last-bit changes
    held, index = distinct_steps(time, MAX_DISTINCT_STEPS, CREEP_STEP_HOLD)
    assert 2 <= held.size <= MAX_DISTINCT_STEPS
    # the held step is within 1e-12 of every sample's own step
    np.testing.assert_allclose(held[index[1:]], diffs, rtol=1e-11, atol=0)
    y_g = 40.0 * np.sin(time * 3.0)[None, :] + rng.normal(size=(4, time.size)).cumsum(axis=1)
    params = np.array(
        [
            [0.05, 0.5, 2.0, 0.0, 0.1, 0.0],
            [0.0, 1.0, 1.0, 0.02, 0.005, 0.0],
            [-0.1, 0.02, 3.0, 0.01, 0.01, 0.6],
            [0.03, 2.0, 0.0, 0.03, 0.002, 1.0],
        ]
    )
    creep = EFFECTS["creep"]()
    y = creep.output(params, time, np.zeros_like(time), y_g)
    # the oracle: the kernel's own Python function with the table switched off (direct rule)
    monkeypatch.setattr(
        creep_module, "distinct_steps", lambda t, m, hold=0.0: (np.empty(0), np.zeros(t.size, dtype=np.int64))
    )
    monkeypatch.setattr(creep_module, "_creep_kernel", creep_module._creep_kernel.py_func)
    expected = creep.output(params, time, np.zeros_like(time), y_g)
    np.testing.assert_array_equal(y, expected)
    assert np.all(np.abs(y - y_g).max(axis=1) > 1e-3)  # every set creeps visibly


TWO_NODE_SWAPPED = {
    "thermal_tau": 53.73,
    "thermal_sensitivity": 0.374,
    "thermal_expansion": -31.78,
    "thermal_tau_core": 3.924,
    "thermal_sensitivity_core": -0.255,
    "thermal_expansion_core": 31.787,
}


def test_thermal_nodes_swapped_give_the_same_output_and_the_canonical_labelling_puts_the_coil_first():
    """The two-node network's exact mirror symmetry (docstring, "Symmetry"): swapping the time
    constants with the mapped gains changes the output only by the discretisation's O(h^2)."""
    from model.effects import Thermal

    time, current = paper_current(fs=100.0)
    m = Model(["thermal"])
    values = {**m.theta_dict(m.default_theta()), **TWO_NODE_SWAPPED}
    a = m.theta_from_dict(values)
    b = m.canonical_theta(a)
    swapped = m.theta_dict(b)
    assert swapped["thermal_tau"] == 3.924 and swapped["thermal_tau_core"] == 53.73
    assert np.max(np.abs(m(a, time, current) - m(b, time, current))) < 1e-4  # um, of a ~300 um output
    back = Thermal.swap_nodes(Thermal.swap_nodes(TWO_NODE_SWAPPED))
    assert all(math.isclose(back[k], v, rel_tol=1e-12) for k, v in TWO_NODE_SWAPPED.items())
    assert list(m.in_canonical_domain(np.vstack([a, b]))) == [False, True]
    # a pinned node is no labelling to choose: left as it is, and in the domain
    pinned = m.with_parameters(m.parameters.replace("thermal_tau_core", vary=False))
    assert np.array_equal(pinned.canonical_theta(a), a) and pinned.in_canonical_domain(a)[0]


@pytest.mark.parametrize("start, start_core", [(0.3, 0.0), (0.0, 0.4), (0.5, -0.2)])
def test_a_warm_start_cools_through_both_nodes_and_swaps_with_the_labelling(start, start_core):
    """Heat left by earlier runs: with no current the nodes decay from their start rises as the
    network's free response (node 1 through tau, node 2 through both), and the mirror labelling
    maps the start rises so that the output is the same."""
    from model.effects import Thermal

    time = np.linspace(0.0, 200.0, 20001)
    tau1, tau2 = 6.0, 40.0
    thermal = EFFECTS["thermal"]()
    y_g = np.full((1, time.size), 50.0)
    node1 = thermal.output(np.array([[tau1, 0.0, 1.0, tau2, 0.0, 0.0, start, start_core]]), time, 0 * time, y_g)
    node2 = thermal.output(np.array([[tau1, 0.0, 0.0, tau2, 0.0, 1.0, start, start_core]]), time, 0 * time, y_g)
    c = tau1 / (tau1 - tau2)
    e1, e2 = np.exp(-time / tau1), np.exp(-time / tau2)
    np.testing.assert_allclose(node1[0] - 50.0, start * e1, atol=1e-12)
    np.testing.assert_allclose(node2[0] - 50.0, start_core * e2 + start * c * (e1 - e2), atol=2e-6)
    time_p, current = paper_current(fs=100.0)
    m = Model(["thermal"])
    values = {
        **m.theta_dict(m.default_theta()),
        **TWO_NODE_SWAPPED,
        "thermal_initial": start,
        "thermal_initial_core": start_core,
    }
    a = m.theta_from_dict(values)
    b = m.theta_from_dict(Thermal.swap_nodes(values))
    assert np.max(np.abs(m(a, time_p, current) - m(b, time_p, current))) < 1e-4
    cold = m.theta_from_dict({**values, "thermal_initial": 0.0, "thermal_initial_core": 0.0})
    quiet = current == 0.0
    quiet[np.argmax(current > 0.0) :] = False  # the unenergised start
    assert np.max(np.abs(m(a, time_p, current) - m(cold, time_p, current))[quiet]) > 0.05  # um: it cools there
    back = Thermal.swap_nodes(Thermal.swap_nodes(values))
    assert math.isclose(back["thermal_initial"], start, abs_tol=1e-12)


def test_the_posterior_samples_only_the_canonical_half():
    from identify.bench.synthetic import simulate
    from identify.fitting.noise import estimate_noise
    from identify.fitting.posterior import LogPosterior

    record = simulate(None, fs=10.0, seed=1).record
    m = Model(["thermal"])
    log_post = LogPosterior(record, m, estimate_noise(record))
    a = m.theta_from_dict({**m.theta_dict(m.default_theta()), **TWO_NODE_SWAPPED})
    x = np.vstack([a, m.canonical_theta(a)])[:, log_post.free]
    assert list(log_post.in_support(x)) == [False, True]
    lp = log_post(x)
    assert lp[0] == -np.inf and np.isfinite(lp[1])


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_effects_earlier_run_state_is_a_run_parameter_pinned_off(name):
    """The state earlier runs left (freed by a joint fit of several records) is among the
    effect's terms, each parameter a run parameter pinned at its off value by default."""
    cls = EFFECTS[name]
    assert set(cls.earlier_run_terms) <= set(cls.terms)
    names = cls.earlier_run_parameters(cls.parameters)
    assert set(names) <= {n for term in cls.earlier_run_terms for n in cls.terms[term]}
    for n in names:
        p = cls.parameters[n]
        assert p.per_record and not p.vary and p.value == cls.off[n], n


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_effect_says_what_tells_it_apart(name):
    """The diagnosis quotes it when two effects fit a record equally well."""
    from identify.diagnosis.explanation import telling_apart

    signature = EFFECTS[name].signature
    assert len(signature) > 30 and not signature.endswith(".")
    other = next(n for n in EFFECTS if n != name)
    text = telling_apart(name, other)
    assert f"'{name}' {signature}" in text and f"'{other}' {EFFECTS[other].signature}" in text
    assert telling_apart(name, f"{other}+{name}") == text  # a pair is described by its members
    assert telling_apart(name) == ""  # one effect: nothing to tell apart


def test_training_with_every_strength_on_batch_is_each_rows_own_output(paper_input):
    """Training's fade is shared between the rows of a batch with the same (V0, p): with its
    strain gain and play width on too (its test parameters leave them at 0), every row of a
    Jacobian's batch is still its own single evaluation, bit for bit."""
    time, current = paper_input[0][::4], paper_input[1][::4]
    m = Model(["training"])
    theta = m.default_theta()
    values = {
        "training_deficit": 0.1,
        "training_threshold": 0.2,
        "training_travel": 3.0,
        "training_shape": 2.0,
        "training_gain": 0.05,
        "training_width": 0.3,
    }
    for key, value in values.items():
        theta[m.names.index(key)] = value
    moves_v0 = m.names.index("training_travel") + 1
    y = _assert_jacobian_batch_rows_are_single(m, theta, time, current, repeats=(moves_v0,))
    assert not np.array_equal(y[0], m(m.default_theta(), time, current))  # the strengths are visible


def _compiled_versions():
    """``{kernel: number of compiled versions}`` of every numba kernel of the model (the GPI's
    kernels and every module of the effects package)."""
    import sys

    import model.gpi_kernels as gpi_kernels
    from model.effects import LIBRARY, _filters

    modules = [gpi_kernels, _filters] + [sys.modules[effect.__module__] for effect in LIBRARY]
    return {
        f"{module.__name__}.{name}": len(obj.signatures)
        for module in modules
        for name, obj in vars(module).items()
        if hasattr(obj, "signatures") and hasattr(obj, "py_func")
    }


def test_read_only_inputs_give_the_same_output_without_another_compiled_kernel(paper_input):
    """numba compiles a kernel once per type of its arguments, and a read-only array (a
    ``broadcast_to`` view, a frozen record column) is another type: every array reaches the
    kernels writeable (:func:`model.gpi.kernel_array`), so read-only inputs compile nothing
    more and give the same bits."""
    time, current = paper_input[0][::8], paper_input[1][::8]
    m = Model(list(EFFECTS))
    theta = m.default_theta()
    for name in EFFECTS:
        for key, value in EFFECTS[name].get_test_parameters().items():
            theta[m.names.index(key)] = value
    batch = np.stack([theta, theta * (1 + 1e-6)])
    expected = m(batch, time, current)
    m(theta, time, current)
    before = _compiled_versions()
    frozen = [np.array(a) for a in (batch, time, current)]
    for a in frozen:
        a.setflags(write=False)
    single = np.broadcast_to(theta, theta.shape)  # a read-only view
    assert np.array_equal(m(*frozen), expected)
    assert np.array_equal(m(single, frozen[1], frozen[2]), expected[0])
    assert _compiled_versions() == before


def test_a_record_that_starts_warm_is_fitted_with_the_start_freed_and_not_by_the_cold_default():
    """The start rises are pinned at 0 by default (a cold start); freed, the least squares
    recovers the heat a run started with, which the cold model cannot reach."""
    from identify.bench import simulate
    from identify.fitting.lsq import fit_least_squares
    from identify.fitting.noise import estimate_noise
    from identify.fitting.parametrisation import normalised_model

    spec = "thermal_tau=8,thermal_sensitivity=0.03,thermal_expansion=3,thermal_initial=0.5,thermal_initial_core=0.2"
    record = simulate(spec, fs=10.0, seed=4, noise_sigma=0.05).record
    noise = estimate_noise(record)
    cold = Model(["thermal"])
    assert not cold.parameters["thermal_initial"].vary and not cold.parameters["thermal_initial_core"].vary
    freed = cold.with_parameters(
        cold.parameters.replace("thermal_initial", vary=True).replace("thermal_initial_core", vary=True)
    )
    fits = [
        fit_least_squares(record, normalised_model(m), noise=noise, n_starts=2, rng=np.random.default_rng(0))
        for m in (cold, freed)
    ]
    assert fits[1].rms < 1.05 * 0.05 < fits[0].rms / 1.5  # the record's noise sigma: 0.05 um
    assert fits[1].theta_dict()["thermal_initial"] == pytest.approx(0.5, abs=0.05)
