"""Design the next experiment (identify.workflows.design, ``python -m identify design``)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from identify.bench import simulate
from identify.cli import main
from identify.data.records import write_record
from identify.diagnosis import Thresholds
from identify.fitting.joint import with_earlier_runs
from identify.fitting.lsq import WhitenedResiduals, fit_least_squares
from identify.fitting.noise import estimate_noise
from identify.fitting.parametrisation import normalised_model
from identify.workflows.design import (
    FAMILIES,
    MAX_REST,
    SHAPES,
    RigLimits,
    contender,
    discrimination,
    drive_of,
    fit_with_earlier_runs,
    fitted_contenders,
    p_right,
    perturbed_parameters,
    random_drive_parameters,
    refine,
    search,
)
from model import Model

LIMITS = RigLimits((0.0, 5.0), max_slew=1.6, duration=110.0, max_rms_current=2.6, fs=10.0, quiet=10.0)


@pytest.mark.parametrize("family", list(FAMILIES))
def test_every_drive_keeps_the_rigs_limits_and_starts_quiet(family):
    rng = np.random.default_rng(1)
    made = 0
    for _ in range(30):
        drive = drive_of(family, random_drive_parameters(rng, family), LIMITS, period=10.0)
        if drive is None:  # beyond the duration or the RMS limit: refused, never clipped
            continue
        made += 1
        time, current = drive
        assert time[0] == 0.0 and np.allclose(np.diff(time), 0.1) and time[-1] == pytest.approx(110.0)
        assert current.min() >= 0.0 and current.max() <= 5.0 + 1e-12
        assert np.all(current[time < 10.0] == 0.0)  # the quiet start the noise needs
        assert np.max(np.abs(np.diff(current))) / 0.1 <= 1.6 * 1.0001
        assert np.sqrt(np.mean(current**2)) <= 2.6
    assert made >= 5


@pytest.mark.parametrize("family", list(FAMILIES))
def test_a_drive_that_rests_holds_the_lower_current_after_the_quiet_start(family):
    rng = np.random.default_rng(2)
    rested = 0
    for _ in range(40):
        params = random_drive_parameters(rng, family)
        drive = drive_of(family, params, LIMITS, period=10.0)
        if drive is None or params["rest"] == 0.0:
            continue
        rested += 1
        time, current = drive
        resting = time < 10.0 + params["rest"] * 100.0 - 1e-9
        assert np.all(current[resting] == 0.0) and current.max() > 0.0
        without = drive_of(family, {**params, "rest": 0.0}, LIMITS, period=10.0)
        if family in ("hold", "steps"):  # their holds are shares of the time left after the rest
            continue
        first = np.argmax(current > 0.0)  # the same drive, later by the rest (to a sample)
        assert abs(first - np.argmax(without[1] > 0.0) - params["rest"] * 100.0 / 0.1) <= 1.0
    assert rested >= 3


@pytest.mark.parametrize(
    "given, problem",
    [
        ({"current_range": (5.0, 0.0)}, "LO < HI"),
        ({"max_slew": 0.0}, "max slew must be > 0"),
        ({"duration": 8.0}, "leaves nothing after the 10 s quiet start"),
        ({"max_rms_current": -1.0}, "max rms current must be > 0"),
        ({"longest": 60.0}, r"the longest record \(60 s\) is shorter than the duration \(110 s\)"),
    ],
)
def test_bad_limits_are_refused_in_one_sentence(given, problem):
    values = {
        "current_range": (0.0, 5.0),
        "max_slew": 1.6,
        "duration": 110.0,
        "max_rms_current": 2.6,
        "fs": 10.0,
        "quiet": 10.0,
    } | given
    with pytest.raises(ValueError, match=problem):
        RigLimits(**values)


def _short_hold():
    """A 40 s hold drive at 5 Hz (10 s quiet start): the confirmations' tests' proposed record."""
    from identify.workflows.design import DesignedDrive

    limits = RigLimits((0.0, 5.0), max_slew=1.6, duration=40.0, max_rms_current=4.0, fs=5.0, quiet=10.0)
    return DesignedDrive(
        "hold", {}, *drive_of("hold", {"cycles": 1, "amplitude": 0.9, "level": 0.9, "hold": 0.4}, limits, 10.0)
    )


def _heating_and_plain(sim, variance: float) -> list:
    """Two contenders at a heated bench record's truth: the heating (``thermal``, its free
    parameters' variance ``variance``) and the plain GPI of the same transducer parameters."""
    model = normalised_model(Model(["thermal"]))
    theta = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    covariance = np.diag(np.where(model.parameters.vary, variance, 0.0))
    plain = normalised_model(Model())
    n = plain.n_parameters
    return [contender("thermal", model, theta, covariance), contender("plain", plain, theta[:n], covariance[:n, :n])]


def test_the_criterion_is_zero_for_a_rival_that_can_be_the_truth_and_positive_otherwise():
    """A rival that contains the truth's physics (the same model) mimics it exactly: no gap. A rival
    without it keeps a gap the noise cannot explain on a drive that shows the effect."""
    sim = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    truth, rival = _heating_and_plain(sim, 1e-4)
    hot = RigLimits((0.0, 5.0), max_slew=1.6, duration=110.0, max_rms_current=4.0, fs=10.0, quiet=10.0)
    time, current = drive_of("hold", {"cycles": 2, "amplitude": 0.9, "level": 0.9, "hold": 0.4}, hot, 10.0)
    noise = estimate_noise(sim.record)
    gap, sd = discrimination(truth, truth, time, current, noise)
    assert abs(gap) < 1e-6
    gap, sd = discrimination(truth, rival, time, current, noise)
    assert gap > 100.0 and sd > 0
    assert p_right(gap, sd, Thresholds()) > 0.99
    assert p_right(5.0, 1.0, Thresholds()) < 0.01  # a gap below bic_significant names nothing


