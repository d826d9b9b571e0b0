"""Fast tests of the diagnosis: the adequacy rule, the screening, the start strategies, the
evidence, the decision as a table, the explanation's sentences, and the command's contract.

The decision is a pure function of the evidence, so it is tested as a table of rows built
from :class:`~identify.diagnosis.evidence.Evidence` objects (:func:`test_decision_table`);
the search is tested by what it finds on records. The end-to-end statistics (every library
effect named, no false alarm over seeds, effects outside the library, two hidden effects) are
in tests/test_diagnose_slow.py.
"""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import pytest

from identify.bench import simulate
from identify.cli import main
from identify.data.records import load_record, write_record
from identify.data.reversals import find_reversals
from identify.diagnosis import RULES, STATUSES, Adequacy, Thresholds, assess_adequacy, decide, diagnose, explain
from identify.diagnosis.adequacy import excess_over_noise, rms_change_and_size
from identify.diagnosis.candidates import first_loading_share
from identify.diagnosis.evidence import Evidence, Explanation, Gap, gap_noise_sd, gaps_among
from identify.diagnosis.explanation import noise_tests_text
from identify.diagnosis.fits import (
    SCREENING_SAMPLES,
    embed,
    plain_of,
    same_threshold_sign,
    short_refit,
    working_copy,
)
from identify.diagnosis.reparametrisation import GPI_EQUIVALENTS, exact_reparametrisation
from identify.diagnosis.residuals import ARNoise, residual_profile
from identify.diagnosis.screening import SCREENING_GRIDS, screen_candidates, screening_grid
from identify.diagnosis.search import short_of_promise
from identify.diagnosis.starts import carried, data_driven, members, near, screening_step
from identify.fitting.lsq import fit_least_squares
from identify.fitting.noise import estimate_noise
from identify.fitting.parametrisation import normalised_model, with_threshold_sign
from model import EFFECTS, Model, paper_current

# -- adequacy ---------------------------------------------------------------------------------


def _profile(residual, time, current, sigma=1.0, n_quiet=10**6):
    noise = ARNoise(np.zeros(0), sigma, sigma, n_quiet)
    return residual_profile(time, current, residual, slice(0, 1001), output_range=300.0, noise=noise)


def test_adequacy_rule_white_structured_and_negligible():
    time, current = paper_current(100.0)
    rng = np.random.default_rng(0)
    white = rng.standard_normal(time.size)
    assert assess_adequacy(_profile(white, time, current)).adequate

    slow = 0.3 * np.sin(2 * np.pi * time / 7.0)  # RMS 0.21 sigma: above the 0.1 sigma floor
    verdict = assess_adequacy(_profile(white + slow, time, current))
    assert not verdict.adequate and "low_frequency" in verdict.failed
    assert verdict.excess_kind == "low_frequency"
    assert verdict.structure_rms == pytest.approx(0.3 / np.sqrt(2), rel=0.25)

    # 70001 samples resolve structure of 0.07 sigma RMS (low-frequency z ~ 12), but it is below the floor
    time_k, current_k = paper_current(1000.0)
    tiny = rng.standard_normal(time_k.size) + 0.1 * np.sin(2 * np.pi * time_k / 7.0)
    profile = residual_profile(
        time_k, current_k, tiny, slice(0, 10001), output_range=300.0, noise=ARNoise(np.zeros(0), 1.0, 1.0, 10**6)
    )
    verdict = assess_adequacy(profile)
    assert verdict.failed and verdict.adequate
    assert not assess_adequacy(profile, Thresholds(structure_floor=0.01)).adequate


def test_thresholds_are_validated():
    with pytest.raises(ValueError, match="explained_minor"):
        Thresholds(explained_minor=None)
    with pytest.raises(ValueError, match="z_critical"):
        Thresholds(z_critical=float("nan"))
    with pytest.raises(ValueError, match="max_refits"):
        Thresholds(max_refits=-1)
    with pytest.raises(ValueError, match="practical_rms_change"):
        Thresholds(practical_rms_change=-0.1)


def test_the_practical_size_and_the_excess_over_the_noise():
    """0.6999 -> 0.6947 um at sigma 0.738 um (0.74 %, 0.115 sigma explained) is below the practical
    size; 1.022 -> 1.0 sigma (2.2 %, 0.21 sigma) is above; a residual below the noise holds no
    excess to explain."""
    change, size = rms_change_and_size(0.6999, 0.6947, 0.738)
    assert change == pytest.approx(0.0074, abs=1e-4) and size == pytest.approx(0.115, abs=1e-3)
    change, size = rms_change_and_size(1.022, 1.0, 1.0)
    assert change > 0.01 and size == pytest.approx(0.2109, abs=1e-4)
    assert excess_over_noise(0.6035, 0.6035 / 0.982) == 0.0
    assert excess_over_noise(1.022, 1.0) == pytest.approx(0.2109, abs=1e-4)


# -- screening and reparametrisations --------------------------------------------------------


def test_screening_grid_classifies_parameters_by_what_they_do():
    sim = simulate(None, seed=0)
    base_model = normalised_model(Model())
    for name, gridded, fixed in (
        ("thermal", {"thermal_tau"}, {"thermal_sensitivity", "thermal_expansion"}),  # amplitudes: linear, off
        ("creep", {"creep_tau", "creep_decades"}, {"creep_amplitude"}),
        ("sensor_drift", set(), {"sensor_drift_linear", "sensor_drift_quadratic"}),
        ("lag", {"lag_tau"}, set()),  # acts while "off" at 0 and nonlinearly: a value grid
        (
            "initial_state",
            {"initial_state_excursion", "initial_state_held", "initial_state_held_slope"},
            {"initial_state_memory"},
        ),
        (
            "training",
            {"training_travel", "training_shape"},
            {"training_deficit", "training_threshold", "training_gain", "training_width"},
        ),
    ):
        model_e = base_model + name
        grid = screening_grid(model_e, name, model_e.default_theta(), sim.record)
        # initial_state's excursion: EXCURSION_VALUES_PER_OPERATOR per operator above v0 (its own axis)
        assert 1 <= len(grid) <= (28 if name != "initial_state" else 1 + 48 + 6 + 12)
        for p in fixed:
            assert {g[p] for g in grid} == {model_e.parameters[p].value}
        for p in gridded:
            assert len({g[p] for g in grid}) >= 3
        for g in grid:
            for p, v in g.items():
                assert model_e.parameters[p].lower <= v <= model_e.parameters[p].upper
        if name == "initial_state":  # the excursion spans the drive's range above v0, evenly, 4 per operator
            excursions = sorted({g["initial_state_excursion"] for g in grid} - {0.0})
            above = float(sim.record.current.max() - sim.record.current[0])
            positive = [e for e in excursions if e > 0]
            assert len(positive) == 4 * model_e.n_operators and positive[-1] == pytest.approx(above)
            np.testing.assert_allclose(np.diff(positive), above / (4 * model_e.n_operators))


