"""Several records of one transducer fitted together (identify.fitting.joint)."""

from __future__ import annotations

import numpy as np
import pytest

from identify.bench import simulate
from identify.diagnosis import Thresholds
from identify.diagnosis.joint import (
    explanations_worth_finishing,
    rival_pair_names,
    short_ends_to_finish,
    started_warm,
    tie_member_pairs,
)
from identify.fitting.joint import JointModel, JointResiduals, fit_joint, with_earlier_runs
from identify.fitting.noise import estimate_noise
from identify.fitting.parametrisation import normalised_model
from model import EFFECTS, Model


def test_the_joint_layout_shares_the_transducer_and_gives_each_record_its_run():
    """Every model parameter is shared; each further record has its own copy of the parameters
    an effect declares to belong to the run, and its own zero."""
    model = normalised_model(Model(["thermal", "sensor_drift"]))
    joint = JointModel(model, 3)
    drift = [p.name for p in EFFECTS["sensor_drift"].parameters]
    warm = ["thermal_initial", "thermal_initial_core"]  # the heat each run starts with
    assert joint.per_record == tuple(warm + drift)
    assert joint.n_parameters == model.n_parameters + 2 * (len(warm) + len(drift) + 1)
    assert "sensor_drift_linear_r2" in joint.names and "zero_r3" in joint.names
    thermal_per_run = {n for n in joint.names if n.startswith("thermal") and n.endswith("_r2")}
    assert thermal_per_run == {"thermal_initial_r2", "thermal_initial_core_r2"}  # the network is shared
    rng = np.random.default_rng(0)
    thetas = [model.default_theta() for _ in range(3)]
    for theta in thetas:
        theta[model.names.index("sensor_drift_linear")] = rng.normal()
    theta = joint.joint_theta(thetas, zeros=[0.0, 1.5, -2.0])
    for r in (1, 2, 3):
        rows, zero = joint.record_rows(theta, r)
        np.testing.assert_array_equal(rows[0], thetas[r - 1])
        assert zero[0] == [0.0, 1.5, -2.0][r - 1]
    assert (joint + "creep").model.effect_names == ("creep", "thermal", "sensor_drift")
    names = joint.names
    assert [names[c] for c in joint.columns_of("thermal_initial")] == [
        "thermal_initial",
        "thermal_initial_r2",
        "thermal_initial_r3",
    ]
    assert [names[c] for c in joint.columns_of("thermal_tau")] == ["thermal_tau"]  # shared: one column
    with pytest.raises(KeyError, match="creep_amplitude"):
        joint.columns_of("creep_amplitude")


@pytest.mark.parametrize(
    ("effects", "core", "freed"),
    [
        (["thermal"], True, {"thermal_initial", "thermal_initial_core"}),
        (["thermal"], False, {"thermal_initial"}),  # node 2 pinned off: its start does nothing
        (["creep", "sensor_drift"], True, set()),
    ],
)
def test_a_joint_fit_frees_the_state_earlier_runs_left(effects, core, freed):
    """A coil still warm from the last run: pinned for one record, free in a joint fit."""
    model = Model(effects)
    if not core:
        model = model.with_parameters(model.parameters.replace("thermal_tau_core", vary=False))
    joint = with_earlier_runs(model)
    assert {p.name for p in joint.parameters if p.vary} - {p.name for p in model.parameters if p.vary} == freed
    assert (joint is model) == (not freed)


def test_one_record_is_the_model_itself():
    sim = simulate(None, seed=0, fs=10.0)
    model = normalised_model(Model())
    noise = estimate_noise(sim.record)
    joint = JointResiduals([sim.record], JointModel(model, 1), [noise])
    from identify.fitting.lsq import WhitenedResiduals

    single = WhitenedResiduals(sim.record, model, noise)
    x = model.default_theta()[single.free]
    np.testing.assert_array_equal(joint(x), single(x))


