"""Command-line conventions on real subprocesses (issue 18): --version."""

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from identify.bench import simulate
from identify.cli import main
from identify.data.records import write_record

ROOT = Path(__file__).resolve().parent.parent


def _env():
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + (os.pathsep + e["PYTHONPATH"] if e.get("PYTHONPATH") else "")
    return e


def test_version(tmp_path):
    import importlib.metadata as md

    done = subprocess.run(
        [sys.executable, "-m", "identify", "--version"],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"python -m identify {md.version('msma-gpi')}"


# -- verbosity, exit codes, progress (issue 18) ------------------------------------------------


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    """Table 1 transducer at 5 Hz (351 samples, noise 0.5 um)."""
    path = tmp_path_factory.mktemp("conventions") / "small.csv"
    write_record(path, simulate(fs=5.0, seed=4).record)
    return path


def _cli(*args, cwd, extra_env=None, timeout=600):
    env = _env()
    env.pop("IDENTIFY_DEBUG", None)
    env.update(extra_env or {})
    return subprocess.run(
        [sys.executable, "-m", "identify", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def test_quiet_and_verbose_on_a_subprocess(small_csv, tmp_path):
    """Default: progress and notes on stderr; -q: none of them (the table stays on stdout);
    -v: one line per least-squares start. The same table every time."""
    plain = _cli("fit", small_csv, "--n-starts", "2", cwd=tmp_path)
    quiet = _cli("fit", small_csv, "--n-starts", "2", "-q", cwd=tmp_path)
    verbose = _cli("fit", small_csv, "--n-starts", "2", "-v", cwd=tmp_path)

    def table(stdout):  # the last line ends with the fit's wall time
        return stdout.rsplit(";", 1)[0]

    for done in (plain, quiet, verbose):
        assert done.returncode == 0, done.stderr[-3000:]
        assert table(done.stdout) == table(plain.stdout) and "reduced chi-square" in done.stdout
    assert "fitting Model" in plain.stderr and "note: read the sidecar" in plain.stderr
    assert "  polish " not in plain.stderr
    assert quiet.stderr == ""
    assert "fitting Model" in verbose.stderr and "  screen " in verbose.stderr and "  polish " in verbose.stderr


def test_old_verbosity_flags_still_work(small_csv, tmp_path, capsys):
    """fit --verbose is -v; diagnose/predict/compensate --quiet is -q (same dest); study
    --progress and batch --no-progress still parse."""
    from identify.cli import build_parser

    parser = build_parser()
    assert parser.parse_args(["fit", "x.csv", "--verbose"]).verbose == 1
    for command in (["diagnose", "x.csv"], ["predict", "d", "x.csv"], ["compensate", "d", "--target", "x.csv"]):
        args = parser.parse_args([*command, "--quiet"])
        assert args.quiet == 1 and args.verbose == 0
    assert parser.parse_args(["study", "x.csv", "--out", str(tmp_path / "o"), "--progress", "off", "-qq"]).quiet == 2
    assert parser.parse_args(["batch", "c.toml", "--no-progress", "-q"]).no_progress
    assert main(["fit", str(small_csv), "--n-starts", "1", "--verbose"]) == 0
    assert "  polish " in capsys.readouterr().err


def test_study_not_converged_exits_1_and_says_so(small_csv, tmp_path):
    done = _cli(
        "study",
        small_csv,
        "--out",
        "run",
        "--max-steps",
        "40",
        "--check-every",
        "20",
        "--n-starts",
        "1",
        "--progress",
        "off",
        "--no-report",
        cwd=tmp_path,
    )
    assert done.returncode == 1, done.stderr[-3000:]
    assert "exit code 1: the chain did NOT CONVERGE" in done.stderr and "Traceback" not in done.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["posterior"]["converged"] is False  # the result is complete: a finding, not a failure
    again = _cli(
        "study",
        small_csv,
        "--out",
        "run",
        "--max-steps",
        "40",
        "--check-every",
        "20",
        "--n-starts",
        "1",
        "--progress",
        "off",
        "--no-report",
        cwd=tmp_path,
    )
    assert again.returncode == 1 and "already holds this study, finished (NOT converged" in again.stderr


def test_fit_whose_solver_did_not_converge_exits_1(small_csv, monkeypatch, capsys):
    import identify.fitting.lsq as lsq

    real = lsq.fit_least_squares

    def stopped_early(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), success=False, message="iteration limit reached")

    monkeypatch.setattr(lsq, "fit_least_squares", stopped_early)
    assert main(["fit", str(small_csv), "--n-starts", "1"]) == 1
    captured = capsys.readouterr()
    assert "solver: NOT converged: iteration limit reached" in captured.out
    assert "exit code 1: the least-squares solver did NOT converge" in captured.err


def test_progress_lines_outside_a_terminal(small_csv, tmp_path):
    """stderr is a pipe (as under nohup or in a batch log): the sampler writes a progress line
    every IDENTIFY_PROGRESS_SECONDS with step, speed and, after the first check, tau and the
    projected steps (50 tau) instead of the cap. The interval is tiny (5 ms) so that a line comes
    before the first check at step 200 even on a machine running 1000s of steps per second."""
    done = _cli(
        "study",
        small_csv,
        "--out",
        "run",
        "--max-steps",
        "600",
        "--check-every",
        "200",
        "--n-starts",
        "1",
        "--no-report",
        cwd=tmp_path,
        extra_env={"IDENTIFY_PROGRESS_SECONDS": "0.005"},
    )
    assert done.returncode == 1, done.stderr[-3000:]
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("emcee: step ")]
    assert len(lines) >= 3, done.stderr[-3000:]
    assert all("(cap 600)" in ln and "steps/s" in ln for ln in lines)
    assert "tau not estimated yet" in lines[0]
    estimated = [ln for ln in lines if "tau_max" in ln]
    assert estimated and all("steps needed (50 x tau" in ln for ln in estimated), lines
    steps = [int(ln.split()[2]) for ln in lines]
    assert steps == sorted(steps) and steps[-1] <= 600
    assert "\r" not in done.stderr  # no bar outside a terminal
    quiet = _cli(
        "study",
        small_csv,
        "--out",
        "run_q",
        "--max-steps",
        "200",
        "--check-every",
        "100",
        "--n-starts",
        "1",
        "--no-report",
        "-q",
        cwd=tmp_path,
        extra_env={"IDENTIFY_PROGRESS_SECONDS": "0.05"},
    )
    assert quiet.returncode == 1 and "emcee: step" not in quiet.stderr
    assert "NOT CONVERGE" in quiet.stderr  # the finding is a warning: -q keeps it