def test_training_screening_grid_spans_the_records_travel():
    sim = simulate(None, seed=0)
    model_e = normalised_model(Model()) + "training"
    grid = SCREENING_GRIDS["training"](model_e, sim.record)
    assert grid[0] == EFFECTS["training"].off and len(grid) == 16
    total = float(np.sum(np.abs(np.diff(sim.record.current))))
    travels = sorted({g["training_travel"] for g in grid[1:]})
    np.testing.assert_allclose(travels, np.geomspace(total / 50, total, 5), rtol=1e-12)
    assert {g["training_shape"] for g in grid[1:]} == {1.0, 3.0, 8.0}


def test_incomplete_reset_screening_grid_keeps_the_proportional_forms_and_adds_the_loading_shapes(monkeypatch):
    """incomplete_reset's own grid: first exactly the grid the generic rule gives its
    strain-proportional form (drive share 0, shape 1, no step and no stroke pinned: 15 points,
    in order), then the stroke at 1 and 2 with the retained fraction at 0.5 and 1 (4 more), then
    each loading shape with the retained fraction at 0, 0.5 and 1 (24 more); with the terms
    pinned off (as a study does where the record does not pay for them) only the first."""
    sim = simulate(None, seed=0)
    model_e = normalised_model(Model()) + "incomplete_reset"
    grid = SCREENING_GRIDS["incomplete_reset"](model_e, sim.record)
    parameters = model_e.parameters
    for name in (
        "incomplete_reset_drive",
        "incomplete_reset_shape",
        "incomplete_reset_onset",
        "incomplete_reset_sharpness",
        "incomplete_reset_stroke",
    ):
        parameters = parameters.replace(name, vary=False)
    pinned = model_e.with_parameters(parameters)
    monkeypatch.delitem(SCREENING_GRIDS, "incomplete_reset")
    generic = screening_grid(pinned, "incomplete_reset", pinned.default_theta(), sim.record)
    monkeypatch.undo()
    assert len(generic) == 15 and grid[:15] == generic and len(grid) == 43
    assert grid[0] == EFFECTS["incomplete_reset"].off
    strokes = {(g["incomplete_reset_retained"], g["incomplete_reset_stroke"]) for g in grid[15:19]}
    assert strokes == {(0.5, 1.0), (0.5, 2.0), (1.0, 1.0), (1.0, 2.0)}
    assert all(g["incomplete_reset_stroke"] == 0.0 for g in grid[:15] + grid[19:])
    shapes = {
        (g["incomplete_reset_drive"], g["incomplete_reset_shape"], g["incomplete_reset_onset"])
        for g in grid[19:]
        if g["incomplete_reset_sharpness"] == 0.0
    }
    assert shapes == {(0.0, 0.4, 0.5), (0.0, 2.5, 0.5), (1.0, 0.4, 0.5), (1.0, 1.0, 0.5), (1.0, 2.5, 0.5)}
    steps = {(g["incomplete_reset_onset"], g["incomplete_reset_sharpness"]) for g in grid[19:]}
    assert steps >= {(0.3, 10.0), (0.5, 10.0), (0.7, 10.0)}
    assert all(g["incomplete_reset_strain"] == 0.0 for g in grid)
    assert {g["incomplete_reset_retained"] for g in grid[19:]} == {0.0, 0.5, 1.0}
    assert SCREENING_GRIDS["incomplete_reset"](pinned, sim.record) == generic


def test_screening_ranks_the_hidden_effect_first_and_its_refit_realises_it():
    """A large hidden thermal effect: the screening ranks it first, the short refit from its
    start strategies realises most of the predicted drop and finds a heating time constant."""
    sim = simulate("thermal", seed=1, fs=25.0)
    model = normalised_model(Model())
    fit = fit_least_squares(sim.record, model, n_starts=1)
    ranking = screen_candidates(sim.record, fit)
    assert ranking[0].effect == "thermal"
    # the slow changes of the response (a drift, a record-long fade, a retained first-cycle
    # strain, creep) overlap with heating on the decaying sine; the others are far behind
    slow = ("sensor_drift", "training", "incomplete_reset", "creep", "rate_width")
    assert ranking[0].chi2_drop > 10 * max(r.chi2_drop for r in ranking[1:] if r.effect not in slow)
    model_e = model + "thermal"
    work = working_copy(sim.record, fit.noise, find_reversals(sim.record.current).index)
    values = [ranking[0].grid_point, *ranking[0].grid]
    groups = [near(fit, model_e, values), data_driven(work, model_e, values), screening_step(ranking[0], model_e)]
    chi2_short, theta_short = short_refit(sim.record, model_e, fit.noise, groups)
    assert fit.chi2 - chi2_short > 0.5 * ranking[0].chi2_drop
    assert model_e.theta_dict(theta_short)["thermal_tau"] > 1.0


def test_fits_side_by_side_are_the_fits_alone_in_order_with_failures_in_place():
    """``concurrently``: independent fits run two at a time compute what each computes alone (the
    same bits: BLAS and numba on one thread each), in the order given; a candidate's failure
    comes back in its place, any other exception is raised."""
    from identify.diagnosis.fits import concurrently, finish
    from identify.fitting.threads import SIDE_BY_SIDE

    sim = simulate("thermal", seed=1, fs=25.0)
    model = normalised_model(Model())
    fit = fit_least_squares(sim.record, model, n_starts=1)
    model_e = model + "thermal"
    starts = [embed(fit.model, fit.theta, model_e), embed(fit.model, fit.theta, model_e)]
    starts[1][model_e.names.index("thermal_tau")] = 5.0
    actions = [lambda x=x: finish(sim.record, model_e, fit.noise, x[model_e.parameters.vary], None) for x in starts]

    def failing():
        raise ValueError("no start")

    together = concurrently([actions[0], failing, actions[1]])
    alone = [actions[0](), actions[1]()]
    assert SIDE_BY_SIDE == 2
    assert together[1][0] is None and isinstance(together[1][1], ValueError)
    for (result, exc), single in zip([together[0], together[2]], alone):
        assert exc is None
        assert np.array_equal(result.theta, single.theta) and result.chi2 == single.chi2
    with pytest.raises(KeyError):
        concurrently([actions[0], lambda: {}["missing"]])


