"""Real measured records: shipped copies, converters, the peer GPI fit on the SMA data.

Reference values and their provenance:

* SMA peer fit (../shared/realdata/PEERS.md item 1, HaammiiD/Genetic-Algorithm-System-
  Identification ``PI_11P.m``): RMSE 2.2587, MAE 1.1423, max |e| 16.849, first output
  18.125279 over the 773 samples of ``input_data_sequence.csv``. PEERS.md quotes 4-5
  digits, so the tolerance is 1e-3 (RMSE) and 1e-4 relative (first output).
* Shipped files: SHA-256 recorded in ``data/*.LICENSE.md`` when they were converted; the
  converter must reproduce them byte for byte from the shared sources.
* Segment facts (quiet start, switch-on step, hold at 1.830 V) from each PROVENANCE.md.

Tests reading ``../shared/realdata`` skip with the path when it is absent.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pytest

from identify.data.realdata import (
    BASAERI_N_OPERATORS,
    MICROMANIPULATOR_HOLD_ROWS,
    REAL_RECORDS,
    SMARTHYSTERESIS_SWITCH_ON_S,
    basaeri_gpi,
    basaeri_theta,
    convert_micromanipulator,
    convert_smarthysteresis,
    drop_window,
    held_input_noise_sigma,
    load_sma_sequence,
    shared_realdata_dir,
)
from identify.data.records import load_record
from model import gpi

ROOT = Path(__file__).resolve().parents[1]
SHARED = shared_realdata_dir()


def shared_file(*parts) -> Path:
    """Path into the shared realdata folder, or skip the test saying which path is missing."""
    path = SHARED.joinpath(*parts)
    if not path.is_file():
        pytest.skip(
            f"real records not available: {path} is absent (../shared/realdata, beside the project, holds the real "
            "records with their licences; docs/realdata.md)"
        )
    return path


def recorded_sha256(notice: str) -> str:
    """The 'SHA-256 of this file' value written in a data/*.LICENSE.md notice."""
    text = (ROOT / "data" / notice).read_text(encoding="utf-8")
    match = re.search(r"SHA-256 of this file: ([0-9a-f]{64})", text)
    assert match, f"data/{notice} must state the SHA-256 of the shipped file"
    return match.group(1)


def load_shipped(name):
    info = REAL_RECORDS[name]
    return load_record(ROOT / info.shipped, **info.load_options)


# -- shipped copies -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, notice",
    [
        ("piezo_smarthysteresis", "piezo_smarthysteresis.LICENSE.md"),
        ("piezo_micromanipulator_dbo", "piezo_micromanipulator.LICENSE.md"),
    ],
)
def test_shipped_copy_matches_its_notice(name, notice):
    """The shipped CSV is the file the notice describes (hash), and the notice carries the MIT text."""
    shipped = ROOT / REAL_RECORDS[name].shipped
    assert hashlib.sha256(shipped.read_bytes()).hexdigest() == recorded_sha256(notice)
    text = (ROOT / "data" / notice).read_text(encoding="utf-8")
    assert "MIT License" in text and "Permission is hereby granted" in text and "Copyright (c)" in text


def test_smarthysteresis_segments():
    """Quiet start at v = 0 with the documented offset/noise, then the step at 3.2572 s to -87.1 V."""
    record = load_shipped("piezo_smarthysteresis")
    assert len(record) == 50001 and record.input_unit == "V" and record.output_unit == "um"
    assert record.time[-1] == pytest.approx(10.0)
    quiet = record.time < SMARTHYSTERESIS_SWITCH_ON_S - 1e-6
    assert np.all(record.current[quiet] == 0.0)
    assert record.current[~quiet][0] == pytest.approx(-87.096918)
    # PROVENANCE.md: y = -1.684 +- 0.049 um in the quiet part
    assert record.displacement[quiet].mean() == pytest.approx(-1.684, abs=2e-3)
    assert record.displacement[quiet].std() == pytest.approx(0.049, abs=2e-3)
    assert np.abs(record.current).max() == pytest.approx(150.0, abs=0.01)


def test_micromanipulator_segments_and_hold_noise():
    """200 Hz time base, the 1.830 V hold, and a hold-based noise sigma of about 0.07 um."""
    record = load_shipped("piezo_micromanipulator_dbo")
    assert len(record) == 7432
    np.testing.assert_allclose(np.diff(record.time), 0.005, atol=1e-12)
    start, stop = MICROMANIPULATOR_HOLD_ROWS
    assert np.all(record.current[start:stop] == 1.830003)
    # the ramps start right before and right after the hold (row 5072 is the ramp-up's first, zero-phase sample)
    assert record.current[start - 1] != 1.830003 and record.current[stop + 1] != 1.830003
    sigma = held_input_noise_sigma(record.displacement, MICROMANIPULATOR_HOLD_ROWS)
    # the plain std over the hold is 0.068 um; the difference-based estimate must agree within 10 %
    assert sigma == pytest.approx(np.std(record.displacement[start:stop]), rel=0.1)
    assert 0.03 < sigma < 0.15


def test_held_input_noise_sigma_ignores_offset_and_drift():
    rng = np.random.default_rng(7)
    y = 5.0 + 0.01 * np.arange(4000) + rng.normal(0.0, 0.2, 4000)
    assert held_input_noise_sigma(y, (0, 4000)) == pytest.approx(0.2, rel=0.05)
    with pytest.raises(ValueError, match="rows"):
        held_input_noise_sigma(y, (10, 15))


# -- converters ---------------------------------------------------------------------------


def test_convert_smarthysteresis_reproduces_shipped_copy(tmp_path):
    source = shared_file("piezo_smarthysteresis", "hysteresis_v_150_1hz.csv")
    result = convert_smarthysteresis(source, tmp_path / "out.csv")
    assert result.n_rows == 50001
    assert (tmp_path / "out.csv").read_bytes() == (ROOT / REAL_RECORDS["piezo_smarthysteresis"].shipped).read_bytes()
    # the values are the source's: compare numerically with a plain parse of the source
    raw = np.genfromtxt(source, delimiter=",")
    record = load_record(tmp_path / "out.csv", **REAL_RECORDS["piezo_smarthysteresis"].load_options)
    np.testing.assert_array_equal(record.time, raw[:, 1])
    np.testing.assert_array_equal(record.displacement, raw[:, 2])
    np.testing.assert_array_equal(record.current, raw[:, 3])


def test_convert_micromanipulator_reproduces_shipped_copy(tmp_path):
    source = shared_file("piezo_micromanipulator_dbo", "Test_Vi_Do_Di.dat")
    result = convert_micromanipulator(source, tmp_path / "out.csv")
    assert result.n_rows == 7432
    assert (tmp_path / "out.csv").read_bytes() == (
        ROOT / REAL_RECORDS["piezo_micromanipulator_dbo"].shipped
    ).read_bytes()
    raw = np.loadtxt(source)[:7432]
    record = load_record(tmp_path / "out.csv", **REAL_RECORDS["piezo_micromanipulator_dbo"].load_options)
    np.testing.assert_array_equal(record.current, raw[:, 0])
    np.testing.assert_array_equal(record.displacement, raw[:, 4])


def test_converters_reject_bad_input_and_write_nothing(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text(",0,1.0,0\n,0.1,abc,0\n")
    with pytest.raises(ValueError, match=r"line 2: displacement 'abc' is not a number"):
        convert_smarthysteresis(bad, tmp_path / "out.csv")
    assert not (tmp_path / "out.csv").exists()
    bad.write_text(",0,1.0,0\n,0,1.1,0\n")
    with pytest.raises(ValueError, match="line 2: time 0 does not increase"):
        convert_smarthysteresis(bad, tmp_path / "out.csv")
    dat = tmp_path / "bad.dat"
    dat.write_text("1 2 3 4 5\n1 2 3\n")
    with pytest.raises(ValueError, match="line 2: expected at least 5 columns"):
        convert_micromanipulator(dat, tmp_path / "out.csv", rows=(0, 2))
    with pytest.raises(ValueError, match="reach beyond"):
        convert_micromanipulator(dat, tmp_path / "out.csv", rows=(0, 10))
    assert not (tmp_path / "out.csv").exists()


# -- the SMA record and the published peer fit ---------------------------------------------


def sma_record():
    shared_file("sma_morphing_wing_ga", "input_data_sequence.csv")
    return load_sma_sequence()


def test_sma_record_states_its_assumptions():
    record = sma_record()
    assert len(record) == 773
    np.testing.assert_array_equal(record.time, np.arange(773.0))
    assert any("no time column" in note for note in record.notes)


def test_peer_fit_reproduces_published_rmse():
    """PEERS.md item 1: their parameters and initial state give RMSE 2.2587 on 773 samples."""
    record = sma_record()
    prediction = basaeri_gpi(record.current)
    error = record.displacement - prediction
    assert np.sqrt(np.mean(error**2)) == pytest.approx(2.2587, abs=1e-3)
    assert np.mean(np.abs(error)) == pytest.approx(1.1423, abs=1e-3)
    assert np.abs(error).max() == pytest.approx(16.849, abs=1e-3)
    assert prediction[0] == pytest.approx(18.125279, rel=1e-4)
    assert prediction.min() == pytest.approx(18.1253, abs=1e-3)
    assert prediction.max() == pytest.approx(131.7497, abs=1e-3)


def test_peer_fit_equals_project_gpi_after_reparametrisation():
    """The peer model is this project's GPI with alpha = -P11 and shifted envelopes (module docstring)."""
    record = sma_record()
    theta, initial_memory = basaeri_theta()
    ours = gpi(theta, record.current, n_operators=BASAERI_N_OPERATORS, initial_memory=initial_memory)
    np.testing.assert_allclose(ours, basaeri_gpi(record.current), rtol=0, atol=1e-9)


def test_peer_mapping_holds_for_other_parameters():
    """The mapping is exact for any parameters and operator counts, not only the published ones."""
    rng = np.random.default_rng(3)
    v = np.concatenate([np.linspace(0, 2.4, 50), np.linspace(2.4, 0.7, 30), np.linspace(0.7, 2.0, 30)])
    for n_operators in (5, 21):
        params = np.array([12.0, 2.0, -4.0, 14.0, 1.0, 5.0, -8.0, 0.5, 8.0, 2.0, 0.05])
        params = params * rng.uniform(0.9, 1.1, size=11)
        theta, z0 = basaeri_theta(params, n_operators=n_operators, offset=3.0)
        np.testing.assert_allclose(
            gpi(theta, v, n_operators=n_operators, initial_memory=z0),
            basaeri_gpi(v, params, n_operators=n_operators, offset=3.0),
            rtol=0,
            atol=1e-9,
        )


# -- the switch-on window of the SmartHysteresis record -------------------------------------


def classical_like_theta(v_peak, n_operators=12, alpha=-0.1993):
    """A valid GPI theta for a +-v_peak drive: near-linear envelopes, plays up to v_peak wide."""
    from model import THETA_NAMES

    half_band = abs(alpha) * (n_operators + 0.5)
    slope = abs(alpha) * (n_operators - 1) / v_peak
    a1 = 0.004
    values = dict(
        alpha=alpha,
        rho=1.0,
        tau=0.0,
        a0=slope / a1,
        a1=a1,
        a2=0.0,
        a3=-half_band,
        b0=slope / a1,
        b1=a1,
        b2=0.0,
        b3=half_band,
        c0=0.5,
        c1=0.01,
        c2=0.0,
        c3=0.0,
        d0=0.6,
        d1=0.01,
        d2=0.0,
        d3=-1.0,
    )
    return np.array([values[n] for n in THETA_NAMES])


def test_drop_window_leaves_gpi_output_unchanged_after_the_first_peak():
    record = load_shipped("piezo_smarthysteresis")
    dropped = drop_window(record, SMARTHYSTERESIS_SWITCH_ON_S, SMARTHYSTERESIS_SWITCH_ON_S + 0.02)
    assert len(record) - len(dropped) == 100
    assert "dropped (100 samples)" in dropped.notes[-1]
    theta = classical_like_theta(150.0)
    full = gpi(theta, record.current)
    short = gpi(theta, dropped.current)
    kept = np.isin(record.time, dropped.time)
    first_peak = record.time[np.argmax(record.current)]  # the first +150 V peak
    assert 3.55 < first_peak < 3.65
    after = record.time[kept] > first_peak
    np.testing.assert_array_equal(short[after], full[kept][after])
    # before that peak the dropped -87.1 V minimum leaves a different memory, as documented
    before = (record.time[kept] > SMARTHYSTERESIS_SWITCH_ON_S) & ~after
    assert np.abs(short[before] - full[kept][before]).max() > 1e-6


def test_drop_window_rejects_empty_or_total_windows():
    record = load_shipped("piezo_smarthysteresis")
    with pytest.raises(ValueError, match="start < stop"):
        drop_window(record, 5.0, 4.0)
    with pytest.raises(ValueError, match="holds 0 of 50001 samples"):
        drop_window(record, 20.0, 30.0)
    with pytest.raises(ValueError, match="holds 50001 of 50001"):
        drop_window(record, -1.0, 11.0)


# -- the project's identification against the published SMA fit ---------------------------

PEER_RMSE = 2.2587  # PEERS.md item 1, over all 773 samples


def sma_model(n_operators):
    from identify.fitting.parametrisation import normalised_model
    from model import Model

    model = normalised_model(Model(["initial_state"], n_operators=n_operators))
    # the peer's operators start above their upper bounds: its initial level is a free parameter
    # (pinned by default, an exact reparametrisation where the GPI's offsets are free)
    return model.with_parameters(model.parameters.replace("initial_state_memory", vary=True))


def full_rms(fit) -> float:
    """RMS over all samples, as PEERS.md computes it (FitResult.rms leaves out the 1-sample 'quiet' start)."""
    return float(np.sqrt(np.mean(fit.residual**2)))


@pytest.mark.slow
def test_least_squares_from_the_peer_solution_improves_on_it():
    """The peer fit lies inside this project's model (21 operators + initial_state), so its
    least squares started there must end clearly lower (measured 1.99-2.19 with the
    least-squares versions of this week, 2.207 at 6853bbe, vs 2.2587)."""
    from identify.fitting.lsq import fit_least_squares
    from identify.fitting.noise import estimate_noise
    from identify.fitting.parametrisation import to_normalisation

    record = sma_record()
    model_ = sma_model(BASAERI_N_OPERATORS)
    theta, _ = basaeri_theta()
    start = model_.default_theta()
    start[:19] = to_normalisation(theta)
    # the peer starts every operator at its upper bound: any level above them does that
    start[model_.names.index("initial_state_memory")] = model_.parameters["initial_state_memory"].upper
    start_error = record.displacement - model_(start, record.time, record.current)
    assert np.sqrt(np.mean(start_error**2)) == pytest.approx(PEER_RMSE, abs=1e-3)
    noise = estimate_noise(record, noise_sigma="free")
    fit = fit_least_squares(record, model_, noise=noise, start=start, n_starts=1, rng=np.random.default_rng(0))
    print(f"RMS from the peer's start: {full_rms(fit):.4f} (peer {PEER_RMSE})")
    assert full_rms(fit) < PEER_RMSE - 0.01  # a clear decrease, beyond the 1e-3 reproduction tolerance
    assert np.abs(fit.residual).max() < 16.849  # the peer's max |error|


def diagnose_json(tmp_path, path, options) -> dict:
    """``python -m identify diagnose PATH OPTIONS --json``: the diagnosis as a dict."""
    import json

    from identify import cli

    out = tmp_path / "diagnosis.json"
    assert cli.main(["diagnose", str(path), *options, "--json", str(out), "--quiet"]) == 0
    return json.loads(out.read_text())


def baseline_residual(diagnosis: dict, record) -> np.ndarray:
    """Data minus the diagnosis' baseline fit, recomputed from its parameters (all samples)."""
    from model import Model

    fitted = Model.from_dict(diagnosis["fit"]["model"])
    theta = np.array([diagnosis["fit"]["theta"][name] for name in fitted.names])
    return record.displacement - fitted(theta, record.time, record.current)


SMA_OPTIONS = [
    "--time-column",
    "none",
    "--input-column",
    "v_input",
    "--output-column",
    "y_output",
    "--input-unit",
    "V",
    "--output-unit",
    "unknown",
]


@pytest.mark.slow
def test_project_identification_beats_the_published_sma_fit(tmp_path):
    """The project's GPI, identified without any peer information, against the GA's 21 operators.

    ``diagnose``'s baseline least squares (12 operators, multi-start from the data-scaled
    Table 1, finished by a trust-region polish) on ``input_data_sequence.csv``:
    measured RMS 1.951 over all 773 samples (max |error| 12.77) vs 2.2587 (16.849) at
    commit 9a03202; 6.99 (max |error| 50.7) at 6853bbe, after the threshold-sign change: a
    regression this test flags.
    The diagnosis needs a known noise level, which this record lacks; a white-noise sigma
    only scales the least-squares objective, so ``--noise-sigma 1.0`` leaves the optimum
    unchanged.
    """
    path = shared_file("sma_morphing_wing_ga", "input_data_sequence.csv")
    record = sma_record()
    diagnosis = diagnose_json(tmp_path, path, [*SMA_OPTIONS, "--noise-sigma", "1.0", "--n-operators", "12"])
    error = baseline_residual(diagnosis, record)
    rms = float(np.sqrt(np.mean(error**2)))
    print(f"project GPI (12 operators): RMS {rms:.4f} over 773 samples, max |error| {np.abs(error).max():.3f}")
    assert rms < PEER_RMSE - 0.1
    assert np.abs(error).max() < 16.849


@pytest.mark.slow
def test_fit_least_squares_alone_against_the_peer_fit():
    """The plain multi-start least squares (no peer information) on the SMA record beats the GA.

    ``fit_least_squares`` (what ``fit`` and ``study`` use) polishes the two best-screened
    starts. Which
    basin they reach is sensitive to the last bits of the model output (the clamps make
    the finite-difference Jacobian jump), so one seed is not a measurement: over seeds 1-5
    (16 starts, 12 and 21 operators, best of the two, RMS over all 773 samples) the
    vectorised-envelope kernel (session 4) gave 5.2795, 2.0193, 1.9098, 2.0683, 1.9378
    and the previous kernel 1.9356, 1.9470, 1.8756, 1.9492, 1.8554, vs the GA's 2.2587.
    With ``n_polish=4`` all five seeds beat the GA with either kernel (1.90-1.94 now).
    Figures after the GPI was given its whole domain: docs/benchmarks.md.
    """
    from identify.fitting.lsq import fit_least_squares
    from identify.fitting.noise import estimate_noise

    record = sma_record()
    noise = estimate_noise(record, noise_sigma="free")
    best = {}
    for seed in range(1, 6):
        figures = {}
        for n_operators in (12, 21):
            fit = fit_least_squares(
                record, sma_model(n_operators), noise=noise, n_starts=16, rng=np.random.default_rng(seed)
            )
            assert (
                fit.model.in_bounds(fit.theta)[0] and fit.model.evaluate(fit.theta, record.time, record.current)[1][0]
            )
            figures[n_operators] = full_rms(fit)
        best[seed] = min(figures.values())
        print(f"seed {seed}: RMS 12 operators {figures[12]:.4f}, 21 operators {figures[21]:.4f} (peer {PEER_RMSE})")
    beaten = sum(rms < PEER_RMSE for rms in best.values())
    print(
        f"fit_least_squares beats the GA's {PEER_RMSE} on {beaten}/5 seeds; median best RMS "
        f"{np.median(list(best.values())):.4f}"
    )
    assert beaten >= 4
    assert np.median(list(best.values())) < PEER_RMSE


# -- the project's least squares on the shipped piezo records (slow: 50,001 and 7,432 samples) --

PIEZO_FIT_OPTIONS = {
    "piezo_smarthysteresis": ["--input-column", "voltage", "--input-unit", "V"],
    "piezo_micromanipulator_dbo": ["--input-column", "voltage", "--input-unit", "V", "--noise-sigma", "0.0706"],
}


@pytest.fixture(scope="module")
def piezo_fits(tmp_path_factory):
    """``python -m identify fit`` on each shipped piezo record: {name: fit.json contents}."""
    from identify import cli

    folder = tmp_path_factory.mktemp("piezo_fits")
    fits = {}
    for name, options in PIEZO_FIT_OPTIONS.items():
        out = folder / f"{name}.json"
        argv = ["fit", str(ROOT / REAL_RECORDS[name].shipped), *options, "--n-starts", "4", "--json", str(out)]
        code = cli.main(argv)
        fits[name] = __import__("json").loads(out.read_text())
        # exit 1 is the documented finding "the solver did not converge" (docs/reliability.md);
        # the micromanipulator's 7,432-sample fit reaches max_nfev with 4 starts
        assert code == (0 if fits[name]["success"] else 1)
    return fits


def straight_line_rms(record, energised) -> float:
    """RMS of the best ``y = a + b v`` over the energised samples: the bar any hysteresis model must clear."""
    design = np.column_stack([np.ones(energised.sum()), record.current[energised]])
    coefficients, *_ = np.linalg.lstsq(design, record.displacement[energised], rcond=None)
    return float(np.sqrt(np.mean((record.displacement[energised] - design @ coefficients) ** 2)))


@pytest.mark.slow
def test_fit_command_runs_on_the_piezo_records_with_their_noise(piezo_fits):
    smart = piezo_fits["piezo_smarthysteresis"]
    # the unenergised start is found in the data and gives the documented sensor noise
    assert smart["noise"]["source"] == "quiet_segment" and smart["noise"]["n_quiet"] == 16286
    assert smart["noise"]["sigma"] == pytest.approx(0.0486, rel=0.02)
    micro = piezo_fits["piezo_micromanipulator_dbo"]
    assert micro["noise"]["source"] == "user" and micro["noise"]["sigma"] == 0.0706
    for fit in (smart, micro):
        assert np.isfinite(fit["rms"]) and fit["rms"] > 0
        assert len(fit["residual"]) in (50001, 7432)


@pytest.mark.slow
def test_gpi_fit_beats_a_straight_line_on_the_piezo_records(piezo_fits):
    """Measured 2026-11-22 (4 starts): SmartHysteresis 0.522 um vs line 1.878 um; micromanipulator
    0.767 um vs 2.397 um. Before thresholds of either sign were allowed (alpha < 0 only) the fit
    ended at 3.7-5.4 and 2.1-6.8 um, no better than the line; the fit now picks alpha > 0."""
    for name, fit in piezo_fits.items():
        record = load_shipped(name)
        energised = np.ones(len(record), dtype=bool)
        if fit["noise"]["source"] == "quiet_segment":
            energised[slice(*fit["noise"]["quiet"])] = False
        line = straight_line_rms(record, energised)
        print(f"{name}: GPI RMS {fit['rms']:.3f} um, straight line {line:.3f} um")
        assert fit["rms"] < 0.5 * line, name


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, factor",
    [("piezo_micromanipulator_dbo", 0.5), ("piezo_smarthysteresis", 0.5)],
)
def test_diagnose_baseline_beats_a_straight_line(tmp_path, name, factor):
    """``diagnose`` on the shipped piezo records: its baseline must beat ``y = a + b v`` as ``fit`` does.

    Measured baselines (um): SmartHysteresis 0.1295 (diagnose of d1c6cff), 1.144 (9a03202 to
    6853bbe, while ``fit`` reaches 0.522 at 6853bbe); micromanipulator 1.30, then 0.934.
    SmartHysteresis takes several minutes (50,001 samples, five candidate refits).
    """
    record = load_shipped(name)
    diagnosis = diagnose_json(tmp_path, ROOT / REAL_RECORDS[name].shipped, PIEZO_FIT_OPTIONS[name] + ["--seed", "1"])
    energised = np.ones(len(record), dtype=bool)
    if name == "piezo_smarthysteresis":
        energised[:16286] = False
    line = straight_line_rms(record, energised)
    print(
        f"{name}: GPI RMS {diagnosis['rms']:.4f} um, straight line {line:.4f} um; verdict {diagnosis['status']} "
        f"{diagnosis['missing']}"
    )
    assert diagnosis["rms"] < factor * line
    assert diagnosis["status"] in ("adequate", "missing_effect", "unexplained")


def test_the_shared_folder_is_beside_the_project(monkeypatch):
    """<project>/../shared/realdata, wherever the module sits in the package (a layout change
    once pointed it inside the project, and every real-data test skipped)."""
    from pathlib import Path

    import identify

    monkeypatch.delenv("MSMA_SHARED_REALDATA", raising=False)
    project = Path(identify.__file__).resolve().parents[1]
    assert shared_realdata_dir() == project.parent / "shared" / "realdata"