def test_the_criterion_keeps_the_rivals_closest_mimicry_over_its_fit_and_the_points_its_refits_found():
    """A rival of the truth's own physics fitted in another basin (a heating a hundred times slower),
    the records holding nothing of it: linearised at that fit alone it looks far from the truth; with the
    point where a refit found it mimicking the truth, the gap is gone. A point that is its fit again
    changes nothing."""
    sim = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    truth, _ = _heating_and_plain(sim, 1e-4)
    model = normalised_model(Model(["thermal"]))
    slow = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value, "thermal_tau": 3000.0})
    rival = contender("thermal", model, slow, np.zeros((slow.size, slow.size)))
    hot = RigLimits((0.0, 5.0), max_slew=1.6, duration=110.0, max_rms_current=4.0, fs=10.0, quiet=10.0)
    time, current = drive_of("hold", {"cycles": 2, "amplitude": 0.9, "level": 0.9, "hold": 0.4}, hot, 10.0)
    noise = estimate_noise(sim.record)
    at_fit = discrimination(truth, rival, time, current, noise)
    assert at_fit[0] > 50.0
    assert discrimination(truth, rival, time, current, noise, [rival.theta]) == at_fit
    gap, sd = discrimination(truth, rival, time, current, noise, [rival.theta, truth.theta])
    assert abs(gap) < 1e-6 and sd < 1e-3


def test_a_confirmation_keeps_where_each_rivals_refit_came_closest_and_the_criterion_uses_it():
    """The confirmation's refits end where each rival mimics each truth best over the draws: one
    point per ordered pair, a vector of the rival's model, around which the criterion is no larger
    than around the rival's fit alone."""
    from identify.workflows.design import RivalBasins, confirm, evaluate, record_misfit

    heated = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    contenders = _heating_and_plain(heated, 1e-6)
    drive = _short_hold()
    noise, th = estimate_noise(heated.record), Thresholds()
    misfits = {c.name: record_misfit(c, [heated.record], [noise]) for c in contenders}
    basins = RivalBasins()
    confirm(drive, contenders, noise, th, np.random.default_rng(5), draws=2, misfits=misfits, basins=basins)
    assert len(basins) == 2
    for truth, rival in (contenders, contenders[::-1]):
        (point,) = basins.of(truth.name, rival.name)
        assert point.shape == rival.theta.shape and rival.model.in_bounds(point)[0]
    alone = {(p["truth"], p["rival"]): p["gap"] for p in evaluate(drive, contenders, noise, th).pairs}
    for p in evaluate(drive, contenders, noise, th, basins=basins).pairs:
        assert p["gap"] <= alone[(p["truth"], p["rival"])] + 1e-9


def test_a_rival_starts_its_refits_where_an_earlier_confirmation_found_it_closest_to_the_truth():
    """A rival of the truth's own physics fitted in another basin (its coil's heating at the
    slowest time constant and weak, its core's at the fastest): refitted from where it is to
    convergence, it keeps a gap; started also where an earlier confirmation found it mimicking
    the truth, it closes it, on the same simulated record."""
    from identify.workflows.design import RivalBasins, confirm, record_misfit

    heated = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    truth, _ = _heating_and_plain(heated, 1e-6)
    model = normalised_model(Model(["thermal"]))
    far = heated.truth["theta"] | {"alpha": model.parameters["alpha"].value, "thermal_tau": 2000.0}
    far |= {"thermal_sensitivity": 0.01, "thermal_tau_core": 1.0}
    rival = contender("slow", model, model.theta_from_dict(far), truth.covariance)
    noise, th = estimate_noise(heated.record), Thresholds()
    misfits = {c.name: record_misfit(c, [heated.record], [noise]) for c in (truth, rival)}
    seen = RivalBasins()
    seen.add("thermal", "slow", truth.theta)

    def gap(basins):
        rows = confirm(
            _short_hold(), [truth, rival], noise, th, np.random.default_rng(5), 1, misfits=misfits, basins=basins
        )
        return next(r for r in rows if r["truth"] == "thermal")["realised_gaps"][0]

    alone, seeded = gap(None), gap(seen)
    assert alone > 2.0 and abs(seeded) < 0.5


@pytest.mark.parametrize("family", list(FAMILIES))
def test_a_perturbed_shape_keeps_its_counts_and_ranges_and_a_drive_without_rest_keeps_none(family):
    rng = np.random.default_rng(4)
    (count_name, _, _), ranges = SHAPES[family]
    for _ in range(20):
        params = random_drive_parameters(rng, family)
        moved = perturbed_parameters(rng, family, params, 0.5)
        assert set(moved) == set(params)
        if count_name in ranges:  # the levels: as many as before
            assert len(moved[count_name]) == len(params[count_name])
        else:
            assert moved[count_name] == params[count_name]
        assert 0.0 <= moved["rest"] <= MAX_REST and (params["rest"] > 0.0 or moved["rest"] == 0.0)
        for name, (lo, hi) in ranges.items():
            values = np.atleast_1d(moved[name])
            assert np.all((values >= lo) & (values <= hi))
        assert any(np.any(np.atleast_1d(moved[n]) != np.atleast_1d(params[n])) for n in ranges)


def test_refining_a_drive_never_ranks_it_lower_and_can_raise_a_weak_one():
    """A weak heating against the plain model on a short record: the local search from the random
    search's best keeps its family and limits and ends at least as high (here higher)."""
    sim = simulate("thermal_tau=30,thermal_sensitivity=0.01,thermal_expansion=1.5", seed=1, fs=5.0)
    contenders = _heating_and_plain(sim, 1e-4)
    noise, th = estimate_noise(sim.record), Thresholds()
    limits = RigLimits((0.0, 5.0), max_slew=1.6, duration=40.0, max_rms_current=4.0, fs=5.0, quiet=10.0)
    found = search(contenders, limits, noise, th, np.random.default_rng(3), 10.0, per_family=3)[:2]
    for drive in found:
        refined = refine(drive, contenders, limits, noise, th, np.random.default_rng(5), 10.0, trials=12)
        assert refined.family == drive.family and drive_of(drive.family, refined.params, limits, 10.0) is not None
        assert (-refined.value, -min(p["gap"] for p in refined.pairs)) <= (
            -drive.value,
            -min(p["gap"] for p in drive.pairs),
        )
    assert refined.value > drive.value or min(p["gap"] for p in refined.pairs) > min(p["gap"] for p in drive.pairs)