@pytest.fixture(scope="module")
def two_records():
    """One transducer (the Table 1 GPI with a hidden heating) on the paper's drive and on the
    drive with holds and a quiet end, 10 Hz."""
    spec = "thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5"
    return [simulate(spec, seed=1, fs=10.0).record, simulate(spec, seed=2, fs=10.0, drive="holds").record]


def test_a_joint_fit_of_one_transducer_is_consistent_and_at_the_noise(two_records):
    fit = fit_joint(two_records, normalised_model(Model(["thermal"])), n_starts=2)
    assert fit.consistency["consistent"] and fit.consistency["p"] > 1e-3
    for f, alone in zip(fit.fits, fit.separate):
        assert f.rms < 1.05 * alone.rms and f.rms / 0.5 < 1.1  # the bench's noise sigma is 0.5 um
    assert abs(fit.theta_dict()["zero_r2"]) < 0.5  # the same sensor zero


def test_the_consistency_rule():
    """The joint chi-square's excess over the separate fits' against its degrees of freedom; a
    record is named only when the test fails and its RMS also rises by more than 10 %."""
    from types import SimpleNamespace

    from identify.fitting.joint import consistency

    model = normalised_model(Model(["thermal"]))
    joint = JointModel(model, 2)
    free = int(model.parameters.vary.sum())

    def fit(chi2, rms):
        return SimpleNamespace(chi2=chi2, rms=rms, vary=model.parameters.vary)

    records = [SimpleNamespace(source="a.csv"), SimpleNamespace(source="b.csv")]
    dof = 2 * free - int(joint.parameters.vary.sum())
    ok = consistency(2000.0 + dof, [fit(1000.0, 0.5), fit(1000.0, 0.5)], joint, [fit(0, 0.5), fit(0, 0.505)], records)
    assert ok["consistent"] and ok["dof"] == dof and 0.3 < ok["p"] < 0.7
    bad = consistency(2600.0, [fit(1000.0, 0.5), fit(1000.0, 0.5)], joint, [fit(0, 0.5), fit(0, 0.65)], records)
    assert not bad["consistent"] and bad["disagreeing"] == "b.csv" and "30 % worse" in bad["message"]
    spread = consistency(2600.0, [fit(1000.0, 0.5), fit(1000.0, 0.5)], joint, [fit(0, 0.52), fit(0, 0.52)], records)
    assert spread["consistent"] and spread["p"] < 1e-6  # a worse joint fit, but no record fits clearly worse


@pytest.mark.slow
def test_records_that_do_not_belong_together_are_named(two_records):
    """The second record's sensor re-zeroed with another gain: the joint fit is much worse than
    the separate fits, and the record that disagrees is named."""
    from dataclasses import replace

    first, second = two_records
    regained = replace(second, displacement=1.3 * second.displacement, source="the re-gained record")
    fit = fit_joint([first, regained], normalised_model(Model(["thermal"])), n_starts=2)
    check = fit.consistency
    assert not check["consistent"] and check["p"] < 1e-6
    assert check["disagreeing"] in ("the re-gained record", first.source)
    assert "do not look like one transducer" in check["message"]


def test_records_that_cannot_be_one_transducers_are_refused_naming_the_record():
    from dataclasses import replace

    from identify.diagnosis import diagnose

    a = simulate(None, seed=1, fs=5.0).record
    b = simulate(None, seed=2, fs=5.0).record
    with pytest.raises(ValueError, match="empty"):
        diagnose([])
    with pytest.raises(ValueError, match=r"\(seed 1\): the same data as record 1"):
        diagnose([a, replace(a)])
    volts = replace(b, input_unit="V", source="volts.csv")
    with pytest.raises(ValueError, match="volts.csv: drive in V"):
        fit_joint([a, volts], normalised_model(Model()))
    quiet_less = replace(b, current=b.current + 1.0, source="no-quiet.csv")
    with pytest.raises(ValueError, match="no-quiet.csv"):
        fit_joint([a, quiet_less], normalised_model(Model()))


