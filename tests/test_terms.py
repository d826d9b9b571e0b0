"""Optional effect terms: their declarations across the library, and pinning off what a record does not support."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.bench.synthetic import simulate
from identify.fitting.lsq import FitResult, fit_least_squares
from identify.fitting.noise import estimate_noise
from identify.fitting.parametrisation import normalised_model
from identify.fitting.terms import optional_terms, select_terms
from model import EFFECTS, Effect, Model, Parameter, ParameterSet, register_effect

ONE_POLE = {"thermal": {"thermal_tau": 25.0, "thermal_sensitivity": 0.08, "thermal_expansion": 2.0}}
TWO_NODES = {
    "thermal": {
        "thermal_tau": 3.0,
        "thermal_sensitivity": 0.03,
        "thermal_expansion": -3.0,
        "thermal_tau_core": 60.0,
        "thermal_sensitivity_core": 0.1,
        "thermal_expansion_core": 4.0,
    }
}


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_declared_term_switches_off_at_the_effects_off_values(name):
    cls = EFFECTS[name]
    values = cls.get_test_parameters()
    for term, names in cls.terms.items():
        assert set(names) < set(cls.parameters.names)
        starts = cls.reduced_starts(values, term)
        assert starts and all(set(s) == set(cls.parameters.names) for s in starts)
        for s in starts:
            assert all(s[n] == cls.off[n] for n in names)


def test_thermal_offers_node_two_moved_onto_node_one():
    values = {**Model(["thermal"]).theta_dict(Model(["thermal"]).default_theta()), **TWO_NODES["thermal"]}
    starts = EFFECTS["thermal"].reduced_starts({k: v for k, v in values.items() if k.startswith("thermal")}, "core")
    assert len(starts) == 2
    assert starts[1]["thermal_tau"] == 60.0 and starts[1]["thermal_sensitivity"] == 0.1
    assert starts[1]["thermal_expansion"] == 4.0 and starts[1]["thermal_sensitivity_core"] == 0.0


def test_a_term_must_name_own_parameters_and_leave_a_core():
    def effect(terms):
        return type(
            "Toy",
            (Effect,),
            {
                "name": "toy",
                "stage": "output",
                "terms": terms,
                "off": {"toy_a": 0.0, "toy_b": 1.0},
                "parameters": ParameterSet([Parameter("toy_a", 0.0, -1, 1), Parameter("toy_b", 1.0, 0.5, 2)]),
            },
        )

    with pytest.raises(ValueError, match="own parameters"):
        register_effect(effect({"x": ("lag_tau",)}))
    with pytest.raises(ValueError, match="outside every optional term"):
        register_effect(effect({"x": ("toy_a", "toy_b")}))
    assert "toy" not in EFFECTS


def test_an_effect_of_alternative_forms_keeps_one():
    """An effect whose every parameter lies in a term must name two or more of them as its
    alternative forms, and a fit keeps one of them (:meth:`model.Effect.keeps_a_form`)."""

    def effect(forms):
        return type(
            "Toy",
            (Effect,),
            {
                "name": "toy",
                "stage": "output",
                "terms": {"x": ("toy_a",), "y": ("toy_b",)},
                "forms": forms,
                "off": {"toy_a": 0.0, "toy_b": 1.0},
                "parameters": ParameterSet([Parameter("toy_a", 0.0, -1, 1), Parameter("toy_b", 1.0, 0.5, 2)]),
            },
        )

    with pytest.raises(ValueError, match="'forms' must name two or more"):
        register_effect(effect(("x",)))
    with pytest.raises(ValueError, match="'forms' must name two or more"):
        register_effect(effect(("x", "z")))
    assert "toy" not in EFFECTS
    toy = effect(("x", "y"))
    assert toy.keeps_a_form({"x"}) and toy.keeps_a_form({"y"}) and not toy.keeps_a_form({"x", "y"})
    assert EFFECTS["thermal"].keeps_a_form({"core"})  # no forms: the core is never a term
    creep = EFFECTS["creep"]
    assert set(creep.forms) == {"saturating", "logarithmic"}
    assert not creep.keeps_a_form({"saturating", "logarithmic", "after_reversal"})


def _fit(effects, seed=3):
    record = simulate(effects, fs=20.0, seed=seed).record
    fit = fit_least_squares(
        record,
        normalised_model(Model(["thermal"])),
        noise=estimate_noise(record),
        n_starts=2,
        rng=np.random.default_rng(0),
    )
    return record, fit


def test_one_pole_heating_pins_the_second_node_off_and_two_nodes_keep_it():
    record, fit = _fit(ONE_POLE)
    assert [t[1] for t in optional_terms(fit.model)] == ["core"]
    selected = select_terms(record, fit, rng=np.random.default_rng(0))
    (decision,) = selected.terms
    assert decision["pinned"] and decision["delta_chi2"] <= decision["penalty"]
    assert not selected.model.parameters["thermal_tau_core"].vary
    assert selected.theta_dict()["thermal_sensitivity_core"] == 0.0
    assert abs(selected.theta_dict()["thermal_tau"] - 25.0) < 5.0  # the one pole is on node 1 now
    assert optional_terms(selected.model) == []
    assert (selected.n_starts, selected.starts, selected.n_agree) == (fit.n_starts, fit.starts, fit.n_agree)
    assert selected.seconds >= fit.seconds
    back = FitResult.from_dict(json.loads(json.dumps(selected.to_dict(), allow_nan=False)))
    assert back.terms == selected.terms and back.model == selected.model

    record, fit = _fit(TWO_NODES)
    kept = select_terms(record, fit, rng=np.random.default_rng(0))
    (decision,) = kept.terms
    assert not decision["pinned"] and decision["delta_chi2"] > decision["penalty"]
    assert kept.model.parameters["thermal_tau_core"].vary and np.array_equal(kept.theta, fit.theta)
    values = kept.theta_dict()  # the canonical labelling: the coil (node 1) the faster node
    assert values["thermal_tau"] <= values["thermal_tau_core"]
    assert abs(values["thermal_tau"] - 3.0) < 1.5 and abs(values["thermal_tau_core"] - 60.0) < 20.0


def test_a_model_without_optional_terms_is_returned_as_it_is():
    record = simulate(None, fs=10.0, seed=1).record
    fit = fit_least_squares(
        record, normalised_model(Model(["initial_state"])), noise=estimate_noise(record), n_starts=1
    )
    assert not EFFECTS["initial_state"].terms and select_terms(record, fit) is fit


def test_all_terms_is_a_setting_only_when_set():
    from identify.workflows.study_run import api_settings as _api_settings

    record = simulate(None, fs=10.0, seed=1).record
    common = dict(
        seed=0,
        noise_sigma=None,
        n_starts=1,
        walkers=None,
        max_steps=10,
        check_every=5,
        moves="de",
        report=False,
        priors=None,
    )
    assert "all_terms" not in _api_settings(record, Model(), **common)
    assert _api_settings(record, Model(), **common, select_terms=False)["all_terms"] is True


def test_the_study_pins_an_unsupported_term_and_all_terms_keeps_it(tmp_path):
    from identify import study
    from identify.cli import main as identify_main
    from identify.data.records import write_record
    from identify.output.results import load_fit, read_json

    record = simulate(ONE_POLE, fs=10.0, seed=3).record
    short = dict(seed=0, n_starts=1, max_steps=40, check_every=20, report=False, quiet=True)
    result = study(record, Model(["thermal"]), out=tmp_path / "selected", **short)
    (decision,) = result.fit.terms
    assert decision["term"] == "core" and decision["pinned"]
    stored = load_fit(tmp_path / "selected")
    assert stored.terms == result.fit.terms and not stored.model.parameters["thermal_tau_core"].vary
    assert read_json(tmp_path / "selected" / "summary.json")["fit"]["terms"] == result.fit.terms
    assert "thermal_tau_core" not in result.posterior.names
    assert "all_terms" not in read_json(tmp_path / "selected" / "manifest.json")["settings"]

    write_record(tmp_path / "rec.csv", (record.time, record.current, record.displacement))
    code = identify_main(
        [
            "study",
            str(tmp_path / "rec.csv"),
            "--out",
            str(tmp_path / "all"),
            "--effects",
            "thermal",
            "--all-terms",
            "--n-starts",
            "1",
            "--max-steps",
            "40",
            "--check-every",
            "20",
            "--no-report",
            "-q",
        ]
    )
    assert code in (0, 1)  # 40 steps: converged or not, a result either way
    assert load_fit(tmp_path / "all").terms == []
    assert read_json(tmp_path / "all" / "manifest.json")["settings"]["all_terms"] is True
    assert load_fit(tmp_path / "all").model.parameters["thermal_tau_core"].vary
    varying = [p["name"] for p in read_json(tmp_path / "all" / "summary.json")["parameters"] if p["vary"]]
    assert "thermal_tau_core" in varying


def test_a_first_order_lag_pins_the_dead_time_off_and_a_dead_time_is_kept():
    """lag's dead time is an optional term: a record made without one does not keep a spurious
    one (a compensation could not invert it); a record with one keeps it."""
    decisions = {}
    for label, values in (
        ("first order", {"lag_tau": 0.05, "lag_delay": 0.0}),
        ("dead time", {"lag_tau": 0.02, "lag_delay": 0.06}),
    ):
        record = simulate({"lag": values}, seed=5, fs=50.0).record
        fit = fit_least_squares(record, normalised_model(Model(["lag"])), n_starts=1, rng=np.random.default_rng(0))
        (decisions[label],) = select_terms(record, fit, rng=np.random.default_rng(0)).terms
    assert decisions["first order"]["term"] == "dead_time" and decisions["first order"]["pinned"]
    assert decisions["first order"]["delta_chi2"] <= decisions["first order"]["penalty"]
    assert not decisions["dead time"]["pinned"]
    assert decisions["dead time"]["delta_chi2"] > 3 * decisions["dead time"]["penalty"]


# -- best_form: the BIC's charge for the terms a record uses (the diagnosis' candidates) --------
def _at_truth(effects, seed=4, fs=20.0):
    """``(record, fit-like)``: the model with ``effects`` (every term free) at the true
    parameters of a simulated record; the Wald statistic needs the Jacobian there, not a search."""
    from types import SimpleNamespace

    sim = simulate(effects, fs=fs, seed=seed)
    record = sim.record
    model = normalised_model(Model(list(effects)))
    theta = model.theta_from_dict({n: v for n, v in sim.truth["theta"].items() if n in model.names})
    residual = record.displacement - model(theta, record.time, record.current)
    return record, SimpleNamespace(model=model, theta=theta, noise=estimate_noise(record), residual=residual)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_term_reduction_switches_its_term_off(name):
    cls = EFFECTS[name]
    for term, names in cls.terms.items():
        reductions = cls.term_reductions(term)
        assert reductions[0] == {n: cls.off[n] for n in names}
        for reduction in reductions:
            assert set(reduction) <= set(cls.parameters.names)
            assert all(cls.parameters[n].lower <= v <= cls.parameters[n].upper for n, v in reduction.items())


def test_a_linear_drift_is_not_charged_for_the_settling_and_ambient_terms():
    from identify.fitting.terms import best_form

    record, fit = _at_truth({"sensor_drift": {"sensor_drift_linear": 3.0}})
    form = best_form(record, fit, ["sensor_drift"], n_samples=record.time.size)
    assert sorted(form["terms"]) == [("sensor_drift", "ambient"), ("sensor_drift", "settling")]
    assert form["parameters"] == 5
    assert 0.0 <= form["delta_chi2"] < 5 * np.log(record.time.size)


def test_creep_is_charged_for_the_form_the_record_has_only():
    """Saturating and logarithmic creep are alternative forms: a record of one is not charged
    for the other (nor for the onset after each leg, unused), and a fit never drops both."""
    from identify.fitting.terms import best_form

    log_only = {"creep_amplitude": 0.0, "creep_log_rate": 0.03, "creep_log_onset": 0.1}
    record, fit = _at_truth({"creep": log_only}, fs=100.0)
    form = best_form(record, fit, ["creep"], n_samples=record.time.size)
    assert sorted(form["terms"]) == [("creep", "after_reversal"), ("creep", "saturating")]
    assert form["parameters"] == 4 and form["delta_chi2"] < 4 * np.log(record.time.size)
    record, fit = _at_truth({"creep": {"creep_amplitude": 0.08, "creep_tau": 2.0, "creep_decades": 1.0}}, fs=100.0)
    form = best_form(record, fit, ["creep"], n_samples=record.time.size)
    assert sorted(form["terms"]) == [("creep", "after_reversal"), ("creep", "logarithmic")]
    assert form["parameters"] == 3
    # both forms too small to pay for themselves: one of them is still charged
    tiny = {"creep_amplitude": 1e-4, "creep_tau": 2.0, "creep_decades": 1.0, "creep_log_rate": 1e-4}
    record, fit = _at_truth({"creep": tiny}, fs=100.0)
    form = best_form(record, fit, ["creep"], n_samples=record.time.size)
    dropped = {term for _, term in form["terms"]}
    assert len(dropped & {"saturating", "logarithmic"}) == 1 and "after_reversal" in dropped


def test_select_terms_keeps_the_last_form_of_an_effect():
    """A record without creep fitted with creep: select_terms may pin one form off, never both
    (that would be the model without creep, a choice of effects, not of terms)."""
    record = simulate(None, fs=20.0, seed=5).record
    fit = fit_least_squares(
        record,
        normalised_model(Model(["creep"])),
        noise=estimate_noise(record),
        n_starts=1,
        rng=np.random.default_rng(0),
    )
    selected = select_terms(record, fit, rng=np.random.default_rng(0))
    pinned = {d["term"] for d in selected.terms if d["pinned"]}
    assert len(pinned & {"saturating", "logarithmic"}) == 1, selected.terms
    kept = "logarithmic" if "saturating" in pinned else "saturating"
    names = EFFECTS["creep"].terms[kept]
    assert all(selected.model.parameters[n].vary for n in names)


def test_a_term_the_record_uses_is_charged():
    from identify.fitting.terms import best_form

    values = {
        "sensor_drift_linear": 1.0,
        "sensor_drift_ambient_sine": 2.0,
        "sensor_drift_ambient_cosine": -1.5,
        "sensor_drift_ambient_period": 64.0,
    }
    record, fit = _at_truth({"sensor_drift": values})
    form = best_form(record, fit, ["sensor_drift"], n_samples=record.time.size)
    assert form["terms"] == [("sensor_drift", "settling")]  # the ambient cycle pays for itself
    # and the effects not named are not weighed
    assert best_form(record, fit, ["thermal"], n_samples=record.time.size)["terms"] == []


def test_a_one_pole_heating_on_node_two_is_the_one_node_form(monkeypatch):
    """Node 2 carrying a one-pole heating behind node 1 at its fastest, without gains: the
    second labelling of the one-node form (:meth:`model.Effect.term_reductions`), not charged
    for the core node; the first labelling alone would charge it."""
    from identify.fitting.terms import best_form

    one_pole_on_node_two = {
        "thermal": {
            "thermal_tau": 1.0,
            "thermal_sensitivity": 0.0,
            "thermal_expansion": 0.0,
            "thermal_tau_core": 25.0,
            "thermal_sensitivity_core": 0.08,
            "thermal_expansion_core": 2.0,
        }
    }
    record, fit = _at_truth(one_pole_on_node_two)
    form = best_form(record, fit, ["thermal"], n_samples=record.time.size)
    assert form["terms"] == [("thermal", "core")] and form["parameters"] == 3
    assert form["delta_chi2"] < 3 * np.log(record.time.size)
    first_only = EFFECTS["thermal"].term_reductions("core")[:1]
    monkeypatch.setattr(EFFECTS["thermal"], "term_reductions", classmethod(lambda cls, term: first_only))
    assert best_form(record, fit, ["thermal"], n_samples=record.time.size)["terms"] == []
    monkeypatch.undo()
    # with node 1's fast gains in use, the core node is not the spare one
    used = {"thermal": {**one_pole_on_node_two["thermal"], "thermal_expansion": 4.0}}
    record, fit = _at_truth(used)
    assert best_form(record, fit, ["thermal"], n_samples=record.time.size)["terms"] == []


def test_a_term_at_a_kink_is_weighed_by_switching_it_off():
    """A gain that decays with the cycles, fitted with a soft threshold of 1e-4 A (the threshold's
    kink: a central difference of a few 1e-9 A there is no slope of the fit): the threshold,
    the drive deficit, the width and the fade's shape go uncharged, the strain gain is kept."""
    from identify.fitting.terms import best_form

    gain_decay = {
        "training": {
            "training_deficit": 0.0,
            "training_threshold": 1e-4,
            "training_travel": 16.8,
            "training_shape": 1.0,
            "training_gain": 0.05,
            "training_width": 0.0,
        }
    }
    record, fit = _at_truth(gain_decay)
    form = best_form(record, fit, ["training"], n_samples=record.time.size)
    assert sorted(term for _, term in form["terms"]) == ["drive", "shape", "threshold", "width"]
    assert form["parameters"] == 4


def test_a_training_of_its_strain_gain_alone_is_charged_for_it():
    """A strain gain fading slowly over the whole record (V0 = 50 A, p = 0.93): with the gain
    switched off, the fade length and shape act no more, and their columns at the fit must not
    rebuild the gain in the first-order re-optimisation (they did: every term went uncharged)."""
    from identify.fitting.terms import best_form

    slow_gain = {
        "training": {
            "training_deficit": 0.0,
            "training_threshold": 0.0,
            "training_travel": 50.0,
            "training_shape": 0.93,
            "training_gain": 0.0163,
            "training_width": 0.0,
        }
    }
    record, fit = _at_truth(slow_gain, fs=20.0)
    form = best_form(record, fit, ["training"], n_samples=record.time.size)
    dropped = sorted(term for _, term in form["terms"])
    assert "strain" not in dropped, form
    assert set(dropped) <= {"drive", "shape", "threshold", "width"}