@pytest.fixture(scope="module")
def creep_csv(tmp_path_factory):
    sim = simulate("creep_amplitude=0.03", seed=1, fs=5.0)
    path = tmp_path_factory.mktemp("design") / "creep.csv"
    write_record(path, sim.record, sidecar=sim.truth)
    return path


def test_the_design_command_writes_the_drive_its_numbers_and_a_page(creep_csv, tmp_path, capsys):
    from identify.workflows.design import simulated_gap

    out = tmp_path / "next"
    args = [
        "design",
        str(creep_csv),
        "--out",
        str(out),
        "--candidates",
        "creep,thermal",
        "--duration",
        "110",
        "--drives",
        "4",
        "--n-starts",
        "2",
        "--quiet",
    ]
    assert main(args) == 0
    drive = np.loadtxt(out / "next_input.csv", delimiter=",", skiprows=1)
    assert drive[0, 0] == 0.0 and drive[-1, 0] == pytest.approx(110.0) and np.all(drive[drive[:, 0] < 10.0, 1] == 0)
    content = json.loads((out / "design.json").read_text())
    assert content["contenders"] == ["creep", "thermal"]
    pairs = content["best"]["pairs"]
    assert {(p["truth"], p["rival"]) for p in pairs} == {("creep", "thermal"), ("thermal", "creep")}
    assert all(p["gap"] >= 0 and p["noise_sd"] >= 0 and 0 <= p["p_right"] <= 1 for p in pairs)
    confirmed = content["best"]["confirmed"]  # the best drive was simulated: a mean and sd per pair
    assert {(c["truth"], c["rival"]) for c in confirmed} == {("creep", "thermal"), ("thermal", "creep")}
    for c in confirmed:
        gaps = np.array(c["realised_gaps"])
        assert gaps.size >= 2 and (c["gap"], c["gap_sd"]) == pytest.approx(simulated_gap(gaps))
        assert c["gap_sd"] > gaps.std(ddof=1)  # the next gap's sd, wider than the draws' own
    page = (out / "design.html").read_text()
    assert "next_input.csv" in page and "data:image/png;base64," in page
    # the same transducer driven by the proposed drive: the bench's simulate takes it
    run = tmp_path / "run2.csv"
    assert (
        main(
            [
                "simulate",
                "--out",
                str(run),
                "--input",
                str(out / "next_input.csv"),
                "--truth",
                str(creep_csv.with_suffix(".json")),
                "--seed",
                "3",
            ]
        )
        == 0
    )
    assert json.loads(run.with_suffix(".json").read_text())["theta"]["creep_amplitude"] == pytest.approx(0.03)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--candidates", "creep,warp"], "unknown effect 'warp'"),
        (["--candidates", "creep"], "two or more"),
        (["--current-range", "5:0"], "LO < HI"),
        (["--duration", "5"], "quiet start"),
        (["--duration", "60", "--longest", "30"], "the longest record (30 s) is shorter than the duration (60 s)"),
    ],
)
def test_bad_design_input_is_one_line_exit_2_and_nothing_written(creep_csv, tmp_path, capsys, extra, message):
    out = tmp_path / "never"
    assert main(["design", str(creep_csv), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_fitted_contenders_hold_what_the_records_say():
    """A contender's information on its transducer parameters comes from its fit; the run's own
    parameters (a drift) carry none to a new record."""
    sim = simulate("sensor_drift_linear=1.1", seed=1, fs=5.0)
    noise = estimate_noise(sim.record)
    (drift,) = fitted_contenders([sim.record], normalised_model(Model()), ["sensor_drift"], [noise], n_starts=1)
    names = drift.model.names
    column = names.index("sensor_drift_linear")
    assert np.all(drift.info[column] == 0) and drift.info[names.index("rho"), names.index("rho")] > 0


def test_a_contender_holds_its_record_as_the_joint_diagnosis_fits_it():
    """A record that starts warm: a heating is refitted with its start free (as the joint
    diagnosis of this record and the next frees it) and fits better; a creep has no such state."""
    sim = simulate("thermal_tau=10,thermal_expansion=3,thermal_initial=1.5", seed=1, fs=5.0)
    noise = estimate_noise(sim.record)
    heating = fit_least_squares(sim.record, normalised_model(Model(["thermal"])), noise=noise, n_starts=1)
    refit = fit_with_earlier_runs(sim.record, heating)
    assert refit.model.parameters["thermal_initial"].vary and not heating.model.parameters["thermal_initial"].vary
    assert refit.chi2 < heating.chi2 - 10.0
    creep = fit_least_squares(sim.record, normalised_model(Model(["creep"])), noise=noise, n_starts=1)
    assert fit_with_earlier_runs(sim.record, creep) is creep


def test_contenders_fitted_on_several_records_free_each_records_start():
    """Two runs of one heating, the second started warm: the contenders fitted jointly hold each
    record as the joint diagnosis fits it, the second's start free."""
    cold = simulate("thermal_tau=10,thermal_expansion=3", seed=1, fs=5.0).record
    warm = simulate("thermal_tau=10,thermal_expansion=3,thermal_initial=1.5", seed=2, fs=5.0).record
    noises = [estimate_noise(cold), estimate_noise(warm)]
    (heating,) = fitted_contenders([cold, warm], normalised_model(Model()), ["thermal"], noises, n_starts=1)
    column = heating.model.names.index("thermal_initial")
    assert heating.model.parameters["thermal_initial"].vary
    first, second = (vector[column] for vector, _ in heating.runs)
    assert first < 0.3 and second > 0.75  # the warm run's start found (1.5 true; it trades with the gain)


@pytest.mark.parametrize(
    "gaps, mean, sd",
    [
        ([], None, None),
        ([5.0], None, None),
        # two draws: sample sd sqrt(2), widened by sqrt(3/2) and t_1(0.97725) = 13.97 over 2
        ([1.0, 3.0], 2.0, 2.0**0.5 * 1.5**0.5 * 13.968 / 2),
        ([2.0, 2.0, 2.0], 2.0, 0.0),
        # six draws: sample sd 1, widened by sqrt(7/6) and t_5(0.97725) = 2.649 over 2
        ([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0], 0.0, (6 / 5) ** 0.5 * (7 / 6) ** 0.5 * 2.649 / 2),
    ],
)
def test_simulated_gap(gaps, mean, sd):
    """The calibrated prediction of one pair: the mean of its simulated gaps and the sd of the next gap
    predicted from them (Student's t), none from one draw."""
    from identify.workflows.design import simulated_gap

    got_mean, got_sd = simulated_gap(gaps)
    if mean is None:
        assert (got_mean, got_sd) == (None, None)
    else:
        assert (got_mean, got_sd) == pytest.approx((mean, sd), rel=1e-3)


def _confirmed(*rows):
    return [{"truth": t, "rival": r, "right_names": k, "draws": 6} for t, r, k in rows]


@pytest.mark.parametrize(
    "rows, share, truth",
    [
        ((), 1.0, None),
        ((("creep", "thermal", 6), ("thermal", "creep", 6)), 1.0, "creep"),
        ((("creep", "thermal", 6), ("thermal", "creep", 2)), 2 / 6, "thermal"),
        ((("a", "b", 5), ("a", "c", 5), ("b", "a", 3), ("c", "a", 4)), 3 / 6, "b"),
    ],
)
def test_the_confirmed_share_is_the_weakest_truths(rows, share, truth):
    """A drive's confirmation is as good as the truth it names least often."""
    from identify.workflows.design_criterion import DesignedDrive, confirmed_share

    drive = DesignedDrive("hold", {}, np.zeros(2), np.zeros(2), confirmed=_confirmed(*rows))
    assert confirmed_share(drive) == (pytest.approx(share), truth)


def test_the_chosen_drive_is_the_confirmed_one_with_the_most_right_names():
    """The linear ranking's first drive loses to one the simulation confirms more often; the
    reason says where the linear prediction was optimistic."""
    from identify.workflows.design_criterion import DesignedDrive, confirmed_rank, simulation_text

    linear_best = DesignedDrive("hold", {}, np.zeros(2), np.zeros(2), value=1.0)
    linear_best.confirmed = _confirmed(("creep", "thermal", 6), ("thermal", "creep", 2))
    confirmed_best = DesignedDrive("steps", {}, np.zeros(2), np.zeros(2), value=0.9)
    confirmed_best.confirmed = _confirmed(("creep", "thermal", 5), ("thermal", "creep", 5))
    assert sorted([linear_best, confirmed_best], key=confirmed_rank)[0] is confirmed_best
    assert "only 2 of 6 draws where 'thermal' was the truth" in simulation_text(linear_best)
    assert "only 5 of 6" in simulation_text(confirmed_best)


@pytest.mark.parametrize(
    "first, second",
    [
        # the weakest truth decides
        ((("a", "b", 5), ("b", "a", 5)), (("a", "b", 6), ("b", "a", 4))),
        # named by neither: the next weakest decides
        ((("a", "b", 0), ("b", "a", 3), ("c", "a", 6)), (("a", "b", 0), ("b", "a", 2), ("c", "a", 6))),
        ((("a", "b", 0), ("b", "a", 0), ("c", "a", 1)), (("a", "b", 0), ("b", "a", 0), ("c", "a", 0))),
    ],
)
def test_confirmed_drives_rank_by_their_weakest_truth_then_the_next(first, second):
    """Leximin over the truths' shares of right names: a drive that names no draw of its weakest
    truth still beats one that names fewer of the others; the linear value only breaks ties."""
    from identify.workflows.design_criterion import DesignedDrive, confirmed_rank

    better = DesignedDrive("hold", {}, np.zeros(2), np.zeros(2), value=0.1, confirmed=_confirmed(*first))
    worse = DesignedDrive("steps", {}, np.zeros(2), np.zeros(2), value=0.9, confirmed=_confirmed(*second))
    assert sorted([worse, better], key=confirmed_rank)[0] is better


@pytest.fixture(scope="module")
def loose_creep():
    """A creep record and a contender at its truth whose covariance is far too wide along the
    creep's parameters (a linearisation that extrapolates), with the record's misfit."""
    from identify.workflows.design import record_misfit

    sim = simulate("creep_amplitude=0.03", seed=1, fs=5.0)
    model = normalised_model(Model(["creep"]))
    theta = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    wide = np.where([n.startswith("creep") for n in model.names], 1.0, 1e-6)
    covariance = np.diag(np.where(model.parameters.vary, wide, 0.0))
    c = contender("creep", model, theta, covariance)
    noise = estimate_noise(sim.record)
    return sim, c, noise, record_misfit(c, [sim.record], [noise])


def test_a_draw_held_to_the_records_raises_their_chi_square_no_more_than_its_radius(loose_creep):
    """Without the records a draw of a too-wide covariance leaves them far behind; held to them,
    each draw's rise stays within the largest squared radius of a draw (every axis clipped at 2)."""
    from identify.workflows.design import draw_transducer

    _, c, _, misfit = loose_creep
    k = int(np.sum(np.diag(c.covariance) > 0))
    free = [draw_transducer(c, np.random.default_rng(s)) for s in range(6)]
    held = [draw_transducer(c, np.random.default_rng(s), misfit) for s in range(6)]
    assert misfit(np.array(free)).max() > 100 * 4 * k
    rises = misfit(np.array(held))
    assert np.all(rises <= 4 * k)
    assert any(not np.array_equal(h, c.theta) for h in held)  # they move: not the fit each time


def test_a_draw_no_step_of_which_the_records_allow_is_the_fit(loose_creep):
    from identify.workflows.design import draw_transducer

    _, c, _, _ = loose_creep
    theta = draw_transducer(c, np.random.default_rng(0), lambda rows: np.full(len(rows), np.inf))
    assert np.array_equal(theta, c.theta)


def test_the_misfit_sums_every_record_each_with_its_own_sensor_zero(loose_creep):
    """A second record offset by its sensor zero adds its own rise: twice one record's, none at the fit."""
    from dataclasses import replace

    from identify.workflows.design import record_misfit

    sim, c, noise, one = loose_creep
    shifted = replace(sim.record, displacement=sim.record.displacement + 2.0)
    two_runs = contender(c.name, c.model, c.theta, c.covariance, runs=[(c.theta, 0.0), (c.theta, 2.0)])
    two = record_misfit(two_runs, [sim.record, shifted], [noise, noise])
    moved = c.theta + np.where([n == "creep_amplitude" for n in c.model.names], 0.01, 0.0)
    assert two(c.theta[None])[0] == pytest.approx(0.0, abs=1e-9)
    assert two(moved[None])[0] == pytest.approx(2 * one(moved[None])[0], rel=1e-9)
    assert record_misfit(two_runs, [sim.record], [noise]) is None  # one run per record, or none
    residuals = WhitenedResiduals(sim.record, c.model, noise)
    w = residuals(c.theta[residuals.free])
    assert one.base == pytest.approx(float(w @ w)) and two.base == pytest.approx(2 * one.base)


def test_a_draw_moves_the_runs_own_parameters_held_to_the_first_record():
    """The next run's own parameters (a sensor's drift) are known only as the first record's fit knows
    them: a draw moves them too, within what that record allows, and the misfit counts them against
    that record alone (a later record keeps its own as fitted)."""
    from identify.workflows.design import draw_transducer, record_misfit

    sim = simulate("sensor_drift_linear=1.0", seed=2, fs=5.0)
    model = normalised_model(Model(["sensor_drift"]))
    theta = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    own = np.array([p.per_record for p in model.parameters])
    covariance = np.diag(np.where(model.parameters.vary, np.where(own, 0.04, 1e-8), 0.0))
    noise = estimate_noise(sim.record)
    one = record_misfit(contender("sensor_drift", model, theta, covariance), [sim.record], [noise])
    c = contender("sensor_drift", model, theta, covariance, runs=[(theta, 0.0), (theta, 0.0)])
    two = record_misfit(c, [sim.record, sim.record], [noise, noise])
    moved = theta + np.where([n == "sensor_drift_linear" for n in model.names], 0.3, 0.0)
    assert one(moved[None])[0] > 1.0
    assert two(moved[None])[0] == pytest.approx(one(moved[None])[0], rel=1e-9)
    k = int(np.sum(np.diag(covariance) > 0))
    draws = np.array([draw_transducer(c, np.random.default_rng(s), two) for s in range(6)])
    assert np.all(two(draws) <= 4 * k)
    assert np.ptp(draws[:, own], axis=0).max() > 0.01  # the run's own parameters move


def test_a_truth_is_drawn_without_the_terms_its_record_does_not_support():
    """A plain drift fitted with the whole sensor_drift: the ambient cycle and the warm-up, which the
    record does not support, are pinned off in what the confirmation draws from (and stay off in every
    draw); the contender itself keeps every term, as its refits do."""
    from identify.fitting.lsq import fit_least_squares
    from identify.workflows.design import draw_transducer, draws_without_unsupported_terms, record_misfit

    sim = simulate("sensor_drift_linear=2.0", seed=3, fs=5.0)
    model = normalised_model(Model(["sensor_drift"]))
    noise = estimate_noise(sim.record)
    fit = fit_least_squares(sim.record, model, noise=noise, n_starts=2, rng=np.random.default_rng(0))
    draws_from = draws_without_unsupported_terms(sim.record, fit)
    assert draws_from is not None
    theta, covariance = draws_from
    names = model.names
    off = [
        names.index(n) for n in ("sensor_drift_ambient_sine", "sensor_drift_ambient_cosine", "sensor_drift_settling")
    ]
    assert np.all(theta[off] == 0.0) and np.all(np.diag(covariance)[off] == 0.0)
    assert np.all(np.diag(fit.covariance)[off] > 0.0)
    c = contender("sensor_drift", fit.model, fit.theta, fit.covariance, draws_from=draws_from)
    misfit = record_misfit(c, [sim.record], [noise])
    draws = np.array([draw_transducer(c, np.random.default_rng(s), misfit) for s in range(4)])
    assert np.all(draws[:, off] == 0.0)
    linear = names.index("sensor_drift_linear")
    assert np.ptp(draws[:, linear]) > 0  # the supported drift is drawn


@pytest.fixture(scope="module")
def fitted_drift():
    """A drift record's sensor_drift contender at its least-squares fit (drawn without the terms the
    record does not support), with the record's misfit."""
    from identify.workflows.design import draws_without_unsupported_terms, record_misfit

    sim = simulate("sensor_drift_linear=2.0", seed=3, fs=5.0)
    model = normalised_model(Model(["sensor_drift"]))
    noise = estimate_noise(sim.record)
    fit = fit_least_squares(sim.record, model, noise=noise, n_starts=2, rng=np.random.default_rng(0))
    c = contender(
        "sensor_drift",
        fit.model,
        fit.theta,
        fit.covariance,
        draws_from=draws_without_unsupported_terms(sim.record, fit),
    )
    return c, record_misfit(c, [sim.record], [noise]), sim.record, noise


def test_a_posterior_draw_spreads_as_the_covariance_where_the_model_is_nearly_linear(fitted_drift):
    """Randomised maximum likelihood: the record's whitened residual shifted by fresh noise and refitted.
    A drift's slope is nearly linear in the output, so its draws spread as the fit's covariance says;
    the records' chi-square rises as a chi-square with as many degrees of freedom as move; the
    parameters the covariance pins stay where they are."""
    from identify.workflows.design import posterior_draw

    c, misfit, _, _ = fitted_drift
    theta, covariance = c.draws_from
    moving = np.diag(covariance) > 0
    draws = np.array([posterior_draw(c, np.random.default_rng(s), misfit) for s in range(30)])
    linear = c.model.names.index("sensor_drift_linear")
    ratio = np.std(draws[:, linear], ddof=1) / np.sqrt(covariance[linear, linear])
    assert 0.7 < ratio < 1.4
    rises = misfit(draws)
    assert 0.5 * moving.sum() < rises.mean() < 1.6 * moving.sum()
    assert np.all(draws[:, ~moving] == theta[~moving])


def test_a_contenders_posterior_draws_are_made_once_for_every_drive(fitted_drift):
    """The records' misfit keeps the draws it makes: a second confirmation asks for them again and
    gets the same transducers (a longer list extends them), without another refit."""
    from identify.workflows.design import record_misfit

    c, _, record, noise = fitted_drift
    fresh = record_misfit(c, [record], [noise])
    first = fresh.posterior_draws(c, 2, np.random.default_rng(1))
    again = fresh.posterior_draws(c, 3, np.random.default_rng(2))
    assert len(again) == 3 and all(a is b for a, b in zip(first, again[:2]))
    assert not np.array_equal(again[2], again[0])


def test_a_posterior_draw_stays_with_the_records_where_the_covariance_is_far_too_wide(loose_creep):
    """The covariance only says which parameters move: with one far too wide along the creep, a draw
    from it leaves the record far behind, a posterior draw does not."""
    from identify.workflows.design import draw_transducer, posterior_draw

    _, c, _, misfit = loose_creep
    k = int(np.sum(np.diag(c.covariance) > 0))
    free = np.array([draw_transducer(c, np.random.default_rng(s)) for s in range(4)])
    drawn = np.array([posterior_draw(c, np.random.default_rng(s), misfit) for s in range(4)])
    assert misfit(free).min() > 100 * k
    assert np.all(misfit(drawn) < 4 * k)
    assert np.ptp(drawn, axis=0).max() > 0


@pytest.mark.parametrize(
    "rows, text",
    [
        ([], ""),
        (
            [
                {"duration": 240.0, "family": "hold", "value": 0.874},
                {"duration": 480.0, "family": "steps", "value": 1.0},
            ],
            " Longer records (beyond --duration) would raise that chance to 87 % at 240 s, 100 % at 480 s.",
        ),
    ],
)
def test_the_longer_records_sentence(rows, text):
    from identify.workflows.design import longer_text

    assert longer_text(rows) == text


def test_a_drive_that_is_not_decisive_looks_at_longer_records():
    """A weak heating against the plain model: the longer records found are at the multiples of the
    limit and decide at least as well as the limit's best (more time to heat and to cool)."""
    from identify.workflows.design import LONGER, longer_records, search

    sim = simulate("thermal_tau=30,thermal_sensitivity=0.01,thermal_expansion=1.5", seed=1, fs=5.0)
    contenders = _heating_and_plain(sim, 1e-4)
    noise, th = estimate_noise(sim.record), Thresholds()
    limits = RigLimits((0.0, 5.0), max_slew=1.6, duration=40.0, max_rms_current=4.0, fs=5.0, quiet=10.0)
    here = search(contenders, limits, noise, th, np.random.default_rng(3), 10.0, per_family=3)[0]
    rows = longer_records(contenders, limits, noise, th, np.random.default_rng(3), 10.0, per_family=3)
    assert [r["duration"] for r in rows] == [40.0 * f for f in LONGER]
    assert all(0.0 <= r["value"] <= 1.0 and r["family"] in FAMILIES for r in rows)
    assert here.value < 0.9 and rows[-1]["value"] > here.value


def test_a_rig_that_takes_longer_records_gets_the_design_made_again_longer():
    """The weak heating of the test above: no drive of 40 s decides, so with the rig's longest
    record at 160 s the design is made at 80 s (and 160 s while none decides) too; the drive
    proposed is at least as good by the simulation's right names as the 40 s one, its record as
    long as its limits say, and the text gives each duration's weakest right name."""
    from identify.workflows.design import LONGER, design_drive
    from identify.workflows.design_criterion import confirmed_rank, decisive

    sim = simulate("thermal_tau=30,thermal_sensitivity=0.01,thermal_expansion=1.5", seed=1, fs=5.0)
    contenders, noise = _heating_and_plain(sim, 1e-4), estimate_noise(sim.record)
    shorter = RigLimits((0.0, 5.0), max_slew=1.6, duration=40.0, max_rms_current=4.0, fs=5.0, quiet=10.0)
    kw = {"rng": np.random.default_rng(3), "per_family": 3, "n_confirm": 1}
    alone = design_drive(contenders, [sim.record], noise, limits=shorter, **kw)
    assert not decisive(alone.best)
    assert [r["duration"] for r in alone.durations] == [40.0] and alone.limits.duration == 40.0
    assert alone.longer  # the rig takes nothing longer: the linear search of longer records instead

    kw["rng"] = np.random.default_rng(3)
    plan = design_drive(contenders, [sim.record], noise, limits=replace(shorter, longest=160.0), **kw)
    durations = [r["duration"] for r in plan.durations]
    assert durations[:2] == [40.0, 40.0 * LONGER[0]] and len(durations) in (2, 3)
    assert len(durations) == 3 or decisive(plan.best)
    assert plan.limits.duration in durations and plan.limits.longest == 160.0
    assert plan.best.time[-1] - plan.best.time[0] == pytest.approx(plan.limits.duration, abs=0.5)
    assert f"the record proposed is {plan.limits.duration:.0f} s long," in plan.reason
    assert plan.longer == []
    assert confirmed_rank(plan.best) <= confirmed_rank(alone.best)


@pytest.mark.parametrize(
    "duration, longest, durations",
    [
        (100.0, None, []),
        (100.0, 100.0, []),
        (100.0, 150.0, [150.0]),
        (100.0, 400.0, [200.0, 400.0]),
        (100.0, 1000.0, [200.0, 400.0]),
        (100.0, 300.0, [200.0, 300.0]),
    ],
)
def test_the_longer_durations_a_design_may_try(duration, longest, durations):
    from identify.workflows.design import longer_durations

    limits = RigLimits((0.0, 5.0), 1.6, duration, 4.0, 5.0, 10.0, longest)
    assert longer_durations(limits) == durations


def test_with_the_records_the_confirmation_refits_every_record_as_the_joint_diagnosis_does():
    """Refitted on every record together, the gap counts the record already taken: the same
    simulated new records separate the heating from the plain model more after a record that
    showed heating than after one that showed none."""
    from identify.workflows.design import confirm, record_misfit

    heated = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    cold = simulate(None, seed=1, fs=5.0)
    contenders = _heating_and_plain(heated, 1e-6)
    drive = _short_hold()
    noise, th = estimate_noise(heated.record), Thresholds()
    gaps = {}
    for name, sim in (("heated", heated), ("cold", cold)):
        misfits = {c.name: record_misfit(c, [sim.record], [noise]) for c in contenders}
        rows = confirm(drive, contenders, noise, th, np.random.default_rng(5), draws=2, misfits=misfits)
        gaps[name] = next(r for r in rows if r["truth"] == "thermal")["realised_gaps"]
    assert all(np.isfinite(gaps["heated"] + gaps["cold"]))
    assert min(gaps["heated"]) > max(gaps["cold"])


def test_the_confirmation_refitting_side_by_side_gives_what_it_gives_one_refit_at_a_time():
    """On every sample the refits (each rival's chain over a truth's draws, each truth's refit of
    a draw) run two at a time (each a fit as alone, the earlier records' residuals each refit's
    own): the same gaps, bit for bit, as in a thread that may use one core only, where they run
    one after another."""
    import threading

    from identify.fitting.threads import cap_numba_threads
    from identify.workflows.design import confirm, record_misfit

    heated = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0)
    contenders = _heating_and_plain(heated, 1e-6)
    drive = _short_hold()
    noise, th = estimate_noise(heated.record), Thresholds()

    def rows():  # the misfits made afresh: they keep the draws they make
        misfits = {c.name: record_misfit(c, [heated.record], [noise]) for c in contenders}
        return confirm(drive, contenders, noise, th, np.random.default_rng(5), draws=2, misfits=misfits)

    together = rows()
    alone = []

    def one_core():
        cap_numba_threads(1)  # this thread's side_by_side runs its actions in turn
        alone.extend(rows())

    worker = threading.Thread(target=one_core)
    worker.start()
    worker.join()
    assert len(together) == 2 and all(np.isfinite(r["realised_gaps"]).all() for r in together)
    assert [r["realised_gaps"] for r in together] == [r["realised_gaps"] for r in alone]


def test_a_rival_fitted_in_another_basin_is_also_refitted_from_where_the_new_record_puts_it():
    """A creep whose fit sits at a time constant the new record does not show (0.05 s against 30 s)
    stays there when refitted from its fit, its transducer held; the screening's grid point, gains
    off, is among its starts and refits as low as a refit from the truth. Every start differs from
    the fit only in the explanation's parameters."""
    from identify.workflows.design import penalised_refit, rival_starts

    sim = simulate("creep_amplitude=0.03,creep_tau=30", seed=1, fs=5.0)
    model = normalised_model(Model(["creep"]))
    truth = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    names = list(model.names)
    creep = np.array([n.startswith("creep") for n in names])
    wrong = truth.copy()
    wrong[names.index("creep_tau")], wrong[names.index("creep_decades")] = 0.05, 0.3
    # the records hold the transducer tightly and say nothing of the creep
    c = contender("creep", model, wrong, np.diag(np.where(model.parameters.vary, np.where(creep, 1e4, 1e-6), 0.0)))
    noise = estimate_noise(sim.record)
    starts = rival_starts(c, sim.record, noise)
    assert np.array_equal(starts[0], wrong) and len(starts) > 1
    assert all(np.array_equal(s[~creep], wrong[~creep]) for s in starts)
    assert any(s[names.index("creep_amplitude")] == 0.0 for s in starts[1:])  # gains off

    def refit(theta):
        return penalised_refit(c, sim.record, noise, theta)[0]

    best, from_fit, at_truth = min(map(refit, starts)), refit(wrong), refit(truth)
    assert best <= 1.01 * at_truth
    assert from_fit > at_truth + 100.0


WARM = {"thermal_initial": 1.0, "thermal_initial_core": 1.0}  # halfway into [0, 2], off at 0


@pytest.mark.parametrize(
    ("effects", "explanation", "set_off", "warm"),
    [
        # the explanation's heating at its off values, its start rises halfway
        (["thermal"], "thermal", "thermal", WARM),
        (["creep", "thermal"], "creep+thermal", "thermal", WARM),
        # the model's heating (not the explanation's) keeps its fitted shape, starts warm
        (["creep", "thermal"], "creep", None, WARM),
        (["creep"], "creep", None, None),  # no state earlier runs leave
    ],
)
def test_a_rivals_warm_start_holds_its_heating_off_and_every_start_rise_halfway(effects, explanation, set_off, warm):
    """The warm start puts every start rise halfway into its range and the explanation's heating
    at its off values; the transducer and every other parameter keep the fit's values."""
    from identify.workflows.design import warm_start

    model = normalised_model(Model(effects))
    names = list(model.names)
    fitted = model.default_theta() + 0.01 * np.arange(len(names))  # every value off its default
    c = contender(explanation, model, fitted, np.diag(np.where(model.parameters.vary, 1e-4, 0.0)))
    started = warm_start(c)
    if warm is None:
        assert started is None
        return
    off = np.array([set_off is not None and n.startswith(set_off + "_") for n in names])
    expected = np.where(off, c.model.default_theta(), fitted)
    for name, value in warm.items():
        expected[names.index(name)] = value
    np.testing.assert_array_equal(started, expected)


def test_a_heating_that_starts_warm_and_cools_is_reached_by_the_warm_start_only():
    """A record whose run starts warm and cools (start rise 1.5, expansion of 20 um per unit,
    60 s): every cold start of a heating rival (its fit with the heating off, the screening's)
    meets the start rise at zero, where the cooling has no slope, and stays thousands above the
    truth's refit; the warm start refits to within 1 % of it."""
    from identify.workflows.design import penalised_refit, rival_starts, warm_start

    sim = simulate("thermal_tau=60,thermal_expansion=20,thermal_initial=1.5", seed=1, fs=5.0)
    model = with_earlier_runs(normalised_model(Model(["thermal"])))
    truth = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    heating = np.array([n.startswith("thermal") for n in model.names])
    cold = np.where(heating, model.default_theta(), truth)
    c = contender("thermal", model, cold, np.diag(np.where(model.parameters.vary, np.where(heating, 1e4, 1e-6), 0.0)))
    noise = estimate_noise(sim.record)

    def refit(theta):
        return penalised_refit(c, sim.record, noise, theta)[0]

    at_truth = refit(truth)
    assert min(map(refit, rival_starts(c, sim.record, noise))) > at_truth + 1000.0
    assert refit(warm_start(c)) <= 1.01 * at_truth


def test_the_joint_refit_frees_each_earlier_records_own_parameters_as_the_joint_diagnosis_does():
    """An earlier record's own parameters (its run's sensor drift) are refitted with the
    transducer, as the joint diagnosis fits them: a contender whose first run's drift starts a
    micrometre off gives the simulated gaps of one whose run starts at its fit (held there, the
    truth's refit carries that record's misfit: the gaps fell from 32 and 46 to -31 and 8)."""
    from identify.workflows.design import confirm, record_misfit

    sim = simulate("sensor_drift_linear=1.5,sensor_drift_quadratic=-0.8", seed=1, fs=5.0)
    model = normalised_model(Model(["sensor_drift"]))
    theta = model.theta_from_dict(sim.truth["theta"] | {"alpha": model.parameters["alpha"].value})
    covariance = np.diag(np.where(model.parameters.vary, 1e-8, 0.0))
    off = theta.copy()
    off[model.names.index("sensor_drift_linear")] += 1.0
    plain = normalised_model(Model())
    n = plain.n_parameters
    rival = contender("plain", plain, theta[:n], covariance[:n, :n])
    drive = _short_hold()
    noise, th = estimate_noise(sim.record), Thresholds()
    gaps = {}
    for label, runs in (("at its fit", None), ("off", [(off, 0.0)])):
        truth = contender("sensor_drift", model, theta, covariance, runs=runs)
        misfits = {c.name: record_misfit(c, [sim.record], [noise]) for c in (truth, rival)}
        rows = confirm(drive, [truth, rival], noise, th, np.random.default_rng(5), draws=2, misfits=misfits)
        gaps[label] = next(r for r in rows if r["truth"] == "sensor_drift")["realised_gaps"]
    assert min(gaps["at its fit"]) > 20.0
    np.testing.assert_allclose(gaps["off"], gaps["at its fit"], rtol=0.02, atol=2.0)


def test_a_confirmation_simulates_the_sensors_correlated_noise():
    """On a sensor with AR(1) noise the next record's noise is correlated too. The joint gap, a
    likelihood ratio with the noise scale profiled out over both records, then agrees with the
    chi-square gap on the new record alone; noise simulated white for that sensor, whitened as
    AR(1), has ``(1 + r^2) / (1 - r^2)`` times the variance the scale expects (``r`` each step's
    correlation) and would shrink the joint gap by about that factor (to a quarter here)."""
    from identify.workflows.design import DesignedDrive, confirm, record_misfit

    heated = simulate("thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5", seed=1, fs=5.0, noise_rho=0.6)
    contenders = _heating_and_plain(heated, 1e-6)
    noise = estimate_noise(heated.record)
    assert noise.rho > 0.4
    # a new record of more samples than the first, so that its noise sets the profiled scale
    limits = RigLimits((0.0, 5.0), max_slew=1.6, duration=40.0, max_rms_current=4.0, fs=25.0, quiet=10.0)
    hold = {"cycles": 1, "amplitude": 0.9, "level": 0.9, "hold": 0.4}
    drive = DesignedDrive("hold", {}, *drive_of("hold", hold, limits, 10.0))
    gaps = {}
    for joint in (True, False):  # the same draws and noise in both (the misfits keep the draws they make)
        misfits = {c.name: record_misfit(c, [heated.record], [noise]) for c in contenders}
        rows = confirm(
            drive, contenders, noise, Thresholds(), np.random.default_rng(5), 3, misfits=misfits, every_record=joint
        )
        gaps[joint] = np.mean(next(r["realised_gaps"] for r in rows if r["truth"] == "thermal"))
    assert gaps[False] > 200.0
    assert abs(gaps[True] / gaps[False] - 1.0) < 0.3
