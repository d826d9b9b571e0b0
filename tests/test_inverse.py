"""The numerical inverse (model/inverse.py): exactness, limits, the Omega switch, batches."""

from __future__ import annotations

import numpy as np
import pytest

from model import EFFECTS, TABLE1, Effect, Model, paper_current
from model.inverse import STATUS_BRANCH, STATUS_EXACT, STATUS_SATURATED, invert


def _theta(model: Model, **overrides):
    values = dict(zip(model.names[:19], TABLE1))
    for effect in model.effect_names:
        values.update(EFFECTS[effect].get_test_parameters())
    values.update(overrides)
    return model.theta_from_dict(values)


def _triangle(fs=100.0, duration=30.0, low=30.0, high=270.0, period=10.0):
    t = np.arange(0.0, duration, 1.0 / fs)
    phase = (t / period) % 1.0
    return t, low + (high - low) * np.where(phase < 0.5, 2 * phase, 2 - 2 * phase)


def _multisine(fs=100.0, duration=30.0):
    t = np.arange(0.0, duration, 1.0 / fs)
    y = (
        150
        + 60 * np.sin(2 * np.pi * 0.13 * t)
        + 40 * np.sin(2 * np.pi * 0.31 * t + 1)
        + 20 * np.sin(2 * np.pi * 0.71 * t + 2)
    )
    return t, y


def _inverted_exactly(model, theta, time, target, rtol):
    """Invert ``target``; assert every sample exact and the model on the found drive (and the
    kernel's own forward) within ``rtol`` of the target's scale. Returns the result."""
    result = invert(model, theta, time, target)
    assert (result.status == STATUS_EXACT).all()
    again = model(theta, time, result.current)
    scale = np.abs(target).max()
    assert np.abs(again - target).max() < rtol * scale
    assert np.abs(result.output - again).max() < rtol * scale  # the kernel's own forward = Model's
    return result


@pytest.mark.parametrize(
    "effects", [[], ["creep"], ["training"], ["initial_state"], ["sensor_drift"], ["creep", "training", "sensor_drift"]]
)
def test_a_target_made_by_the_model_is_reproduced_to_rounding(effects):
    """The paper's input through the model, then inverted: the model on the inverse's drive
    gives the target back to rounding at every sample (dead zones, quiet start, reversals)."""
    model = Model(effects)
    theta = _theta(model)
    time, current = paper_current(fs=100)
    target = model(theta, time, current)
    result = _inverted_exactly(model, theta, time, target, 1e-13)
    assert result.current.min() >= 0.0 and result.current.max() <= 5.0


@pytest.mark.parametrize("excursion", [-3.0, 2.0, 8.0])
def test_a_prior_excursion_is_inverted_to_rounding(excursion):
    """``initial_state``'s prior excursion (the memory the record starts from, below, within
    and beyond the record's range) is part of the inverse's first step."""
    model = Model(["initial_state", "creep"])
    theta = _theta(model, initial_state_excursion=excursion)
    time, current = paper_current(fs=100)
    target = model(theta, time, current)
    plain = model(_theta(model), time, current)
    assert np.abs(target - plain).max() > 0.1  # the excursion is seen
    _inverted_exactly(model, theta, time, target, 1e-13)


@pytest.mark.parametrize("held, slope", [(0.4, 0.0), (-0.3, 0.8), (2.0, -1.5)])
def test_a_held_initial_memory_is_inverted_to_rounding(held, slope):
    """``initial_state``'s memory held beyond the bounds (kept through the first loading)
    is part of the inverse's first step and of the memory it carries."""
    model = Model(["initial_state", "creep"])
    theta = _theta(model, initial_state_held=held, initial_state_held_slope=slope)
    time, current = paper_current(fs=100)
    target = model(theta, time, current)
    plain = model(_theta(model), time, current)
    assert np.abs(target - plain).max() > 0.1  # the held memory is seen
    _inverted_exactly(model, theta, time, target, 1e-13)


