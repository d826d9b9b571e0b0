"""Batch runs: config validation, job expansion, markers/resume, summary, executors.

The end-to-end tests run the real ``fit`` command in subprocesses on tiny simulated
records (the paper's input at 8 Hz: 561 samples, Table 1 + white noise of known sigma),
with one least-squares start from Table 1, so each job takes a few seconds.
"""

from __future__ import annotations

import csv
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

import model
from identify import cli
from identify.data.fileio import toml_module
from identify.data.records import write_record
from identify.workflows import batch as B
from identify.workflows.batch_run import job_environment
from identify.workflows.batch_summary import assumptions_from_options, error_from_log, exit_is_finding

NOISE_SIGMA = 0.3  # um, the simulated sensor noise


def require_fit_command():
    if "fit" not in cli.COMMANDS:
        pytest.skip("the 'fit' command is not registered in identify.cli.COMMANDS yet")


@pytest.fixture
def fit_registered(monkeypatch):
    """Make 'fit' known to in-process config validation even before it is registered."""
    if "fit" not in cli.COMMANDS:
        monkeypatch.setitem(cli.COMMANDS, "fit", "identify.cli.fit")


def simulated_record(path: Path, seed: int, columns=("time", "current", "displacement")) -> Path:
    time_s, current = model.paper_current(fs=8.0)
    rng = np.random.default_rng(seed)
    y = model.Model()(model.TABLE1, time_s, current) + NOISE_SIGMA * rng.standard_normal(time_s.size)
    write_record(path, (time_s, current, y))
    if columns != ("time", "current", "displacement"):
        text = path.read_text().splitlines()
        text[0] = ",".join(columns)
        path.write_text("\n".join(text) + "\n")
    return path


def write_config(folder: Path, text: str) -> Path:
    path = folder / "batch.toml"
    path.write_text(text)
    return path


def read_summary(out: Path) -> dict:
    with open(out / "summary.csv", newline="") as fh:
        return {row["key"]: row for row in csv.DictReader(fh)}


# -- configuration -------------------------------------------------------------------------


def test_config_errors_name_the_key_and_file(tmp_path, fit_registered):
    simulated_record(tmp_path / "a.csv", 1)
    cases = [
        ('task = "fit"\nout = "o"\nrecords = [{path = "a.csv"}]\nwrokers = 2\n', "unknown key(s) wrokers"),
        ('task = "fitt"\nout = "o"\nrecords = [{path = "a.csv"}]\n', "task must be one of fit, diagnose, study"),
        ('task = "fit"\nrecords = [{path = "a.csv"}]\n', "out must be a folder path"),
        ('task = "fit"\nout = "o"\n', "records must be a non-empty array"),
        ('task = "fit"\nout = "o"\nrecords = [{path = "a.csv", glob = "*.csv"}]\n', "records[0] needs exactly one of"),
        (
            'task = "fit"\nout = "o"\nrecords = [{glob = "nothing*.csv"}]\n',
            "records[0].glob 'nothing*.csv' matches no file",
        ),
        ('task = "fit"\nout = "o"\nworkers = 0\nrecords = [{path = "a.csv"}]\n', "workers must be an integer >= 1"),
        ('task = "fit"\nout = "o"\nexecutor = "spark"\nrecords = [{path = "a.csv"}]\n', "executor must be one of"),
        ('task = "fit"\nout = "o"\nrecords = [{path = "a.csv"}, {path = "a.csv"}]\n', "two records are named 'a'"),
        (
            'task = "fit"\nout = "o"\nrecords = [{path = "a.csv"}]\nvariants = [{n_operators = 3}]\n',
            "variants[0].name is required",
        ),
        (
            'task = "fit"\nout = "o"\nrecords = [{path = "a.csv", out = "x"}]\n',
            "records[0].out: set by the batch itself",
        ),
        ('task = "fit"\nout = "o"\nrecords = [{path = "a.csv"}\n', "not valid TOML"),
    ]
    for text, expected in cases:
        path = write_config(tmp_path, text)
        with pytest.raises(B.BatchConfigError) as info:
            B.expand_jobs(B.load_config(path))
        message = str(info.value)
        assert str(path) in message, message
        assert expected in message, f"expected {expected!r} in {message!r}"