def test_a_fit_side_by_side_measures_at_most_its_threads_cap_and_the_caller_keeps_its_own():
    """A worker of ``concurrently`` runs numba on one thread, its fits' thread-count measurements
    included; the calling thread keeps numba's maximum (a posterior that once measured one
    thread faster may measure two again)."""
    import threading

    import numba

    from identify.fitting.threads import cap_numba_threads, fastest_thread_count, numba_thread_cap

    seen = {}

    def worker():
        cap_numba_threads(1)
        seen["cap"] = numba_thread_cap()
        seen["chosen"] = fastest_thread_count(lambda x: x, 0, repeats=1)

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert seen == {"cap": 1, "chosen": 1}
    before = numba.get_num_threads()
    numba.set_num_threads(1)  # as a measurement that found one thread faster leaves it
    try:
        assert numba_thread_cap() == numba.config.NUMBA_NUM_THREADS
    finally:
        numba.set_num_threads(before)


def test_a_worker_whose_fellows_are_idle_runs_numba_on_their_cores_too():
    """While both workers of a call run an action, each batch of model evaluations runs numba on
    one thread; once the other action is done (nothing left to start), on two."""
    import threading
    import time as clock

    import numba

    from identify.fitting.threads import side_by_side, use_idle_cores

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one numba thread on this machine")
    both = threading.Barrier(2, timeout=10)
    measured = threading.Barrier(2, timeout=10)  # neither returns before both counted together
    first_done = threading.Event()

    def first():
        both.wait()
        use_idle_cores()
        together = numba.get_num_threads()
        measured.wait()
        first_done.set()
        return together

    def second():
        both.wait()
        use_idle_cores()
        together = numba.get_num_threads()
        measured.wait()
        first_done.wait(10)
        deadline = clock.monotonic() + 10
        while clock.monotonic() < deadline:  # the first worker stops counting as busy after its return
            use_idle_cores()
            if numba.get_num_threads() == 2:
                break
            clock.sleep(0.01)
        return together, numba.get_num_threads()

    (together_first, _), ((together_second, alone), _) = side_by_side([first, second])
    assert together_first == 1 and together_second == 1
    assert alone == 2


def test_fits_from_scratch_stop_by_gap_z_and_are_taken_again_only_under_no_lower_reference(monkeypatch):
    """A fit from scratch with a reference runs under the reach rule with the decision's gap_z;
    a later call takes it again where its reference is no higher (a stricter rule), and fits
    again where it is higher or absent (the runs stopped before might now go on)."""
    from types import SimpleNamespace

    import identify.diagnosis.search as search_module
    from identify.fitting.lsq_solver import reach_rule

    rules = []

    def fake_from_scratch(work, model_e, rng, sign, n_starts):
        rules.append(reach_rule())
        return [(model_e, np.zeros(model_e.n_parameters))]

    monkeypatch.setattr(search_module, "from_scratch", fake_from_scratch)
    thresholds = Thresholds(gap_z=3.0)
    setting = SimpleNamespace(
        work=None, rng=np.random.default_rng(0), n_starts=2, say=lambda message: None, thresholds=thresholds, fresh={}
    )
    model_e = normalised_model(Model(["thermal"]))

    def fit(reference=None):
        references = None if reference is None else [reference]
        (fitted,) = search_module.fresh_fits(setting, [model_e], ["positive"], references)
        assert fitted[0][0] is model_e
        return list(rules)

    assert fit(100.0) == [(100.0, 3.0)]
    assert fit(90.0) == [(100.0, 3.0)]  # stricter: the fit made under 100 serves
    assert fit(200.0) == [(100.0, 3.0), (200.0, 3.0)]
    assert fit() == [(100.0, 3.0), (200.0, 3.0), None]
    assert fit(50.0) == [(100.0, 3.0), (200.0, 3.0), None]


def test_the_sign_that_starts_higher_is_finished_only_while_it_can_end_lower_or_tie(monkeypatch):
    """With a tie margin, the finish of the threshold sign whose start is the higher on the record
    runs within beyond_a_tie of the lower start (its own start's effective sample size), the
    other's without it, and the lower sign's fit is the one it is without the margin."""
    import identify.diagnosis.baseline as baseline_module
    from identify.diagnosis.baseline import best_baseline, fit_baselines
    from identify.diagnosis.fits import n_eff, whitened_at
    from identify.fitting.lsq_solver import tie_rule

    record = simulate("thermal", seed=3, fs=20.0).record
    noise = estimate_noise(record)
    model = normalised_model(Model())
    real_finish = baseline_module.finish
    seen = []

    def finish(record_f, model_f, noise_f, x, rng, fit=None):
        rule = tie_rule()
        seen.append((model_f, fit.theta.copy(), rule))
        return real_finish(record_f, model_f, noise_f, x, rng, fit=fit)

    monkeypatch.setattr(baseline_module, "finish", finish)
    with_margin = fit_baselines(record, model, noise, rng=np.random.default_rng(0), tie_bic=10.0)
    residuals = [whitened_at(record, m, noise, theta) for m, theta, _ in seen]
    starts = [float(w @ w) for w in residuals]
    assert len(seen) == 2
    low, high = int(np.argmin(starts)), int(np.argmax(starts))
    assert seen[low][2] is None
    assert seen[high][2] == (starts[low], 10.0, n_eff(residuals[high]))
    seen.clear()
    without = fit_baselines(record, model, noise, rng=np.random.default_rng(0))
    assert all(rule is None for _, _, rule in seen)
    best_with, best_without = best_baseline(record, with_margin), best_baseline(record, without)
    assert np.array_equal(best_with.theta, best_without.theta)


def _increasing_amplitude_input(fs=50.0):
    """10 s quiet, then a 0.1 Hz sine whose amplitude grows from 0.5 A to 2.5 A (peaks 1-5 A)."""
    time = np.arange(0.0, 70.0 + 0.5 / fs, 1.0 / fs)
    grow = 0.5 + 2.0 * np.clip((time - 10.0) / 60.0, 0.0, 1.0)
    current = np.where(time < 10.0, 0.0, grow * (1.0 - np.cos(0.2 * np.pi * (time - 10.0))))
    return time, current


