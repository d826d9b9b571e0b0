"""Several records of one transducer through fit, study, report and the bad-input rules."""

from __future__ import annotations

import json
from dataclasses import replace

import h5py
import numpy as np
import pytest
import tomllib

from identify.bench import simulate
from identify.cli import main
from identify.data.records import write_record
from model import Model

#: The bench's transducer with a hidden heating (the bundled record's effect), 5 Hz: small and quick.
SPEC = "thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5"


@pytest.fixture(scope="module")
def two_files(tmp_path_factory):
    """The paper's drive and the drive with holds and a quiet end, one transducer, as CSV files."""
    folder = tmp_path_factory.mktemp("records")
    paths = []
    for name, drive, seed in (("paper.csv", "paper", 1), ("holds.csv", "holds", 2)):
        path = folder / name
        write_record(path, simulate(SPEC, seed=seed, fs=5.0, drive=drive).record)
        paths.append(path)
    return paths


def _chain(path):
    with h5py.File(path, "r") as f:
        return np.asarray(f["mcmc"]["chain"]), np.asarray(f["mcmc"]["log_prob"])


def test_a_list_of_one_record_is_the_study_of_that_record(two_files, tmp_path):
    """One record stays exactly what it is: the chain of study([rec]) equals study(rec)'s bit for bit."""
    from identify import load_record, study

    record = load_record(two_files[0])
    options = dict(seed=3, max_steps=60, check_every=30, n_starts=1, report=False, quiet=True)
    one = study(record, Model(), out=tmp_path / "one", **options)
    listed = study([record], Model(), out=tmp_path / "listed", **options)
    assert listed.record is record or listed.record.sha256 == record.sha256
    for a, b in zip(_chain(tmp_path / "one" / "chain.h5"), _chain(tmp_path / "listed" / "chain.h5")):
        np.testing.assert_array_equal(a, b)
    assert json.loads((tmp_path / "one" / "summary.json").read_text()).get("records") is None
    assert one.summary["parameters"] == listed.summary["parameters"]


def test_fit_of_several_records_writes_each_record_and_a_records_list(two_files, tmp_path, capsys):
    out = tmp_path / "fit"
    code = main(["fit", *map(str, two_files), "--effects", "thermal", "--n-starts", "1", "--out", str(out)])
    assert code in (0, 1)
    printed = capsys.readouterr().out
    assert "record 1" in printed and "record 2" in printed and "zero_r2" in printed
    content = json.loads((out / "fit.json").read_text())
    assert [r["source"] for r in content["records"]] == [str(p) for p in two_files]
    assert content["joint"]["n_records"] == 2 and "zero_r2" in content["joint"]["names"]
    assert (out / "data.npz").exists() and (out / "data_record2.npz").exists()
    manifest = json.loads((out / "manifest.json").read_text())
    assert [r["file"] for r in manifest["data"]["records"]] == [str(p) for p in two_files]


@pytest.mark.slow
def test_the_study_of_two_records(two_files, tmp_path):
    """summary.json lists the records and leave-one-record-out; posterior.nc has one variable per
    record that az.loo scores; the report is written; a rerun finds the study finished."""
    import arviz as az

    from identify import study

    out = tmp_path / "joint"
    result = study(
        list(map(str, two_files)),
        Model(["thermal"]),
        out=out,
        seed=0,
        n_starts=1,
        max_steps=400,
        check_every=100,
        quiet=True,
    )
    summary = json.loads((out / "summary.json").read_text())
    assert [r["file"] for r in summary["records"]] == [str(p) for p in two_files]
    for rec in summary["records"]:
        assert rec["samples"] > 0 and 0.3 < rec["noise_sigma"] < 0.8 and rec["rms"] < 1.2 * rec["noise_sigma"]
    assert [row["record"] for row in summary["leave_one_record_out"]] == [1, 2]
    for row in summary["leave_one_record_out"]:
        assert row["rms_sigma"] < 2.0 and 0.8 < row["inside_95"] <= 1.0
    names = [p["name"] for p in summary["parameters"]]
    assert names.count("thermal_tau") == 1 and "zero_r2" in names
    idata = az.from_netcdf(out / "posterior.nc")
    for r, path in enumerate(two_files, start=1):
        var = f"displacement_record{r}"
        assert idata.observed_data[var].size == len(np.loadtxt(path, delimiter=",", skiprows=1))
        loo = az.loo(idata, var_name=var)
        assert np.isfinite(loo.elpd_loo)
    assert (out / "report.html").exists() and (out / "record2_fit.png").exists()
    page = (out / "report.html").read_text()
    assert "Shared parameters" in page and "Leave one record out" in page
    again = study(
        list(map(str, two_files)),
        Model(["thermal"]),
        out=out,
        seed=0,
        n_starts=1,
        max_steps=400,
        check_every=100,
        quiet=True,
    )
    assert again.status == "finished before" and result.status in ("converged", "not converged")


def _no_quiet_start(path, tmp_path):
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    moving = data[np.flatnonzero(data[:, 1] != 0)[0] :]
    moving[:, 0] -= moving[0, 0]
    out = tmp_path / "no_quiet.csv"
    np.savetxt(out, moving, delimiter=",", header="time,current,displacement", comments="")
    return out


def _other_columns(path, tmp_path):
    out = tmp_path / "voltage.csv"
    text = path.read_text().splitlines()
    out.write_text("\n".join(["time,voltage,displacement", *text[1:]]) + "\n")
    return out