@pytest.mark.parametrize(
    "effects", [[], ["thermal"], ["creep"], ["training"], ["thermal", "creep", "training", "initial_state"]]
)
@pytest.mark.parametrize("shape", ["triangle", "multisine"])
def test_user_targets_are_followed_exactly(effects, shape):
    """Targets that were not made by the model (a triangle, a multi-sine) within the range."""
    model = Model(effects)
    theta = _theta(model)
    time, target = _triangle() if shape == "triangle" else _multisine()
    result = invert(model, theta, time, target)
    assert (result.status == STATUS_EXACT).all()
    again = model(theta, time, result.current)
    assert np.abs(again - target).max() < 1e-12 * np.abs(target).max()


def test_thermal_model_made_target_is_followed_to_its_dead_zones():
    """Thermal heats with the present current, so inside a dead zone (operators still) the
    output depends on the current by ~1e-3 um/A and is not monotone; a target made by the
    model through dead zones is then not unique: documented, measured here."""
    model = Model(["thermal"])
    theta = _theta(model)
    time, current = paper_current(fs=100)
    target = model(theta, time, current)
    result = invert(model, theta, time, target)
    exact = result.status == STATUS_EXACT
    assert exact.mean() > 0.85
    assert exact[:1700].all()  # up to the first dead zone after the first peak


def test_a_batch_is_the_rows_inverted_one_by_one():
    model = Model(["thermal"])
    theta = _theta(model)
    rng = np.random.default_rng(3)
    batch = theta[None, :] * (1.0 + 2e-3 * rng.standard_normal((5, theta.size)))
    batch[:, 0] = theta[0]
    time, target = _multisine(duration=10.0)
    together = invert(model, batch, time, target)
    assert together.current.shape == (5, time.size)
    for w in range(5):
        alone = invert(model, batch[w], time, target)
        np.testing.assert_array_equal(alone.current, together.current[w])
        np.testing.assert_array_equal(alone.status, together.status[w])
    again = invert(model, batch, time, target)
    np.testing.assert_array_equal(again.current, together.current)  # deterministic


def test_targets_beyond_the_current_limits_saturate():
    model = Model()
    time, target = _triangle(low=30.0, high=320.0)  # Table 1 peaks at ~296 um at 5 A
    result = invert(model, TABLE1, time, target)
    saturated = result.status == STATUS_SATURATED
    assert saturated.any()
    assert np.all(result.current[saturated] == 5.0)
    assert np.all(result.error[saturated] < 0)  # short of the target, never beyond it
    assert (result.status[target < 280] == STATUS_EXACT).all()
    narrow = invert(model, TABLE1, time, np.clip(target, 30, 280), current_range=(0.0, 3.0))
    assert narrow.current.max() == 3.0 and (narrow.status == STATUS_SATURATED).any()


def test_the_omega_gap_at_a_reversal_is_at_most_half_the_jump():
    """With Omega's rising branch above its falling one, a reversal makes the output jump
    away from a target that turns: the inverse keeps the nearer output (flagged)."""
    model = Model()
    theta = TABLE1.copy()
    theta[14], theta[18] = TABLE1[18] + 1.0, TABLE1[14]  # c3 > d3: Omega_c above Omega_d
    time, target = _triangle()
    result = invert(model, theta, time, target)
    jump = 1.0 + (TABLE1[18] - TABLE1[14]) + 2 * (TABLE1[11] + TABLE1[15])  # bound on |Omega_c - Omega_d|
    branch = result.status == STATUS_BRANCH
    assert branch.any()
    assert np.abs(result.error[branch]).max() <= 0.5 * jump + 1e-9
    assert (result.status != STATUS_SATURATED).all()
    # away from the reversals the target is followed exactly
    assert (result.status == STATUS_EXACT).mean() > 0.9


def test_a_lag_is_inverted_and_saturates_only_where_the_drive_must_step():
    """At a reversal the Omega switch needs the drive to cross a dead zone at once; a lag
    cannot, so the current sits at its limit for a few samples after each reversal (5 after a
    peak, 1 after a trough here), exact elsewhere."""
    model = Model(["lag"])
    theta = _theta(model)
    time, target = _triangle()
    result = invert(model, theta, time, target)
    assert result.current.min() >= 0.0 and result.current.max() <= 5.0
    again = model(theta, time, result.current)
    np.testing.assert_allclose(again, result.output, rtol=0, atol=1e-10)
    not_exact = np.flatnonzero(result.status != STATUS_EXACT)
    assert not_exact.size < 0.02 * time.size
    reversals = np.array([500, 1000, 1500, 2000, 2500])
    assert all(np.min(np.abs(reversals - k)) <= 10 for k in not_exact)
    assert (result.status[not_exact] == STATUS_SATURATED).all()