@pytest.mark.parametrize("effects", [(), ("lag", "thermal")])
def test_initial_states_level_is_an_exact_reparametrisation_of_the_gpi_and_its_excursion_is_not(effects):
    """A constant initial memory level equals shifted envelope and Omega offsets, on any input
    (the paper's and an increasing amplitude), from the virgin level to 20, with other effects;
    the prior excursion is no such shift."""
    sim = simulate(None, seed=0, fs=50.0)
    model = normalised_model(Model(list(effects)))
    model_e = model + "initial_state"
    values = {"lag_tau": 0.05, "thermal_sensitivity": 0.05, "thermal_expansion": 2.0}
    base = model_e.theta_from_dict({k: v for k, v in values.items() if k in model_e.names})
    for time_, current in ((sim.record.time, sim.record.current), _increasing_amplitude_input()):
        for z0 in (-20.0, -2.0, 0.5, 20.0):
            theta_e = base.copy()
            theta_e[model_e.names.index("initial_state_memory")] = z0
            plain = GPI_EQUIVALENTS["initial_state"](model_e, theta_e, time_, current)
            y_effect, y_plain = model_e(np.vstack([theta_e, plain]), time_, current)
            assert np.max(np.abs(y_effect - y_plain)) <= 1e-9 * np.ptp(y_effect)
            assert np.max(np.abs(y_effect - model_e(base, time_, current))) > 1.0  # not vacuous
    theta_e = base.copy()
    theta_e[model_e.names.index("initial_state_excursion")] = 2.0
    with pytest.raises(ValueError, match="not a shift of the offsets"):
        GPI_EQUIVALENTS["initial_state"](model_e, theta_e, sim.record.time, sim.record.current)
    assert not exact_reparametrisation(sim.record, model, model.default_theta(), "initial_state")
    for other in ("creep", "sensor_drift") + (() if effects else ("lag", "thermal")):
        assert not exact_reparametrisation(sim.record, model, model.default_theta(), other)


def test_initial_state_is_not_a_reparametrisation_when_the_offsets_are_pinned():
    sim = simulate(None, seed=0, fs=25.0)
    model = normalised_model(Model())
    pinned = Model([], gpi_parameters=model.parameters.replace("c3", vary=False))
    assert not exact_reparametrisation(sim.record, pinned, pinned.default_theta(), "initial_state")


# -- the working copy, the threshold signs and the start strategies ----------------------------


@pytest.mark.parametrize("fs", [100.0, 1000.0])
@pytest.mark.parametrize("spec", ["lag_tau=0.0127", "lag_tau=0.005,lag_delay=0.02"])
def test_the_working_copy_keeps_a_lagged_drives_reversals(spec, fs):
    """A lagged drive reverses after the current, between the samples a plain thinning keeps; the
    working copy keeps the full rate around each reversal, so the true model there equals the
    whole record's, where a plain thinning puts tens of units into the chi-square."""
    from identify.data.records import thinning_indices

    sim = simulate(spec, seed=1, noise_sigma=0.5, fs=fs)
    record = sim.record
    truth = Model(**sim.truth["model"])
    theta = np.array([sim.truth["theta"][name] for name in truth.names])
    reversals = find_reversals(record.current).index
    work = working_copy(record, estimate_noise(record), reversals)
    assert work.step > 1

    def chi2(keep):
        miss = np.ravel(truth(theta, record.time[keep], record.current[keep])) - sim.clean[keep]
        return float(miss @ miss) / 0.5**2

    kept = np.searchsorted(record.time, work.record.time)
    assert chi2(kept) < 1.0
    assert chi2(thinning_indices(record.current, work.step, reversals)) > 30.0
    assert len(work.record) < 1.5 * SCREENING_SAMPLES


def test_the_working_copy_whitens_each_step_with_its_own_correlation():
    from identify.fitting.noise import NoiseModel, whiten

    sim = simulate({}, seed=4, noise_sigma=0.5, noise_rho=0.7, fs=1000.0)
    record = sim.record
    noise = estimate_noise(record)
    work = working_copy(record, noise, find_reversals(record.current).index)
    kept = np.searchsorted(record.time, work.record.time)
    residual = work.record.displacement - sim.clean[kept]
    w = whiten(residual, work.noise, time=work.record.time)
    assert np.std(w) == pytest.approx(1.0, abs=0.04)
    assert abs(float(w[1:] @ w[:-1] / (w @ w))) < 0.06
    blind = whiten(residual, NoiseModel(sigma=noise.sigma, rho=noise.rho**work.step, kind="ar1"))
    assert float(blind[1:] @ blind[:-1] / (blind @ blind)) > 0.1


def test_threshold_signs_and_vectors_between_models():
    negative = normalised_model(Model(["lag"]))
    positive = with_threshold_sign(negative, 1)
    assert negative.parameters["alpha"].value < 0 < positive.parameters["alpha"].value
    assert same_threshold_sign(negative, negative + "training") and not same_threshold_sign(negative, positive)
    plain = plain_of(positive + "training", negative)
    assert plain.effect_names == ("lag",) and plain.parameters["alpha"].value == positive.parameters["alpha"].value
    free = Model(["lag"])
    assert plain_of(free + "training", free) is free
    with pytest.raises(ValueError, match="not nested"):
        embed(negative, negative.default_theta(), positive + "creep")
    theta = embed(negative, negative.default_theta(), negative + "creep")
    assert theta[(negative + "creep").names.index("creep_amplitude")] == EFFECTS["creep"].off["creep_amplitude"]


def test_start_strategies_give_vectors_of_the_candidates_model_in_its_sign():
    """``carried`` keeps what an earlier round reached only for the same model and sign; ``near``
    puts the candidate's values on a donor fit; ``members`` starts a pair from each member with
    the partner's values, and gives nothing from a member of another sign."""
    base = normalised_model(Model())
    model_lag = base + "lag"
    theta = model_lag.default_theta()
    theta[model_lag.names.index("lag_tau")] = 0.02
    other_sign = with_threshold_sign(model_lag, 1)
    history = [(model_lag, theta), (other_sign, other_sign.default_theta())]
    assert [s[model_lag.names.index("lag_tau")] for s in carried(history, model_lag)] == [0.02]
    assert carried(history, base + "creep") == []

    class Donor:
        model, theta = base, base.default_theta()

    starts = near(Donor, model_lag, [{"lag_tau": 0.05}])
    assert [s[model_lag.names.index("lag_tau")] for s in starts] == [0.05, 0.0]
    pair = base + ["lag", "creep"]
    model_creep = base + "creep"
    creep_theta = model_creep.default_theta()
    creep_theta[model_creep.names.index("creep_amplitude")] = 0.1
    starts = members(pair, ("lag", model_lag, theta), ("creep", model_creep, creep_theta))
    assert len(starts) == 2
    assert all(s[pair.names.index("lag_tau")] == 0.02 and s[pair.names.index("creep_amplitude")] == 0.1 for s in starts)
    assert len(members(pair, ("lag", other_sign, other_sign.default_theta()), ("creep", model_creep, creep_theta))) == 1


# -- evidence ----------------------------------------------------------------------------------


