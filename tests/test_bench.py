"""Tests of the virtual bench (identify/bench.py) and the ``simulate`` command."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

import identify
from identify import cli
from identify.bench import parse_effect_spec, sensor_noise, simulate
from identify.cli import simulate as cmd_simulate
from identify.data.records import load_record, sidecar_path
from model import EFFECTS, TABLE1, Model, gpi, paper_current


def _run(argv) -> int:
    """Run the simulate command with ``argv`` (its own parser: independent of other commands)."""
    parser = argparse.ArgumentParser()
    cmd_simulate.add_arguments(parser)
    return cmd_simulate.run(parser.parse_args(argv))


def test_simulate_is_registered():
    assert cli.COMMANDS["simulate"] == "identify.cli.simulate"


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    argv = ["--effects", "thermal,creep_amplitude=0.02", "--noise", "0.5", "--seed", "11"]
    a, b, c = tmp_path / "a" / "r.csv", tmp_path / "b" / "r.csv", tmp_path / "c" / "r.csv"
    assert _run(["--out", str(a), *argv]) == 0
    assert _run(["--out", str(b), *argv]) == 0
    assert _run(["--out", str(c), *argv[:-1], "12"]) == 0
    assert a.read_bytes() == b.read_bytes()
    truth_a = json.loads(sidecar_path(a).read_text())
    truth_b = json.loads(sidecar_path(b).read_text())
    truth_a.pop("command"), truth_b.pop("command")  # holds --out, which differs
    assert truth_a == truth_b
    assert a.read_bytes() != c.read_bytes()
    # Only the noise differs between seeds: same time and current columns.
    ra, rc = load_record(a), load_record(c)
    assert np.array_equal(ra.time, rc.time) and np.array_equal(ra.current, rc.current)
    assert not np.array_equal(ra.displacement, rc.displacement)


def test_sidecar_round_trip_reproduces_the_record(tmp_path):
    out = tmp_path / "bench.csv"
    spec = ",".join(EFFECTS)  # the whole library
    assert (
        _run(
            ["--out", str(out), "--effects", spec, "--noise", "0.3", "--noise-rho", "0.6", "--fs", "50", "--seed", "4"]
        )
        == 0
    )
    record = load_record(out)
    truth = record.sidecar
    assert truth["seed"] == 4 and truth["fs"] == 50.0 and truth["input_reading"] == "literal"
    assert truth["noise"] == {"sigma": 0.3, "rho": 0.6, "kind": "ar1"}
    assert truth["software"]["version"] == identify.__version__
    assert "git_commit" in truth["software"]
    assert truth["model"] == {"effects": list(EFFECTS), "n_operators": 12, "reading": "swapped"}
    assert set(truth["effects"]) == set(EFFECTS)
    for name, params in truth["effects"].items():
        assert params == {**EFFECTS[name].off, **EFFECTS[name].get_test_parameters()}
    # The truth alone rebuilds the noise-free record; the rest is the noise of that seed.
    m = Model.from_dict(truth["model"])
    theta = m.theta_from_dict(truth["theta"])
    time, current = paper_current(fs=truth["fs"], reading=truth["input_reading"])
    np.testing.assert_array_equal(record.time, time)
    np.testing.assert_array_equal(record.current, current)
    clean = m(theta, time, current)
    rng = np.random.default_rng(truth["seed"])
    noise = sensor_noise(rng, time.size, truth["noise"]["sigma"], truth["noise"]["rho"])
    np.testing.assert_array_equal(record.displacement, clean + noise)
    # Written floats round-trip exactly, and the recorded effect size is the clean contribution.
    plain = gpi(TABLE1, current)
    np.testing.assert_allclose(truth["effect_size"]["rms_um"], np.sqrt(np.mean((clean - plain) ** 2)), rtol=1e-12)


def test_quiet_segment_has_exactly_zero_current(tmp_path):
    out = tmp_path / "q.csv"
    assert _run(["--out", str(out), "--input", "centred", "--fs", "200"]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "time,current,displacement"
    record = load_record(out)
    quiet = record.time < 10.0
    assert quiet.sum() == 2000
    assert np.all(record.current[quiet] == 0.0)
    assert all(line.split(",")[1] == "0" for line in lines[1:2001])
    assert record.current[~quiet].max() > 4.9 and record.sidecar["effects"] == {}


def test_noise_statistics():
    rng = np.random.default_rng(1)
    white = sensor_noise(rng, 200_000, 0.5)
    ar1 = sensor_noise(rng, 200_000, 0.5, rho=0.8)
    # Standard errors: std of a sample std ~ sigma / sqrt(2n) (white; ~3x larger for rho=0.8).
    assert abs(white.std() - 0.5) < 0.005
    assert abs(ar1.std() - 0.5) < 0.015

    def lag1(e):
        return np.corrcoef(e[:-1], e[1:])[0, 1]

    assert abs(lag1(white)) < 0.01 and abs(lag1(ar1) - 0.8) < 0.01
    with pytest.raises(ValueError, match="rho"):
        sensor_noise(rng, 10, 0.5, rho=1.0)
    with pytest.raises(ValueError, match="sigma"):
        sensor_noise(rng, 10, -1.0)


def test_spec_parsing():
    assert parse_effect_spec("") == {} and parse_effect_spec("none") == {} and parse_effect_spec(None) == {}
    chosen = parse_effect_spec("thermal, creep_amplitude=0.02")
    assert list(chosen) == ["creep", "thermal"]  # canonical order
    assert chosen["thermal"] == {**EFFECTS["thermal"].off, **EFFECTS["thermal"].get_test_parameters()}
    assert chosen["creep"]["creep_amplitude"] == 0.02
    assert chosen["creep"]["creep_tau"] == EFFECTS["creep"].get_test_parameters()["creep_tau"]
    assert parse_effect_spec({"lag": {"lag_tau": 0.2}}) == {"lag": {"lag_tau": 0.2, "lag_delay": 0.0}}


@pytest.mark.parametrize(
    "spec, message",
    [
        ("heat", "unknown effect or missing '=value'.*thermal \\(thermal_tau"),
        ("thermal_speed=3", "unknown parameter 'thermal_speed'.*sensor_drift"),
        ("creep_amplitude=2", "creep_amplitude=2.0 is outside its bounds \\[-0.5, 0.5\\]"),
        ("lag_tau=fast", "value of 'lag_tau' must be a number"),
        ("lag_tau=nan", "outside its bounds"),
        ("thermal,,lag", "item 2 is empty"),
        ("lag_tau=0.1,lag_tau=0.2", "'lag_tau' is given twice"),
    ],
)
def test_bad_spec_errors(spec, message):
    with pytest.raises(ValueError, match=message):
        parse_effect_spec(spec)


def test_bad_options_exit_2_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert _run(["--out", str(out), "--effects", "heat"]) == 2
    assert "simulate: error:" in capsys.readouterr().err
    assert _run(["--out", str(out), "--noise-rho", "1.5"]) == 2
    assert _run(["--out", str(tmp_path / "x.txt")]) == 2
    assert list(tmp_path.iterdir()) == []


def test_simulate_truth_matches_model():
    sim = simulate("sensor_drift_linear=4", noise_sigma=0.0, seed=0)
    s = sim.record.time / 70.0
    drift = EFFECTS["sensor_drift"].get_test_parameters()["sensor_drift_quadratic"]
    np.testing.assert_allclose(sim.record.displacement - sim.plain, 4.0 * s + drift * s**2, rtol=1e-9, atol=1e-12)
    assert sim.truth["noise"]["kind"] == "white" and sim.truth["effect_size"]["rms_over_noise_sigma"] is None
    assert sim.record.sidecar is sim.truth


@pytest.mark.parametrize("stem", ["bench_default", "bench_clean"])
def test_shipped_records_match_their_truth(stem):
    """data/*.csv equal what their sidecar's settings simulate now (to 1e-9 um: kernel rounding may change)."""
    path = Path(__file__).resolve().parent.parent / "data" / f"{stem}.csv"
    record = load_record(path)
    truth = record.sidecar
    assert truth["generator"] == "identify.bench.simulate"
    sim = simulate(
        truth["effects"],
        noise_sigma=truth["noise"]["sigma"],
        noise_rho=truth["noise"]["rho"],
        fs=truth["fs"],
        input_reading=truth["input_reading"],
        seed=truth["seed"],
    )
    np.testing.assert_array_equal(record.time, sim.record.time)
    np.testing.assert_array_equal(record.current, sim.record.current)
    np.testing.assert_allclose(record.displacement, sim.record.displacement, rtol=0, atol=1e-9)
    assert len(record) == 7001 and truth["noise"]["sigma"] == 0.5
    if stem == "bench_default":
        # One hidden effect: a few percent of full scale at most, several times the noise (RMS).
        assert len(truth["effects"]) == 1
        assert not any(name in path.name for name in EFFECTS)
        assert truth["effect_size"]["max_pct_of_full_scale"] <= 3.0
        assert truth["effect_size"]["rms_over_noise_sigma"] >= 3.0
    else:
        assert truth["effects"] == {}


def test_through_the_command_line(tmp_path, capsys):
    out = tmp_path / "cli.csv"
    assert cli.main(["simulate", "--out", str(out), "--effects", "sensor_drift", "--seed", "3"]) == 0
    assert "wrote" in capsys.readouterr().out
    record = load_record(out)
    assert record.sidecar["effects"] == {"sensor_drift": EFFECTS["sensor_drift"].get_test_parameters()}
    assert record.sidecar["command"].startswith("python -m identify simulate --out")