#: every extra term of each general form on (beyond the test parameters, the simpler forms)
GENERAL_FORMS = {
    "training": {
        "training_deficit": 0.08,
        "training_threshold": 0.1,
        "training_travel": 6.0,
        "training_shape": 1.5,
        "training_gain": 0.06,
        "training_width": 0.3,
    },
    "creep": {
        "creep_amplitude": 0.03,
        "creep_tau": 2.0,
        "creep_decades": 2.0,
        "creep_log_rate": 0.004,
        "creep_log_onset": 0.2,
        "creep_log_hold": 0.5,
    },
    "thermal": {
        "thermal_tau": 8.0,
        "thermal_sensitivity": 0.02,
        "thermal_expansion": 1.5,
        "thermal_tau_core": 120.0,
        "thermal_sensitivity_core": 0.03,
        "thermal_expansion_core": -2.0,
    },
    "sensor_drift": {
        "sensor_drift_linear": 1.0,
        "sensor_drift_quadratic": -0.5,
        "sensor_drift_settling": 2.0,
        "sensor_drift_settling_tau": 12.0,
        "sensor_drift_ambient_sine": 0.8,
        "sensor_drift_ambient_cosine": -0.6,
        "sensor_drift_ambient_period": 64.0,
    },
}


@pytest.mark.parametrize(
    "effects",
    [["training"], ["creep"], ["thermal"], ["sensor_drift"], ["training", "creep", "thermal", "sensor_drift"]],
)
def test_the_general_forms_are_inverted_exactly(effects):
    """Each supported effect with every term of its general form on (training's strain part,
    creep's logarithmic part, thermal's second node, the settling and ambient drift): the model on the
    inverse's drive gives the target back to rounding, and the kernel's own output is the
    Model's (an inverse that left a term out would report 'exact' for a drive that misses)."""
    model = Model(effects)
    values = {}
    for effect in effects:
        values.update(GENERAL_FORMS[effect])
    theta = _theta(model, **values)
    time, current = paper_current(fs=100)
    current = 0.5 + 0.8 * current  # inside the limits, so every sample can be reached
    target = model(theta, time, current)
    result = _inverted_exactly(model, theta, time, target, 1e-12)
    scale = np.abs(target).max()
    # each general term matters on this target: without it the model misses by far more
    for effect in effects:
        simple = dict(values)
        simple.update({k: v for k, v in EFFECTS[effect].get_test_parameters().items() if k in GENERAL_FORMS[effect]})
        assert np.abs(model(_theta(model, **simple), time, result.current) - target).max() > 1e-3 * scale


def test_a_dead_time_is_refused_with_its_reason():
    model = Model(["lag"])
    time, current = paper_current(fs=100)
    theta = _theta(model, lag_tau=0.02, lag_delay=0.0)
    target = model(theta, time, 0.5 + 0.8 * current)
    invert(model, theta, time, target)  # a first-order lag alone is inverted
    with pytest.raises(ValueError, match=r"lag's dead time \(lag_delay = 0.03 s in parameter set 0\)"):
        invert(model, _theta(model, lag_tau=0.02, lag_delay=0.03), time, target)


def test_an_effect_without_an_inverse_step_is_named():
    class Backlash(Effect):
        name = "backlash_test"
        stage = "output"

    model = Model([Backlash()])
    with pytest.raises(ValueError, match="backlash_test"):
        invert(model, model.default_theta(), np.arange(3.0), np.zeros(3))


def test_malformed_arguments_raise():
    model = Model()
    time, target = _triangle(duration=1.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        invert(model, TABLE1, time[::-1], target)
    with pytest.raises(ValueError, match="lo < hi"):
        invert(model, TABLE1, time, target, current_range=(5.0, 0.0))
    with pytest.raises(ValueError, match="shape"):
        invert(model, TABLE1[:5], time, target)
    with pytest.raises(ValueError, match="finite"):
        invert(model, TABLE1, time, np.where(time > 0.5, np.nan, target))