def test_gap_noise_sd_is_the_spread_another_noise_realisation_gives_the_gap():
    """The sd of the likelihood gap between two fixed predictions over noise realisations: when
    one model is the truth the gap's z is about ||d|| / 2; two approximations that differ widely
    and fit equally well have a gap the noise can reverse."""
    rng = np.random.default_rng(5)
    n = 4000
    t = np.linspace(0.0, 1.0, n)
    shape_a, shape_b = np.sin(7 * t), np.cos(5 * t)
    shape_b *= np.linalg.norm(shape_a) / np.linalg.norm(shape_b)
    for off_b, off_o in ((0.0 * shape_a, 0.3 * shape_a), (0.25 * shape_a, 0.25 * shape_b)):
        gaps, sds = [], []
        for _ in range(1500):
            e = rng.standard_normal(n)
            wb, wo = e + off_b, e + off_o
            gaps.append(n * math.log(float(wo @ wo) / float(wb @ wb)))
            sds.append(gap_noise_sd(wb, wo, n))
        assert np.std(gaps) == pytest.approx(np.mean(sds), rel=0.08)
    d = 0.3 * shape_a
    e = rng.standard_normal(n)
    z = n * math.log(float((e + d) @ (e + d)) / float(e @ e)) / gap_noise_sd(e, e + d, n)
    assert z == pytest.approx(math.sqrt(float(d @ d)) / 2, abs=1.5)


def test_gaps_among_every_two_explanations_the_better_first():
    """Three explanations give the three gaps, each led by the lower chi-square, its size the
    likelihood gap at the better one's effective size."""
    e = np.random.default_rng(2).standard_normal(500)
    whitened = [e, 1.1 * e, 1.3 * e]
    chi2 = [float(w @ w) for w in whitened]
    explanations = [Explanation(name, c, 400.0, 0.0, True, 1.0) for name, c in zip("bac", chi2)]
    gaps = gaps_among(explanations, whitened)
    assert [(g.better, g.other) for g in gaps] == [("b", "a"), ("b", "c"), ("a", "c")]
    assert gaps[2].gap == pytest.approx(400.0 * math.log(chi2[2] / chi2[1]))
    assert all(g.gap > 0 and g.noise_sd > 0 for g in gaps)
    assert gaps_among(explanations[:1], whitened[:1]) == ()


def test_how_far_one_explanation_fits_ahead_of_another():
    """The lead of the better fit is its likelihood gap, the other way round the same negated; an
    explanation the evidence does not hold has none."""
    evidence = _evidence([_ex("creep", 1.0, 70.0), _ex("thermal", 1.1, 20.0)])
    gap = N * math.log(1.1**2)
    assert evidence.lead("creep", "thermal") == pytest.approx(gap)
    assert evidence.lead("thermal", "creep") == pytest.approx(-gap)
    assert evidence.lead("creep", "training") is None


def test_the_first_loading_share_of_a_fit():
    """A training that fades within the first loading puts its part there; a drift spreads."""
    for spec, name, low, high in (
        ("training_deficit=0.08", "training", 0.95, 1.0),
        ("sensor_drift_linear=1.1", "sensor_drift", 0.0, 0.5),
    ):
        sim = simulate(spec, noise_sigma=0.5, seed=0)
        model = Model.from_dict(sim.truth["model"])

        class Fit:
            pass

        fit = Fit()
        fit.model, fit.theta = model, model.theta_from_dict(sim.truth["theta"])
        assert low < first_loading_share(sim.record, fit, [name]) <= high


# -- the decision, as a table --------------------------------------------------------------------

N = 1000.0  # effective samples of every explanation in the table


def _adequacy(adequate: bool) -> Adequacy:
    failed = () if adequate else ("low_frequency",)
    z = {"variance": 1.0, "ljung_box": 1.0, "low_frequency": 1.0 if adequate else 40.0}
    return Adequacy(adequate, failed, z, 0.0, 0.0, 0.0 if adequate else 0.5, "low_frequency", 0.25)


def _ex(name, rms, delta_bic, adequate=True, share=0.3, explained=0.9):
    """An explanation reaching residual RMS ``rms`` (sigma = 1, so chi-square = N rms^2)."""
    return Explanation(name, N * rms * rms, N, delta_bic, adequate, rms, explained, share)


def _evidence(explanations, *, baseline_rms=2.0, adequate=False, sd=None, strength=None, first_cycle=()):
    """Evidence with the gaps of every two explanations: the likelihood gap of their chi-squares
    and a noise sd (``sd``: ``{frozenset({a, b}): sd}``, default 1)."""
    gaps = []
    for i, a in enumerate(explanations):
        for b in explanations[i + 1 :]:
            better, other = (a, b) if a.chi2 <= b.chi2 else (b, a)
            gap = N * math.log(other.chi2 / better.chi2)
            gaps.append(Gap(better.name, other.name, gap, (sd or {}).get(frozenset((a.name, b.name)), 1.0)))
    return Evidence(
        1.0,
        baseline_rms,
        _adequacy(adequate),
        tuple(explanations),
        tuple(gaps),
        strength or {e.name: e.delta_bic for e in explanations if "+" not in e.name},
        first_cycle,
        adequate,
    )


def _pair_sd(a, b, sd):
    return {frozenset((a, b)): sd}