@pytest.mark.slow
def test_the_joint_diagnosis_names_creep_with_a_record_of_holds():
    """A creep on the paper's drive and on the drive with holds and a quiet end: the joint
    verdict names it, and it repairs each record."""
    from identify.diagnosis import diagnose

    spec = "creep_amplitude=0.03"
    records = [simulate(spec, seed=1, fs=25.0).record, simulate(spec, seed=2, fs=25.0, drive="holds").record]
    d = diagnose(records, rng=np.random.default_rng(0))
    assert d.status == "missing_effect" and d.missing == "creep", d.reason
    assert d.adequate_by_record["creep"] == [True, True]
    assert len(d.to_dict()["records"]) == 2
    # a pair never ends above one of its members, as a model never ends above one it contains
    chi2 = {e.name: e.chi2 for e in d.evidence.explanations}
    for name, value in chi2.items():
        members = [chi2[m] for m in name.split("+") if "+" in name and m in chi2]
        assert all(value <= m + 1e-6 * m for m in members), (name, value, members)


def test_the_joint_stage_fits_what_the_records_together_ask_for():
    """Two runs whose sensor drifts go the other way: a creep's shared parameters mimic each
    drift alone (each record alone is adequate with it, and finishes no candidate), not both
    together. The joint baseline's residual asks for the drift, and the joint stage fits it: it
    repairs both records (it may tie with a heating whose runs start warm)."""
    from identify.diagnosis import diagnose

    records = [
        simulate("sensor_drift_linear=1.5", seed=1, fs=10.0).record,
        simulate("sensor_drift_linear=-1.5", seed=2, fs=10.0).record,
    ]
    d = diagnose(records, ["creep"], rng=np.random.default_rng(0))
    assert [r["alone"] for r in d.records] == ["adequate", "adequate"]  # the path under test
    assert not any(r["adequate"] for r in d.records)
    assert d.status in ("missing_effect", "tied") and "sensor_drift" in (d.missing, *d.tied), d.reason
    assert d.adequate_by_record["sensor_drift"] == [True, True]


@pytest.mark.slow
def test_a_second_run_that_starts_warm_is_the_heating_alone():
    """One heating, the second run started while the coil was still warm: jointly, the heating
    alone repairs both records, each record's start its own (with every run pinned cold it
    repairs neither)."""
    from identify.diagnosis import diagnose

    spec = "thermal_tau=30,thermal_expansion=3"
    records = [simulate(spec, seed=1, fs=10.0).record, simulate(spec + ",thermal_initial=0.6", seed=2, fs=10.0).record]
    d = diagnose(records, rng=np.random.default_rng(0))
    assert d.status == "missing_effect" and d.missing == "thermal", d.reason
    assert d.adequate_by_record["thermal"] == [True, True]
    assert "Two effects" not in d.reason