def test_unknown_or_mistyped_task_option_is_rejected_before_running(tmp_path, fit_registered):
    simulated_record(tmp_path / "a.csv", 1)
    for table, expected in (
        ("[options]\nn_startz = 2\n", "options.n_startz = 2: not accepted by 'python -m identify fit'"),
        ("[options]\nn_starts = 'many'\n", "options.n_starts = 'many'"),
        ("[[variants]]\nname = 'v'\nverbose = 3\n", "variants[v].verbose = 3"),
        ("[[variants]]\nname = 'v'\nreading = 'sideways'\n", "variants[v].reading = 'sideways'"),
    ):
        path = write_config(tmp_path, f'task = "fit"\nout = "o"\n[[records]]\npath = "a.csv"\n{table}')
        with pytest.raises(B.BatchConfigError, match=None) as info:
            B.expand_jobs(B.load_config(path))
        assert expected in str(info.value) and str(path) in str(info.value), str(info.value)
    assert not (tmp_path / "o").exists(), "nothing may run or be written for a bad config"


def test_jobs_are_records_times_variants_with_merged_options(tmp_path, fit_registered):
    simulated_record(tmp_path / "a.csv", 1)
    simulated_record(tmp_path / "b.csv", 2, columns=("t", "volts", "disp"))
    path = write_config(
        tmp_path,
        """
task = "fit"
out = "runs"
workers = 2
[options]
n_starts = 3
noise_sigma = 0.5
[[records]]
path = "a.csv"
[[records]]
path = "b.csv"
name = "piezo"
time_column = "t"
input_column = "volts"
output_column = "disp"
input_unit = "V"
noise_sigma = 0.2
[[variants]]
name = "plain"
[[variants]]
name = "lag-thermal"
effects = ["lag", "thermal"]
n_operators = 8
verbose = true
noise_sigma = "free"
""",
    )
    config = B.load_config(path)
    jobs = B.expand_jobs(config)
    assert [j.key for j in jobs] == ["a__plain", "a__lag-thermal", "piezo__plain", "piezo__lag-thermal"]
    assert config.out == (tmp_path / "runs").resolve()
    args = {j.key: list(j.argv) for j in jobs}

    def option(argv, flag):
        return argv[argv.index(flag) + 1] if flag in argv else None

    assert args["a__plain"][:2] == ["fit", str((tmp_path / "a.csv").resolve())]
    assert option(args["a__plain"], "--n-starts") == "3"
    assert option(args["a__plain"], "--noise-sigma") == "0.5"  # global
    assert option(args["piezo__plain"], "--noise-sigma") == "0.2"  # the record's overrides
    assert option(args["piezo__lag-thermal"], "--noise-sigma") == "free"  # the variant's overrides both
    assert option(args["piezo__plain"], "--input-column") == "volts"
    assert option(args["a__lag-thermal"], "--effects") == "lag,thermal"  # list -> comma-separated
    assert "--verbose" in args["a__lag-thermal"] and "--verbose" not in args["a__plain"]  # switch
    # every job writes into its own folder
    assert len({j.out_dir for j in jobs}) == 4 and all(Path(j.out_dir).parent == config.out for j in jobs)
    # the fingerprint depends on options and the record's bytes, not on the output folder
    assert len({j.fingerprint for j in jobs}) == 4
    (tmp_path / "a.csv").write_text((tmp_path / "a.csv").read_text().replace("\n0,", "\n0.0,", 1))
    changed = {j.key: j.fingerprint for j in B.expand_jobs(config)}
    assert changed["a__plain"] != jobs[0].fingerprint
    assert changed["piezo__plain"] == jobs[2].fingerprint
    # threads per job: the cores shared among the workers
    assert jobs[0].threads == max(1, (os.cpu_count() or 1) // 2)


def test_finished_result_requires_marker_with_same_fingerprint(tmp_path):
    job = B.Job("r__v", "fit", "r", "v", "r.csv", ("fit",), str(tmp_path / "r__v"), fingerprint="abc")
    assert B.finished_result(job) is None
    (tmp_path / "r__v").mkdir()
    result = B.JobResult("r__v", "fit", "r", "v", status="ok", rms=0.31, seconds=4.0)
    marker = tmp_path / "r__v" / B.DONE_MARKER
    marker.write_text(json.dumps({"fingerprint": "abc", "result": result.to_dict()}))
    again = B.finished_result(job)
    assert again is not None and again.status == "skipped" and again.rms == 0.31
    marker.write_text(json.dumps({"fingerprint": "other", "result": result.to_dict()}))
    assert B.finished_result(job) is None, "a changed job must be redone"
    marker.write_text('{"fingerprint": "abc", "resu')  # torn (cannot happen with atomic writes, but be safe)
    assert B.finished_result(job) is None


def test_error_line_is_taken_from_the_log():
    log = "fitting ...\nTraceback (most recent call last):\n  File x\nValueError: theta has a NaN\n"
    assert error_from_log(log, 1) == "ValueError: theta has a NaN"
    assert error_from_log("loading\nerror: a.csv, line 3: column 'current' is empty\n", 2).startswith(
        "error: a.csv, line 3"
    )
    assert error_from_log("", 9) == "exit code 9: (no output)"


def test_summary_files(tmp_path):
    results = [
        B.JobResult(
            "a__v",
            "fit",
            "a",
            "v",
            "ok",
            rms=0.301,
            max_error_pct=1.5,
            statistic_name="reduced_chi2",
            statistic=1.01,
            verdict="converged",
            seconds=3.2,
            output_unit="um",
            report="a__v/report.html",
        ),
        B.JobResult("b__v", "fit", "b", "v", "failed", seconds=0.4, error="error: b.csv, line 7: 'x' is not a number"),
    ]
    B.write_summary(tmp_path, results)
    rows = read_summary(tmp_path)
    assert rows["a__v"]["status"] == "ok" and float(rows["a__v"]["rms"]) == 0.301
    assert rows["b__v"]["status"] == "failed" and "line 7" in rows["b__v"]["error"] and rows["b__v"]["rms"] == ""
    md = (tmp_path / "summary.md").read_text()
    assert "[a__v](a__v/report.html)" in md and "0.301 um" in md and "2 runs: 1 ok, 1 failed." in md
    page = (tmp_path / "index.html").read_text()
    assert '<a href="a__v/report.html">a__v</a>' in page and 'class="failed"' in page
    assert "&#x27;x&#x27; is not a number" in page  # escaped
    assert not list(tmp_path.glob(".*.tmp")), "no temporary files left behind"


def test_executor_registry():
    assert {"local", "dask"} <= set(B.EXECUTORS)
    with pytest.raises(ValueError, match="unknown executor 'nope'; known: local, dask"):
        B.get_executor("nope", 1)


# -- end to end ------------------------------------------------------------------------------


def small_batch(tmp_path: Path, extra="", executor="local") -> Path:
    simulated_record(tmp_path / "good.csv", 11)
    bad = tmp_path / "bad.csv"
    simulated_record(bad, 12)
    lines = bad.read_text().splitlines()
    lines[6] = lines[6].split(",")[0] + ",not-a-number," + lines[6].split(",")[2]  # file line 7
    bad.write_text("\n".join(lines) + "\n")
    return write_config(
        tmp_path,
        f"""
task = "fit"
out = "runs"
workers = 2
executor = "{executor}"
{extra}
[options]
n_starts = 1
[[records]]
path = "good.csv"
[[records]]
path = "bad.csv"
""",
    )


def test_batch_runs_reports_failures_and_resumes(tmp_path):
    """A bad file fails in the table without stopping the good one; a rerun skips the good and redoes the bad."""
    require_fit_command()
    config = B.load_config(small_batch(tmp_path))
    result = B.run_batch(config, progress=False)
    by_key = {r.key: r for r in result.results}
    assert by_key["good__default"].status == "ok", by_key["good__default"].error
    assert by_key["bad__default"].status == "failed"
    assert "line 7" in by_key["bad__default"].error and "not-a-number" in by_key["bad__default"].error
    # the fit recovers the simulated noise level
    assert by_key["good__default"].rms == pytest.approx(NOISE_SIGMA, rel=0.15)
    assert by_key["good__default"].statistic_name == "reduced_chi2"
    # the noise sigma comes from 81 quiet samples (relative sd ~8 %), so chi2/dof ~ 1 within +-40 %
    assert 0.6 < by_key["good__default"].statistic < 1.6
    out = config.out
    assert (out / "good__default" / B.DONE_MARKER).is_file()
    assert (out / "bad__default" / B.FAILED_MARKER).is_file() and not (out / "bad__default" / B.DONE_MARKER).exists()
    rows = read_summary(out)
    assert set(rows) == {"good__default", "bad__default"}
    assert rows["bad__default"]["status"] == "failed"
    assert "bad__default/batch.log" in (out / "index.html").read_text()

    done_mtime = (out / "good__default" / B.DONE_MARKER).stat().st_mtime_ns
    # fix the bad file and rerun: the good run is skipped, the failed one redone
    simulated_record(tmp_path / "bad.csv", 12)
    again = B.run_batch(B.load_config(config.source), progress=False)
    by_key = {r.key: r for r in again.results}
    assert by_key["good__default"].status == "skipped"
    assert (out / "good__default" / B.DONE_MARKER).stat().st_mtime_ns == done_mtime
    assert by_key["bad__default"].status == "ok"
    assert not (out / "bad__default" / B.FAILED_MARKER).exists()
    rows = read_summary(out)
    assert rows["good__default"]["status"] == "skipped" and rows["bad__default"]["status"] == "ok"
    assert float(rows["good__default"]["rms"]) == pytest.approx(NOISE_SIGMA, rel=0.15)


def test_timeout_fails_only_that_job(tmp_path):
    require_fit_command()
    config = B.load_config(small_batch(tmp_path, extra="timeout = 0.05"))
    result = B.run_batch(config, progress=False)
    good = {r.key: r for r in result.results}["good__default"]
    assert good.status == "failed" and "timed out after 0.05 s" in good.error
    assert result.seconds < 60


def test_command_line_exit_codes(tmp_path, capsys):
    require_fit_command()
    path = small_batch(tmp_path)
    assert cli.main(["batch", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "2 job(s)" in out and "good__default: python -m identify fit" in out
    assert not (tmp_path / "runs").exists()
    bad = write_config(tmp_path, 'task = "fit"\nout = "o"\nrecords = [{path = "good.csv"}]\n[options]\nbogus = 1\n')
    assert cli.main(["batch", str(bad)]) == 2
    assert "options.bogus" in capsys.readouterr().err


def test_dask_executor(tmp_path):
    """The same batch on a dask.distributed LocalCluster (threads, one worker)."""
    require_fit_command()
    pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install '.[dask]')")
    config = B.load_config(small_batch(tmp_path, executor="dask", extra="[executor_options]\nprocesses = false\n"))
    config = B.BatchConfig(**{**config.__dict__, "workers": 1})
    started = time.perf_counter()
    result = B.run_batch(config, progress=False)
    by_key = {r.key: r for r in result.results}
    assert by_key["good__default"].status == "ok", by_key["good__default"].error
    assert by_key["good__default"].rms == pytest.approx(NOISE_SIGMA, rel=0.15)
    assert by_key["bad__default"].status == "failed" and "line 7" in by_key["bad__default"].error
    assert time.perf_counter() - started < 120


def test_assumptions_are_stated_from_the_options():
    notes = assumptions_from_options(["fit", "x.csv", "--time-column", "none", "--noise-sigma", "free"])
    assert any("time is the sample index" in n for n in notes)
    assert any("noise sigma is a free parameter" in n for n in notes)
    assert assumptions_from_options(["fit", "x.csv", "--noise-sigma", "0.07"]) == [
        "no quiet segment used: noise sigma = 0.07 given in the config"
    ]
    assert assumptions_from_options(["fit", "x.csv", "--time-column", "t"]) == []


EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.toml")), ids=lambda p: p.name)
def test_example_configs_are_valid(path):
    """Every shipped example config validates against the commands' real option parsers."""
    data = toml_module().loads(path.read_text())
    if data.get("task") not in cli.COMMANDS:
        pytest.skip(f"{path.name}: task {data.get('task')!r} is not registered yet")
    config = B.load_config(path)
    jobs = B.expand_jobs(config)
    assert len(jobs) == len(config.records) * len(config.variants) >= 2
    assert all(Path(j.record_path).is_file() for j in jobs), "example records must exist in the repository"


def test_priors_key_is_resolved_against_the_config(tmp_path):
    """A ``priors`` option names a file relative to the config; the study jobs get its absolute path."""
    simulated_record(tmp_path / "good.csv", 11)
    (tmp_path / "priors").mkdir()
    (tmp_path / "priors" / "c0.toml").write_text("[c0]\ndistribution = 'normal'\nmu = 1.5\nsigma = 0.2\n")
    text = 'task = "study"\nout = "runs"\n[options]\npriors = "priors/c0.toml"\n[[records]]\npath = "good.csv"\n'
    jobs = B.expand_jobs(B.load_config(write_config(tmp_path, text)))
    argv = jobs[0].argv
    assert argv[argv.index("--priors") + 1] == str((tmp_path / "priors" / "c0.toml").resolve())
    with pytest.raises(B.BatchConfigError, match=r"batch\.toml: options\.priors: no such priors file .*nowhere\.toml"):
        B.load_config(write_config(tmp_path, text.replace("priors/c0.toml", "nowhere.toml")))


def test_a_run_that_did_not_converge_makes_the_batch_exit_1(tmp_path, capsys):
    """A study job whose chain stops at its cap exits 1 (a finding): the batch reports it as
    finished but NOT converged (not as failed) and exits 1; an exit 1 with an error line is a failure."""
    simulated_record(tmp_path / "good.csv", 11)
    text = (
        'task = "study"\nout = "runs"\nworkers = 1\n[options]\nn_starts = 1\nmax_steps = 40\ncheck_every = 20\n'
        'no_report = true\n[[records]]\npath = "good.csv"\n'
    )
    assert cli.main(["batch", str(write_config(tmp_path, text)), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "NOT CONVERGED good__default: posterior NOT converged" in err
    row = read_summary(tmp_path / "runs")["good__default"]
    assert row["status"] == "ok" and row["verdict"] == "posterior NOT converged"
    assert "1 of the finished NOT converged" in (tmp_path / "runs" / "summary.md").read_text()
    assert exit_is_finding("step 40: ...\nexit code 1: the chain did NOT CONVERGE (raise --max-steps to extend it)\n")
    assert not exit_is_finding("exit code 1: the chain did NOT CONVERGE\nerror: unexpected OSError: disk full\n")


def test_a_job_imports_this_very_package():
    """A job's PYTHONPATH starts with the folder that holds the ``identify`` and ``model``
    packages (so a batch runs this checkout's code even where the package is not installed)."""
    import os

    first = Path(job_environment(1)["PYTHONPATH"].split(os.pathsep)[0])
    assert (first / "identify" / "__init__.py").is_file() and (first / "model" / "__init__.py").is_file()