#: (id, evidence, status, rule, missing, tied)
DECISIONS = [
    ("noise: nothing refitted", _evidence([], baseline_rms=1.0, adequate=True), "adequate", "noise", None, ()),
    (
        "noise: a targeted refit below the practical size",
        _evidence([_ex("creep", 1.019, 40.0)], baseline_rms=1.022, adequate=True),
        "adequate",
        "noise",
        None,
        (),
    ),
    (
        "negligible: no excess over the noise to explain",
        _evidence([_ex("creep", 0.98, 40.0)], baseline_rms=1.004, adequate=True),
        "adequate",
        "negligible",
        None,
        (),
    ),
    (
        "targeted: a small effect the omnibus tests miss is named",
        _evidence([_ex("creep", 1.0, 70.0), _ex("thermal", 1.019, 20.0)], baseline_rms=1.022, adequate=True),
        "missing_effect",
        "named",
        "creep",
        (),
    ),
    (
        "targeted: a repair in the first loading alone is no finding",
        _evidence([_ex("initial_state", 1.0, 70.0, share=0.99)], baseline_rms=1.022, adequate=True),
        "adequate",
        "first_loading_only",
        None,
        (),
    ),
    (
        "targeted: two repairs the data do not separate tie",
        _evidence([_ex("creep", 1.0, 70.0), _ex("sensor_drift", 1.001, 72.0)], baseline_rms=1.022, adequate=True),
        "tied",
        "tied",
        None,
        ("creep", "sensor_drift"),
    ),
    (
        "too small: the repair explains less than the practical size",
        _evidence([_ex("thermal", 1.009, 362.0)], baseline_rms=1.012),
        "adequate",
        "too_small",
        None,
        (),
    ),
    (
        "none repairs",
        _evidence([_ex("thermal", 1.3, 900.0, adequate=False), _ex("creep", 1.4, 700.0, adequate=False)]),
        "unexplained",
        "none_repairs",
        None,
        (),
    ),
    (
        "named: separated from the rival by the gap and its noise",
        _evidence([_ex("thermal", 1.0, 3000.0), _ex("creep", 1.1, 2800.0)], sd=_pair_sd("thermal", "creep", 20.0)),
        "missing_effect",
        "named",
        "thermal",
        (),
    ),
    (
        "tied: the gap is within 2.5 of its noise sd",
        _evidence([_ex("thermal", 1.0, 3000.0), _ex("creep", 1.02, 2960.0)], sd=_pair_sd("thermal", "creep", 20.0)),
        "tied",
        "tied",
        None,
        ("thermal", "creep"),
    ),
    (
        "tied: a gap below bic_significant is no evidence however small its noise",
        _evidence([_ex("thermal", 1.0, 3000.0), _ex("creep", 1.003, 2995.0)], sd=_pair_sd("thermal", "creep", 0.1)),
        "tied",
        "tied",
        None,
        ("thermal", "creep"),
    ),
    (
        "tied: a name never comes from a parameter count (fewer parameters, a worse fit)",
        _evidence(
            [_ex("training", 1.0002, 6082.0), _ex("thermal", 1.0, 6066.0)], sd=_pair_sd("training", "thermal", 0.01)
        ),
        "tied",
        "tied",
        None,
        ("thermal", "training"),
    ),
    (
        "tied: a rival that leaves structure but is not separated blocks the name",
        _evidence(
            [_ex("thermal", 1.0, 3000.0), _ex("creep", 1.01, 2980.0, adequate=False)],
            sd=_pair_sd("thermal", "creep", 20.0),
        ),
        "tied",
        "tied",
        None,
        ("thermal", "creep"),
    ),
    (
        "named: a rival that leaves structure far behind does not block",
        _evidence([_ex("thermal", 1.0, 3000.0), _ex("creep", 1.3, 2000.0, adequate=False)]),
        "missing_effect",
        "named",
        "thermal",
        (),
    ),
    (
        "named: a pair that is not needed beside its member adds nothing",
        _evidence([_ex("thermal", 1.0, 3000.0), _ex("thermal+creep", 0.9995, 2995.0), _ex("creep", 1.2, 1800.0)]),
        "missing_effect",
        "named",
        "thermal",
        (),
    ),
    (
        "named from a pair: needed beside a single that reaches the noise, the member stronger alone",
        _evidence(
            [
                _ex("creep", 1.05, 3785.0),
                _ex("lag+sensor_drift", 0.99, 4157.0),
                _ex("lag", 1.5, 1200.0, False),
                _ex("sensor_drift", 1.4, 1500.0, False),
            ]
        ),
        "missing_effect",
        "named_from_pair",
        "sensor_drift",
        (),
    ),
    (
        "named from a pair: the pairs the data do not separate share a member",
        _evidence(
            [
                _ex("training+creep", 1.0, 3000.0),
                _ex("training+sensor_drift", 1.005, 2990.0),
                _ex("training", 1.3, 2000.0, False),
            ],
            strength={"training": 2000.0, "creep": 300.0, "sensor_drift": 200.0},
        ),
        "missing_effect",
        "named_from_pair",
        "training",
        (),
    ),
    (
        "tied: pairs without a common member",
        _evidence(
            [
                _ex("thermal+incomplete_reset", 1.0, 3135.0),
                _ex("creep+sensor_drift", 1.002, 3128.0),
                _ex("thermal", 1.2, 2000.0, False),
            ]
        ),
        "tied",
        "tied",
        None,
        ("thermal+incomplete_reset", "creep+sensor_drift"),
    ),
    (
        "tied: a pair best is compared with a single given a second effect's freedom too",
        _evidence(
            [
                _ex("incomplete_reset", 1.02, 1392.0),
                _ex("training", 1.012, 1358.0),
                _ex("thermal", 1.04, 1291.0),
                _ex("incomplete_reset+thermal", 1.006, 1418.0),
                _ex("training+rate_width", 1.0055, 1484.0),
            ]
        ),
        "tied",
        "tied",
        None,
        ("incomplete_reset+thermal", "training+rate_width"),
    ),
    (
        "tied: a single and a pair without it",
        _evidence([_ex("thermal", 1.0, 3103.0), _ex("creep+sensor_drift", 0.999, 3128.0)]),
        "tied",
        "tied",
        None,
        ("creep+sensor_drift", "thermal"),
    ),
    (
        "first loading again: a name beside first-cycle physics the model has",
        _evidence([_ex("initial_state", 1.0, 225.0, share=0.999)], first_cycle=("training",)),
        "unexplained",
        "first_loading_again",
        None,
        (),
    ),
    (
        "named: a first-loading name without first-cycle physics in the model (with a caution)",
        _evidence([_ex("training", 1.0, 3336.0, share=0.996)]),
        "missing_effect",
        "named",
        "training",
        (),
    ),
]


@pytest.mark.parametrize(
    "evidence, status, rule, missing, tied", [row[1:] for row in DECISIONS], ids=[row[0] for row in DECISIONS]
)
def test_decision_table(evidence, status, rule, missing, tied):
    decision = decide(evidence, Thresholds())
    assert (decision.status, decision.rule, decision.missing) == (status, rule, missing), decision
    if status == "tied":
        assert set(decision.tied) == set(tied) and decision.tied[0] == tied[0]
    assert RULES[decision.rule][0] == decision.status


def test_the_decision_table_covers_every_rule_and_runs_fast():
    started = time.perf_counter()
    rules = {decide(row[1]).rule for row in DECISIONS}
    assert time.perf_counter() - started < 1.0
    assert rules == set(RULES)
    assert {RULES[r][0] for r in RULES} == set(STATUSES)
    from identify.diagnosis.explanation import TEXTS

    assert set(TEXTS) == set(RULES)  # every rule has its text


# -- the explanation ---------------------------------------------------------------------------


def _text(row_id: str) -> str:
    evidence = next(row[1] for row in DECISIONS if row[0] == row_id)
    return explain(decide(evidence), evidence, Thresholds(), "Where: here.")