def test_the_diagnose_command_refuses_a_record_given_twice(tmp_path, capsys):
    from identify.cli import main
    from identify.data.records import write_record

    path = tmp_path / "a.csv"
    write_record(path, simulate(None, seed=1, fs=5.0).record)
    out = tmp_path / "never"
    assert main(["diagnose", str(path), str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "a record given twice" in err and err.count("\n") == 1
    assert not (out / "diagnosis.json").exists()


def test_the_joint_log_likelihood_is_the_sum_of_each_records_own(two_records):
    """Each record scored with its own noise model, its own run parameters and zero; the
    posterior is the prior plus their sum."""
    from identify.fitting.joint_posterior import JointLogPosterior
    from identify.fitting.noise import log_likelihood

    model = normalised_model(Model(["thermal"]))
    joint = JointModel(model, 2)
    noises = [estimate_noise(r) for r in two_records]
    log_post = JointLogPosterior(two_records, joint, noises)
    theta = joint.default_theta()
    theta[joint.names.index("zero_r2")] = 0.3
    x = theta[log_post.free]
    expected = []
    for r, (record, noise) in enumerate(zip(two_records, noises), start=1):
        rows, zero = joint.record_rows(theta, r)
        residual = record.displacement - (model(rows[0], record.time, record.current) + zero[0])
        expected.append(log_likelihood(residual, noise))
    parts = log_post.record_log_likelihoods(theta[None, :])[:, 0]
    np.testing.assert_allclose(parts, expected, rtol=1e-10)
    assert log_post(x) == pytest.approx(log_post.log_prior(x[None, :])[0] + sum(expected), rel=1e-10)
    outside = x.copy()
    outside[log_post.names.index("zero_r2")] = 1e9
    assert log_post(outside) == -np.inf


@pytest.mark.parametrize(
    "strength, max_refits, expected",
    [
        ({"a": 100.0, "b": 50.0}, 3, []),  # no pair fitted: nothing to name from a pair
        # the best pair a+b names a: every single with a gain in a's place (each names another
        # effect), and c in b's place (stronger alone than a: it would be that pair's name)
        (
            {"a": 1000.0, "b": 300.0, "c": 1343.0, "d": 200.0, "a+b": 1876.0, "c+d": 1500.0},
            3,
            [("c+b", "a+b", "c"), ("d+b", "a+b", "d"), ("a+c", "a+b", "c")],
        ),
        # c+b fitted already (in the other order): only the other swap
        ({"a": 1000.0, "b": 300.0, "c": 1343.0, "a+b": 1876.0, "b+c": 1700.0}, 3, [("a+c", "a+b", "c")]),
        # c weaker than the partner b alone: c+b would name b, not a; a+c would still name a
        ({"a": 1000.0, "b": 300.0, "c": 250.0, "a+b": 1876.0}, 3, [("c+b", "a+b", "c")]),
        # c far behind a alone: no bound on the pair's gain rules c+b out (overlapping explanations)
        ({"a": 1000.0, "b": 100.0, "c": 800.0, "a+b": 1100.0}, 3, [("c+b", "a+b", "c")]),
        # a single without a gain is no rival
        ({"a": 1000.0, "b": 100.0, "c": -5.0, "a+b": 1100.0}, 3, []),
        # the partner b never fitted alone (no record found it worth finishing): it gains nothing
        # alone, so a is named; c is swapped in for a, and for b (stronger alone than a)
        ({"a": 1000.0, "c": 1343.0, "a+b": 1876.0}, 3, [("c+b", "a+b", "c"), ("a+c", "a+b", "c")]),
        # the named member second in the pair's name: the same rule by strength, not by position
        ({"a": 300.0, "b": 1000.0, "c": 250.0, "a+b": 1876.0}, 3, [("a+c", "a+b", "c")]),
        # at most max_refits swaps per member, strongest first
        (
            {"a": 1000.0, "b": 900.0, "c": 1200.0, "d": 1100.0, "a+b": 2500.0},
            1,
            [("c+b", "a+b", "c"), ("a+c", "a+b", "c")],
        ),
    ],
)
def test_rival_pairs_of_the_best_joint_pair(strength, max_refits, expected):
    assert rival_pair_names(strength, max_refits) == expected


@pytest.mark.parametrize(
    ("tied", "strength", "expected"),
    [
        # singles only: nothing to recombine
        (["a", "b"], {"a": 10.0, "b": 9.0}, []),
        # two pairs sharing a member: their other members are never fitted together
        (
            ["a+b", "a+c"],
            {"a": 100.0, "b": 50.0, "c": 40.0, "a+b": 130.0, "a+c": 128.0},
            [("b+c", ("a+b", "c"))],  # started from the stronger pair that holds one of them
        ),
        # every pair of the members already fitted: the tie stands as it is
        (["a+b", "a+c"], {"a": 1.0, "b": 1.0, "c": 1.0, "a+b": 3.0, "a+c": 3.0, "b+c": 2.0}, []),
        # the tie of four pairs over four members: the two never fitted, the strongest members
        # first; c never fitted alone, so only a pair holding c and the other's single start it
        (
            ["t+s", "s+c", "r+s", "r+t"],
            {"t": 900.0, "r": 800.0, "s": 700.0, "t+s": 1500.0, "s+c": 1490.0, "r+s": 1480.0, "r+t": 1470.0},
            [("t+c", ("s+c", "t")), ("c+r", ("s+c", "r"))],
        ),
        # b never fitted alone: both new pairs start from the pair that holds a member and c's single
        (["a+b", "c"], {"a": 5.0, "a+b": 6.0, "c": 6.0}, [("a+c", ("a+b", "c")), ("b+c", ("a+b", "c"))]),
    ],
)
def test_a_tie_of_pairs_is_a_verdict_once_every_pair_of_its_members_is_fitted(tied, strength, expected):
    assert tie_member_pairs(tied, strength) == expected


def _tried(name, gain, adequate=False):
    """A candidate as a record's diagnosis holds it: refitted, its gain, whether it repairs."""
    from types import SimpleNamespace

    return SimpleNamespace(effect=name, delta_bic=gain, adequate_after=adequate, refitted=True, fit=object())


@pytest.mark.parametrize(
    ("records", "expected"),
    [
        # a pair each record names in its own order is one model, fitted once (the first order)
        ([([], [("a+b", 50.0)]), ([], [("b+a", 60.0)])], ["a+b"]),
        # singles of both records, the second's new one after; a gain of zero is no candidate
        ([([("a", 30.0), ("c", 0.0)], []), ([("b", 20.0), ("a", 10.0)], [])], ["a", "b"]),
        # the ones that repair a record are kept beyond the max_refits best
        ([([("a", 30.0), ("b", 20.0), ("c", 10.0), ("d", 5.0, True)], [])], ["d", "a", "b", "c"]),
    ],
)
def test_the_explanations_the_records_found_worth_finishing(records, expected):
    from types import SimpleNamespace

    alone = [
        SimpleNamespace(ranking=[_tried(*s) for s in singles], pairs_tried=[_tried(*p) for p in pairs])
        for singles, pairs in records
    ]
    assert explanations_worth_finishing(alone, Thresholds(max_refits=3)) == expected


@pytest.mark.parametrize(
    ("effects", "warm"),
    [
        (["thermal"], {"thermal_initial": 1.0, "thermal_initial_core": 1.0}),  # [0, 2], off at 0
        (["creep", "thermal"], {"thermal_initial": 1.0, "thermal_initial_core": 1.0}),
        (["creep"], None),  # no state earlier runs leave
        ([], None),
    ],
)
def test_a_joint_start_with_every_record_started_warm(effects, warm):
    """The warm joint start puts each record's earlier-run state halfway into its range (every
    record's column) and leaves every other parameter where it was."""
    joint = JointModel(with_earlier_runs(Model(effects)), 3)
    theta = joint.default_theta()
    started = started_warm(joint, theta)
    if warm is None:
        assert started is None
        return
    moved = {c: value for name, value in warm.items() for c in joint.columns_of(name)}
    assert len(moved) == 3 * len(warm)  # one column per record
    expected = theta.copy()
    for column, value in moved.items():
        expected[column] = value
    np.testing.assert_array_equal(started, expected)
    assert started is not theta and np.all(theta[list(moved)] == 0.0)


@pytest.mark.parametrize(
    ("best_chi2", "short_chis", "finished"),
    [
        # no other start run (an effect no record fitted alone): every short end is finished
        (None, [120.0, 90.0], [0, 1]),
        # the other starts' fits end above a short run already made: that run is finished too
        (30653.2, [30563.5], [0]),
        # only the short ends below the other starts' best
        (100.0, [99.0, 100.0, 101.0], [0]),
        # the other starts end lower: no further run
        (50.0, [60.0], []),
        (50.0, [], []),
    ],
)
def test_a_joint_fit_never_ends_above_its_own_short_refit(best_chi2, short_chis, finished):
    """An explanation's fit is finished from where its short joint refits ended wherever they lie
    below where its other starts end (the truth's joint fit left in a record's own basin while a
    short run of it had already gone lower)."""
    ends = [(chi2, np.full(3, float(k))) for k, chi2 in enumerate(short_chis)]
    starts = short_ends_to_finish(best_chi2, ends)
    assert [int(s[0]) for s in starts] == finished
