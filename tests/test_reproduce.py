"""Reproducing a run from its manifest: bit-identical rerun, what differs, refused changed data.

One short real study (a 561-sample simulated record, one least-squares start, a 40-step
chain) is run once per module with ``python -m identify study``; the reproduction test
reruns it through ``python -m identify reproduce``. The other tests work on copies of
that folder, so the fast set runs two short studies in all.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

import model
from identify import cli
from identify.data.records import write_record
from identify.workflows import reproduce as R

STUDY_OPTIONS = ["--max-steps", "40", "--check-every", "20", "--n-starts", "1", "--seed", "3", "--walkers", "40"]


@pytest.fixture(scope="module")
def study_run(tmp_path_factory):
    """A finished short study: (folder holding record + run, the run folder)."""
    if "study" not in cli.COMMANDS:
        pytest.skip("the 'study' command is not registered in identify.cli.COMMANDS yet")
    base = tmp_path_factory.mktemp("study")
    time_s, current = model.paper_current(fs=8.0)
    rng = np.random.default_rng(5)
    y = model.Model()(model.TABLE1, time_s, current) + 0.3 * rng.standard_normal(time_s.size)
    write_record(base / "rec.csv", (time_s, current, y))
    root = str(Path(__file__).resolve().parents[1])  # this work tree's code, wherever the package is installed from
    env = dict(
        os.environ, PYTHONPATH=root + (os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH") else "")
    )
    completed = subprocess.run(
        [sys.executable, "-m", "identify", "study", "rec.csv", "--out", "run", *STUDY_OPTIONS],
        cwd=base,
        capture_output=True,
        text=True,
        env=env,
    )
    assert completed.returncode == 1, completed.stderr[-2000:]  # 40 steps: NOT CONVERGED (a finding)
    return base, base / "run"


def copy_run(study_run, tmp_path) -> Path:
    """A copy of the record and the run in ``tmp_path`` (same relative layout)."""
    base, run = study_run
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    shutil.copytree(run, tmp_path / "run")
    return tmp_path / "run"


def test_reproduce_reruns_bit_identically(study_run, tmp_path, capsys):
    base, run = study_run
    out = tmp_path / "again"
    assert cli.main(["reproduce", str(run), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "IDENTICAL: chain.h5 bit-identical" in printed
    report = json.loads((out / R.REPORT_FILE).read_text())
    assert report["identical"] is True and report["chain_identical"] is True
    chain = [a for a in report["arrays"] if a["file"] == "chain.h5" and a["name"] == "mcmc/chain"]
    assert chain and chain[0]["identical"] and chain[0]["shape_original"][0] == 40
    assert report["numbers"] == [] and report["n_numbers_compared"] > 100
    # the rerun used the recorded relative data path from the folder it was found in
    assert report["command"][:2] == ["study", "rec.csv"] and "--seed" in report["command"]
    # and really ran: its own chain exists with the same content
    with h5py.File(run / "chain.h5") as a, h5py.File(out / "chain.h5") as b:
        np.testing.assert_array_equal(a["mcmc/chain"][()], b["mcmc/chain"][()])


def test_differences_are_named_with_their_size(study_run, tmp_path):
    run = copy_run(study_run, tmp_path)
    other = tmp_path / "other"
    shutil.copytree(run, other)
    with h5py.File(other / "chain.h5", "r+") as f:
        f["mcmc/chain"][5, 2, 1] += 1e-3  # the chain is stored in float32: a change it can hold
    summary = json.loads((other / "summary.json").read_text())
    summary["fit"]["rms"] += 0.25
    (other / "summary.json").write_text(json.dumps(summary))
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["versions"]["numpy"] = "0.0-test"
    (other / "manifest.json").write_text(json.dumps(manifest))

    arrays, n_numbers, numbers, versions, commit = R.compare_runs(run, other)
    chain = next(a for a in arrays if a.name == "mcmc/chain")
    assert not chain.identical and chain.n_different == 1
    assert chain.max_abs_difference == pytest.approx(1e-3, rel=1e-3)
    assert all(a.identical for a in arrays if a.name != "mcmc/chain")
    assert [(d.file, d.path) for d in numbers] == [("summary.json", "fit.rms")]
    assert numbers[0].abs_difference == pytest.approx(0.25)
    assert versions == {"numpy": [json.loads((run / "manifest.json").read_text())["versions"]["numpy"], "0.0-test"]}
    report = R.ReproductionReport(
        str(run), str(other), ["study"], "rec.csv", 0, arrays, numbers, n_numbers, versions, commit
    )
    assert not report.identical and report.chain_identical is False
    text = report.describe()
    assert "chain.h5:mcmc/chain: 1 element(s) differ, max |difference| 0.001" in text
    assert "summary.json:fit.rms" in text and "numpy" in text and "0.0-test" in text


def test_changed_data_is_refused_before_anything_runs(study_run, tmp_path):
    run = copy_run(study_run, tmp_path)
    record = tmp_path / "rec.csv"
    lines = record.read_text().splitlines()
    lines[100] = lines[100][:-1] + ("1" if lines[100][-1] != "1" else "2")
    record.write_text("\n".join(lines) + "\n")
    out = tmp_path / "again"
    with pytest.raises(
        R.DataChangedError, match="the data changed since the run: SHA-256 is [0-9a-f]{64}, the manifest records"
    ):
        R.reproduce(run, out)
    assert not out.exists()
    assert cli.main(["reproduce", str(run), "--out", str(out)]) == 2
    record.unlink()
    with pytest.raises(R.DataChangedError, match="rec.csv is missing"):
        R.locate_data(R.read_manifest(run), run)


def test_moved_data_can_be_given_explicitly(study_run, tmp_path):
    run = copy_run(study_run, tmp_path)
    moved = tmp_path / "elsewhere.csv"
    (tmp_path / "rec.csv").rename(moved)
    location = R.locate_data(R.read_manifest(run), run, data=moved)
    assert location.path == moved.resolve() and location.argument == str(moved.resolve())


def test_manifest_problems_are_clear(tmp_path, study_run):
    with pytest.raises(R.ManifestError, match="no such results folder"):
        R.read_manifest(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(R.ManifestError, match="manifest.json: missing"):
        R.read_manifest(tmp_path / "empty")
    run = copy_run(study_run, tmp_path)
    manifest = json.loads((run / "manifest.json").read_text())
    del manifest["data"]["sha256"]
    (run / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(R.ManifestError, match="needs data.file and data.sha256"):
        R.read_manifest(run)


def test_rerun_arguments_restore_every_setting(study_run):
    """The rebuilt command line parses back to exactly the recorded settings."""
    import argparse
    import importlib

    _, run = study_run
    manifest = R.read_manifest(run)
    args = R.rerun_arguments(manifest, "rec.csv", "/tmp/x")
    assert args[0] == "study"
    parser = argparse.ArgumentParser()
    importlib.import_module(cli.COMMANDS["study"]).add_arguments(parser)
    parsed = vars(parser.parse_args(args[1:]))
    for key, value in manifest["settings"].items():
        assert parsed[key] == value, key
    assert parsed["out"] == "/tmp/x" and parsed["seed"] == manifest["seed"] == 3
    # without a command line in the manifest, the command is recognised from the settings
    del manifest["command"]
    assert R.rerun_arguments(manifest, "rec.csv", "/tmp/x")[0] == "study"


def test_compare_arrays_is_bitwise():
    a = np.array([0.0, np.nan, 1.5])
    assert R.compare_arrays("f", "x", a, a.copy()).identical  # NaN in the same place
    b = np.array([-0.0, np.nan, 1.5])
    signed = R.compare_arrays("f", "x", a, b)
    assert not signed.identical and signed.max_abs_difference == 0.0  # equal values, different bits
    shape = R.compare_arrays("f", "x", a, a[:2])
    assert not shape.identical and "shape (3,) -> (2,)" in shape.describe()
    missing = R.compare_arrays("f", "x", a, None)
    assert "missing in the rerun" in missing.describe()
    text = R.compare_arrays("f", "source", np.array("a.csv"), np.array("b.csv"))
    assert not text.identical and not text.numeric and "'a.csv' -> 'b.csv'" in text.describe()


def test_timing_keys_are_not_compared():
    a = {"fit": {"rms": 0.3, "seconds": 1.0}, "runs": [{"started": "x"}]}
    b = {"fit": {"rms": 0.3, "seconds": 9.0}, "runs": [{"started": "y"}, {"started": "z"}]}
    n, diffs = R.compare_json("s.json", a, b)
    assert n == 1 and diffs == []
    n, diffs = R.compare_json("s.json", a, {"fit": {"rms": 0.31}})
    assert [d.path for d in diffs] == ["fit.rms"] and diffs[0].abs_difference == pytest.approx(0.01)


def test_batch_thread_count_is_read_for_the_rerun(tmp_path):
    """A run made by a batch is rerun with the batch's thread count (BLAS sums depend on it)."""
    assert R.recorded_threads(tmp_path) is None
    (tmp_path / "batch_job.json").write_text(json.dumps({"key": "r__v", "threads": 1}))
    assert R.recorded_threads(tmp_path) == 1
    (tmp_path / "batch_job.json").write_text(json.dumps({"threads": "many"}))
    assert R.recorded_threads(tmp_path) is None