def test_the_tests_sentence_states_the_comparison_actually_made():
    th = Thresholds()
    small = Adequacy(
        True,
        ("ljung_box",),
        {"variance": 1.0, "ljung_box": 18.0, "low_frequency": 2.0},
        0.01,
        0.05,
        0.05,
        "ljung_box",
        3.0,
    )
    text = noise_tests_text(small, th)
    assert "ljung_box z 18.0" in text and "0.050 sigma, below the 0.1 sigma floor" in text and "< 5" not in text
    quiet = Adequacy(True, (), {"variance": 1.0, "ljung_box": 4.97, "low_frequency": -0.3}, 0.0, 0.0, 0.0, "none", 0.0)
    assert "(largest 4.97)" in noise_tests_text(quiet, th)
    edge = Adequacy(
        True,
        ("ljung_box",),
        {"variance": 1.0, "ljung_box": 18.0, "low_frequency": 2.0},
        0.01,
        0.09996,
        0.09996,
        "ljung_box",
        3.0,
    )
    assert "0.09996 sigma, below the 0.1 sigma floor" in noise_tests_text(edge, th)
    bad = _adequacy(False)
    assert "low_frequency z 40.0" in noise_tests_text(bad, th) and ">= the 0.1 sigma floor" in noise_tests_text(bad, th)


def test_a_tie_is_explained_with_its_evidence_and_what_would_separate_it():
    text = _text("tied: the gap is within 2.5 of its noise sd")
    assert "none is named (tied)" in text and "'thermal'" in text and "'creep'" in text
    assert "the noise alone moves that gap by 20" in text and "sd < 2.5" in text
    assert "What would tell them apart" in text and EFFECTS["thermal"].signature in text
    assert "hold at constant current" in text
    text = _text("tied: a gap below bic_significant is no evidence however small its noise")
    assert "not more than 10" in text


def test_a_name_is_explained_with_its_closest_rival_and_a_first_loading_caution():
    text = _text("named: separated from the rival by the gap and its noise")
    assert text.startswith("Adding 'thermal' explains 90 %") and "closest: 'creep'" in text
    assert "Caution" in _text("named: a first-loading name without first-cycle physics in the model (with a caution)")
    pair = _text("named from a pair: needed beside a single that reaches the noise, the member stronger alone")
    assert "Two effects seem to be missing: 'sensor_drift' and 'lag'" in pair and "stronger of the two alone" in pair
    shared = _text("named from a pair: the pairs the data do not separate share a member")
    assert "Add 'training'" in shared and "contains it too" in shared


def test_a_name_whose_misfit_size_was_already_at_the_noise_says_what_it_removes():
    evidence = _evidence([_ex("creep", 1.0, 300.0, explained=0.0)], baseline_rms=1.05)
    text = explain(decide(evidence), evidence, Thresholds(), "")
    assert text.startswith("Adding 'creep' explains the structure the noise tests found") and "0 %" not in text


def test_the_other_verdicts_are_explained():
    assert "No library effect, alone or with another" in _text("none repairs") and "Where: here." in _text(
        "none repairs"
    )
    # with nothing fitted the text says so, and claims nothing about what fits would have shown
    nothing = _evidence([])
    decision = decide(nothing)
    text = explain(decision, nothing, Thresholds(), "Where: here.")
    assert decision.status == "unexplained" and "none was fitted on the whole record" in text
    assert "alone or with another" not in text
    assert "not a finding" in _text("targeted: a repair in the first loading alone is no finding")
    assert "below the practical size" in _text("too small: the repair explains less than the practical size")
    assert "('training')" in _text("first loading again: a name beside first-cycle physics the model has")


# -- the diagnosis on records, and its command -------------------------------------------------


@pytest.fixture(scope="module")
def clean_csv(tmp_path_factory):
    sim = simulate(None, seed=3, fs=50.0, duration=40.0)
    path = tmp_path_factory.mktemp("diag") / "clean.csv"
    write_record(path, sim.record)
    return path


def test_diagnose_command_writes_the_contract(clean_csv, tmp_path, capsys):
    out_json = tmp_path / "d.json"
    out_dir = tmp_path / "run"
    args = ["diagnose", str(clean_csv), "--json", str(out_json), "--out", str(out_dir), "--quiet", "--n-starts", "2"]
    assert main(args) == 0
    assert "verdict: adequate" in capsys.readouterr().out
    content = json.loads(out_json.read_text())
    keys = {"effects", "noise_sigma", "rms", "max_error_pct", "status", "missing", "tied", "rule", "ranking"}
    assert keys <= set(content) and {"decision", "evidence", "gaps"} <= set(content)
    assert content["status"] == "adequate" and content["missing"] is None and content["tied"] == []
    assert content["effects"] == [] and 0.8 < content["rms"] / content["noise_sigma"] < 1.2
    assert {r["effect"] for r in content["ranking"]} == set(EFFECTS)  # every library effect is a candidate
    for entry in content["ranking"]:
        assert {"effect", "rms_after", "delta_bic", "explained_fraction", "parameters"} <= set(entry)
    entry = next(r for r in content["ranking"] if r["effect"] == "initial_state")
    assert "not identifiable" not in (entry.get("note") or "") and "initial_state_excursion" in entry["parameters"]
    assert json.loads((out_dir / "diagnosis.json").read_text()) == content
    pngs = sorted(p.name for p in (out_dir / "diagnosis").glob("*.png"))
    stems = ("1_residual_vs_time", "2_residual_vs_current", "3_residual_vs_rate", "4_cycles", "5_autocorrelation")
    assert pngs == [f"{stem}.png" for stem in (*stems, "6_candidates")]


def test_diagnose_with_effects_fits_them(clean_csv, tmp_path):
    out_json = tmp_path / "d.json"
    args = ["diagnose", str(clean_csv), "--effects", "sensor_drift", "--json", str(out_json), "--quiet"]
    assert main([*args, "--n-starts", "2"]) == 0
    content = json.loads(out_json.read_text())
    assert content["effects"] == ["sensor_drift"] and "sensor_drift_linear" in content["fit"]["theta"]
    assert "sensor_drift" not in {r["effect"] for r in content["ranking"]}


def test_diagnose_command_errors(tmp_path, capsys, clean_csv):
    assert main(["diagnose", str(tmp_path / "missing.csv"), "--quiet"]) == 2
    assert "missing.csv" in capsys.readouterr().err
    assert main(["diagnose", str(clean_csv), "--effects", "warp_drive", "--quiet"]) == 2
    assert "unknown effect" in capsys.readouterr().err
    assert main(["diagnose", str(clean_csv), "--noise-sigma", "free", "--quiet"]) == 2
    assert "free noise sigma" in capsys.readouterr().err
    assert main(["diagnose", str(clean_csv), "--drop-window", "20", "--quiet"]) == 2
    assert "START:STOP" in capsys.readouterr().err
    assert main(["diagnose", str(clean_csv), "--drop-window", "500:600", "--quiet"]) == 2
    assert "holds 0" in capsys.readouterr().err