@pytest.mark.parametrize("command", ["study", "fit"])
@pytest.mark.parametrize("case", ["twice", "no quiet start", "other columns"])
def test_bad_records_are_one_line_naming_the_record_exit_2_nothing_written(two_files, tmp_path, capsys, command, case):
    first = two_files[0]
    other = {
        "twice": lambda: first,
        "no quiet start": lambda: _no_quiet_start(two_files[1], tmp_path),
        "other columns": lambda: _other_columns(two_files[1], tmp_path),
    }[case]()
    out = tmp_path / "out"
    assert main([command, str(first), str(other), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and str(other) in errors[0] and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


def test_records_in_other_units_an_empty_list_and_no_quiet_start_from_python(two_files, tmp_path):
    from identify import load_record, study
    from identify.data.records import RecordError
    from identify.fitting.noise import NoQuietSegmentError

    a, b = (load_record(p) for p in two_files)
    with pytest.raises(RecordError, match="empty"):
        study([], out=tmp_path / "empty")
    with pytest.raises(RecordError, match="mm.csv: drive in A and output in mm"):
        study([a, replace(b, output_unit="mm", source="mm.csv")], out=tmp_path / "units")
    with pytest.raises(NoQuietSegmentError, match="no_quiet.csv"):
        study([a, load_record(_no_quiet_start(two_files[1], tmp_path))], out=tmp_path / "quiet")
    for name in ("empty", "units", "quiet"):
        folder = tmp_path / name
        assert not folder.exists() or not any(folder.iterdir())


def test_reproduce_reruns_a_fit_of_several_records(two_files, tmp_path):
    from identify.workflows.reproduce import reproduce

    out = tmp_path / "fit"
    assert main(["fit", *map(str, two_files), "--n-starts", "1", "--out", str(out)]) in (0, 1)
    report = reproduce(out, tmp_path / "again")
    files = {a.file for a in report.arrays}
    assert "data_record2.npz" in files and report.n_numbers_compared > 0
    assert not report.numbers and all(a.identical for a in report.arrays)


def test_a_batch_job_of_several_records_runs_the_command_on_all(two_files, tmp_path):
    from identify.workflows.batch import BatchConfigError, expand_jobs, parse_config

    text = (
        'task = "study"\nout = "out"\n[[records]]\nname = "both"\n'
        f'paths = ["{two_files[0]}", "{two_files[1]}"]\n[[records]]\npath = "{two_files[0]}"\n'
    )
    config = parse_config(tomllib.loads(text), tmp_path / "batch.toml")
    jobs = expand_jobs(config)
    assert [j.record for j in jobs] == ["both", "paper"]
    assert list(jobs[0].argv[1:3]) == [str(two_files[0]), str(two_files[1])] and jobs[0].argv[3] == "--out"
    assert jobs[1].argv[2] == "--out"
    bad = text.replace('name = "both"\n', "")
    with pytest.raises(BatchConfigError, match="name is required"):
        parse_config(tomllib.loads(bad), tmp_path / "batch.toml")


def test_predict_validates_several_records_each_on_its_own(two_files, tmp_path, capsys):
    from identify import study
    from identify.workflows.use import predict

    out = tmp_path / "study"
    study(str(two_files[0]), Model(), out=out, seed=0, n_starts=1, max_steps=60, check_every=30, quiet=True)
    many = tmp_path / "many"
    code = main(["predict", str(out), *map(str, two_files), "--out", str(many), "--diagnosis", "adequacy"])
    assert code == 0
    for path in two_files:
        assert (many / f"predict-{path.stem}" / "prediction.json").exists()
    predictions = predict(out, list(map(str, two_files)), diagnosis="adequacy", n_draws=20)
    assert [p.record.source for p in predictions] == [str(p) for p in two_files]
    assert (
        main(["predict", str(out), str(two_files[0]), str(tmp_path / "missing.csv"), "--out", str(tmp_path / "x")]) == 2
    )
    assert "missing.csv" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_the_bundled_second_record_is_the_same_transducer_on_the_drive_with_holds():
    """data/bench_default_holds.csv equals what its sidecar's truth simulates on the drive with
    holds now (to 1e-9 um), and its truth is bench_default.json's transducer and noise."""
    from pathlib import Path

    from identify import load_record
    from identify.bench.synthetic import simulate_like

    data = Path(__file__).resolve().parent.parent / "data"
    holds, default = load_record(data / "bench_default_holds.csv"), load_record(data / "bench_default.csv")
    truth, first = holds.sidecar, default.sidecar
    assert {k: v for k, v in truth["theta"].items() if k in first["theta"]} == first["theta"]
    assert truth["noise"] == first["noise"] and truth["fs"] == pytest.approx(first["fs"], rel=1e-9)
    assert {k: v for k, v in truth["effects"]["thermal"].items() if k in first["effects"]["thermal"]} == (
        first["effects"]["thermal"]
    )
    assert truth["theta"]["thermal_sensitivity_core"] == 0.0  # the second node absent: the same one-pole heating
    assert "--truth data/bench_default.json --drive holds" in truth["command"]
    sim = simulate_like(first, holds.time, holds.current, seed=truth["seed"])
    np.testing.assert_allclose(holds.displacement, sim.record.displacement, rtol=0, atol=1e-9)
    quiet_end = holds.current[-int(5 * truth["fs"]) :]
    assert holds.current.max() >= 4.5 and not quiet_end.any() and not holds.current[: int(truth["fs"])].any()