def test_diagnose_rejects_bad_arguments(clean_csv):
    record = load_record(clean_csv)
    with pytest.raises(ValueError, match="already in the model"):
        diagnose(record, ["thermal"], candidates=["thermal"])
    with pytest.raises(ValueError, match="unknown effect"):
        diagnose(record, candidates=["warp_drive"])
    fit = fit_least_squares(record, normalised_model(Model()), n_starts=1)
    with pytest.raises(ValueError, match="not of"):
        diagnose(record, ["creep"], fit=fit)


@pytest.fixture
def failing_effect():
    """A library effect whose model fails for every setting but its off one (registered for the
    test only): its refit cannot succeed."""
    from model.composite import Effect, register_effect
    from model.parameters import Parameter, ParameterSet

    class Faulty(Effect):
        name = "faulty"
        stage = "output"
        parameters = ParameterSet([Parameter("faulty_gain", 0.0, -1.0, 1.0, unit="um")])
        off = {"faulty_gain": 0.0}
        summary = "a test effect whose output cannot be computed when it is on"

        @classmethod
        def get_test_parameters(cls):
            return {"faulty_gain": 0.5}

        def output(self, params, time, current, displacement):
            if np.any(np.asarray(params)[:, 0] != 0.0):
                raise ValueError("cannot be computed (a test effect)")
            return displacement

    register_effect(Faulty)
    yield "faulty"
    del EFFECTS["faulty"]


def test_a_candidate_whose_refit_fails_is_listed_with_its_reason_and_the_verdict_given(failing_effect):
    """The diagnosis never crashes on a record that loads: a candidate that fails is listed with
    the reason, and the verdict is given on the others (the hidden heating is the best)."""
    sim = simulate("thermal", seed=1, fs=25.0)
    result = diagnose(sim.record, n_starts=2, rng=np.random.default_rng(0), candidates=["thermal", failing_effect])
    faulty = next(c for c in result.ranking if c.effect == failing_effect)
    assert "failed" in faulty.note and "a test effect" in faulty.note and not faulty.refitted
    assert result.best.effect == "thermal" and result.status in STATUSES
    json.dumps(result.to_dict(), allow_nan=False)


def test_a_hidden_heating_is_named_and_the_reason_gives_its_evidence():
    """The bundled record's hidden heating at 12.5 Hz: named, separated from every rival, and the
    JSON's decision and evidence agree with the verdict."""
    record = load_record("data/bench_default.csv")
    keep = np.arange(0, len(record), 8)
    from identify.data.records import Record

    small = Record(
        record.time[keep], record.current[keep], record.displacement[keep], source="bench 12.5 Hz", sha256=""
    )
    result = diagnose(small, n_starts=2, rng=np.random.default_rng(0), candidates=["thermal", "creep", "lag"])
    assert result.status == "missing_effect" and result.missing == "thermal" and result.rule == "named"
    content = result.to_dict()
    assert content["decision"]["missing"] == "thermal"
    assert {e["name"] for e in content["evidence"]["explanations"]} >= {"thermal"}
    assert "Adding 'thermal'" in result.reason and result.verdict_text() == "missing_effect -> add 'thermal'"


def test_the_diagnose_command_waits_passively_unless_told(monkeypatch):
    """The command sets OMP_WAIT_POLICY=PASSIVE where it is unset (the results do not depend on
    it, the CPU time does) and leaves a user's value alone."""
    from identify.cli.diagnose import passive_waiting

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    passive_waiting()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    passive_waiting()
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"


def test_a_parameter_pinned_by_default_is_neither_charged_nor_moved_by_a_mimicking_start():
    """thermal's start rises are pinned (a cold start): adding thermal costs its six network
    parameters (initial_state its three free ones), and the start that mimics another
    explanation leaves the rises at 0."""
    from identify.diagnosis.mimic import mimic_start
    from model import EFFECTS, TABLE1, THETA_NAMES

    assert EFFECTS["thermal"].n_varying() == len(EFFECTS["thermal"].parameters) - 2 == 6
    assert EFFECTS["initial_state"].n_varying() == 3  # its memory level: pinned, an exact reparametrisation
    record = simulate("creep_amplitude=0.03", fs=10.0, seed=2).record
    gpi = dict(zip(THETA_NAMES, TABLE1))
    named = Model(["creep"])
    named_theta = named.theta_from_dict({**gpi, "creep_amplitude": 0.03})
    model_e = Model(["thermal"])
    theta = mimic_start(named, named_theta, model_e, "thermal", record.time, record.current)
    values = model_e.theta_dict(theta)
    assert values["thermal_initial"] == 0.0 and values["thermal_initial_core"] == 0.0
    assert values["thermal_expansion"] != 0.0 or values["thermal_sensitivity"] != 0.0  # it did mimic


def test_before_a_name_every_rival_that_repairs_too_is_started_where_it_mimics_the_name():
    """A rival that repairs the model as well but lost may have lost to its finish's basin, not to
    the data: before the name stands it is started once where it reproduces the named fit, and its
    better fit kept (a hidden heating at 25 Hz where training repairs too)."""
    sim = simulate("thermal", seed=5, fs=25.0, noise_sigma=0.5)
    said = []
    candidates = ["thermal", "creep", "sensor_drift", "training"]
    result = diagnose(sim.record, n_starts=2, rng=np.random.default_rng(0), candidates=candidates, progress=said.append)
    assert result.status == "missing_effect" and result.missing == "thermal"
    repairing = {c.effect for c in result.ranking if c.refitted and c.adequate_after} - {"thermal"}
    assert repairing, "the record must have a rival that repairs too"
    started = [m for m in said if "started where it mimics 'thermal'" in m]
    expected = [f"before naming 'thermal': '{n}' started where it mimics 'thermal'" for n in repairing]
    assert sorted(started) == sorted(expected)


@pytest.mark.parametrize(
    ("promised_gain", "promise", "short", "fresh"),
    [
        (200.0, 5000.0, 5240.0, True),  # a significant promise missed by far: fitted from scratch
        (200.0, 5000.0, 5020.0, False),  # missed by less than the significance (1423 ln(5020/5000) = 5.7)
        (200.0, 5000.0, 4900.0, False),  # kept: the short refit beat its promise
        (6.5, 5678.8, 5719.8, False),  # missed (10.2 BIC), but the promise itself gains too little
        (10.0, 5678.8, 5719.8, False),  # a promise of exactly the significance is not significant
        (10.1, 5678.8, 5719.8, True),
    ],
)
def test_fresh_fit_only_for_a_significant_promise_missed(promised_gain, promise, short, fresh):
    """The search fits a candidate from scratch only when its screening promised a significant gain
    and its short refit fell significantly short of that promise (n_eff 1423, significance 10)."""
    assert short_of_promise(promised_gain, 1423.0, promise, short, 10.0) is fresh
