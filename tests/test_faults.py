"""Faults a hostile, realistic user causes (issues 15 and 64), reproduced with real subprocesses.

Every case asserts what the user sees and what is left on disk: no traceback, the right
exit code (docs/reliability.md), one ``error:`` line naming the option, the line or the
file, results equal to an uninterrupted run's (chains bit for bit, every result value
but wall times), no process left behind (checked by PID), nothing corrupted, nothing
outside the folder changed (checksums before and after).

Issue 64's round: a real full disk (a 1-5 MB tmpfs the test mounts; skipped, saying why,
where it cannot), links planted in a results folder, options and manifests that name
paths outside it, markup in units and messages, a second batch configuration.

Records are the paper's input at 5 Hz (351 samples) and chains are short, so the fast
part runs in a few minutes on two cores; the whole-batch equality is ``slow``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from identify.bench import simulate
from identify.data.records import write_record
from identify.workflows.reproduce import TIMING_KEYS

ROOT = Path(__file__).resolve().parents[1]
#: Short studies: 1 least-squares start, no report.
STUDY = ["--n-starts", "1", "--progress", "off", "--no-report"]
#: Result values that are not expected to survive an interruption (being removed from
#: the summary by another change: it counts only the last process's proposals).
NOT_RESUMABLE = {"outside_domain_fraction"}
#: Exit code of a study whose chain stopped at its cap, NOT CONVERGED (a finding to look at).
NOT_CONVERGED = 1


def verdict_code(folder: Path) -> int:
    """The exit code a finished study in ``folder`` must end with: 0 when summary.json says
    its chain converged, 1 (NOT CONVERGED) otherwise."""
    converged = json.loads((Path(folder) / "summary.json").read_text())["posterior"]["converged"]
    assert isinstance(converged, bool)
    return 0 if converged else NOT_CONVERGED


# -- helpers ---------------------------------------------------------------------------------


def env() -> dict:
    """The environment of a subprocess that runs this work tree's code."""
    e = dict(os.environ, PYTHONUNBUFFERED="1")
    e["PYTHONPATH"] = str(ROOT) + (os.pathsep + e["PYTHONPATH"] if e.get("PYTHONPATH") else "")
    e.pop("IDENTIFY_DEBUG", None)
    return e


def cli(*args, cwd, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "identify", *map(str, args)],
        cwd=cwd,
        env=env(),
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def start(*args, cwd) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "identify", *map(str, args)],
        cwd=cwd,
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        stdin=subprocess.DEVNULL,
        preexec_fn=lambda: signal.signal(
            signal.SIGINT, signal.SIG_DFL
        ),  # Ctrl-C even when pytest runs in the background
    )


def one_error(completed, *needles, code=2) -> str:
    """The single ``error:`` line of a failed command (no traceback), checked for ``needles``."""
    err = completed.stderr
    assert completed.returncode == code, (completed.returncode, err[-3000:])
    assert "Traceback" not in err and "Traceback" not in completed.stdout, err[-3000:]
    # "error: ..." (simulate and paper keep their own prefixes: "simulate: error: ...", "paper: ...")
    errors = [line for line in err.splitlines() if line.startswith(("error:", "simulate: error:", "paper: "))]
    assert len(errors) == 1, err
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
    return errors[0]


def digests(folder: Path) -> dict:
    """SHA-256 of every file under ``folder`` (relative path -> digest)."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def chain_arrays(folder: Path) -> dict:
    with h5py.File(folder / "chain.h5", "r") as f:
        g = f["mcmc"]
        arrays = {name: g[name][()] for name in ("chain", "log_prob", "accepted")}
        arrays["iteration"] = int(g.attrs["iteration"])
        arrays["random_state"] = [np.asarray(g.attrs[f"random_state_{i}"]) for i in range(5)]
    n = arrays["iteration"]
    arrays["chain"], arrays["log_prob"] = arrays["chain"][:n], arrays["log_prob"][:n]
    return arrays


def assert_same_chain(a: Path, b: Path) -> None:
    x, y = chain_arrays(a), chain_arrays(b)
    assert x["iteration"] == y["iteration"]
    for name in ("chain", "log_prob", "accepted"):
        assert x[name].tobytes() == y[name].tobytes(), name
    for u, v in zip(x["random_state"], y["random_state"]):
        assert np.array_equal(u, v)


def values(document, path=""):
    """Every leaf of a JSON document except wall times and :data:`NOT_RESUMABLE`."""
    if isinstance(document, dict):
        out = {}
        for k, v in document.items():
            if k not in TIMING_KEYS and k not in NOT_RESUMABLE:
                out.update(values(v, f"{path}.{k}"))
        return out
    if isinstance(document, list):
        out = {}
        for i, v in enumerate(document):
            out.update(values(v, f"{path}[{i}]"))
        return out
    return {path: document}


def assert_same_results(a: Path, b: Path) -> None:
    """Same chain bit for bit, same data, and every value of fit.json and summary.json equal."""
    assert_same_chain(a, b)
    with np.load(a / "data.npz") as x, np.load(b / "data.npz") as y:
        for name in ("time", "current", "displacement"):
            assert x[name].tobytes() == y[name].tobytes()
    for name in ("fit.json", "summary.json"):
        va = values(json.loads((a / name).read_text()))
        vb = values(json.loads((b / name).read_text()))
        assert va == vb, {k: (va.get(k), vb.get(k)) for k in set(va) | set(vb) if va.get(k) != vb.get(k)}


def descendants(pid: int) -> dict[int, str]:
    """Processes below ``pid`` (PID -> command line), from /proc."""
    parents, commands = {}, {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            commands[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    found, frontier = {}, [pid]
    while frontier:
        p = frontier.pop()
        for child, parent in parents.items():
            if parent == p and child not in found:
                found[child] = commands.get(child, "")
                frontier.append(child)
    return found


def alive(pid: int, command: str) -> bool:
    """The process still exists (and is the same program: guards against PID reuse), not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z" and cmdline == command


def steps(folder: Path) -> int:
    """Steps in ``folder/chain.h5`` (0 when absent or being written)."""
    try:
        with h5py.File(folder / "chain.h5", "r") as f:
            return int(f["mcmc"].attrs["iteration"])
    except Exception:
        return 0


def wait_for(condition, proc, what, timeout=300.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, f"ended before {what}: {proc.communicate()}"
        assert time.monotonic() < deadline, f"no {what} within {timeout} s"
        time.sleep(0.05)


def record_csv(path: Path, seed: int = 4, quiet=True) -> Path:
    record = simulate(fs=5.0, seed=seed).record
    if not quiet:
        keep = record.time >= 12.0
        write_record(path, (record.time[keep] - 12.0, record.current[keep], record.displacement[keep]))
    else:
        write_record(path, record)
    return path


def replace_cell(path: Path, line: int, column: int, text: str) -> None:
    """Set the cell at 1-based ``line`` and ``column`` of a CSV file."""
    lines = path.read_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[column - 1] = text
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


# -- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("faults")
    record_csv(folder / "rec.csv")
    (folder / "rec.json").unlink(missing_ok=True)
    return folder


FINISHED = ["--seed", "2", "--max-steps", "300", "--check-every", "100", *STUDY]


@pytest.fixture(scope="module")
def finished(base) -> Path:
    """A finished 300-step study of rec.csv (not converged, at its cap)."""
    completed = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=base)
    assert completed.returncode == NOT_CONVERGED, completed.stderr[-3000:]
    assert "exit code 1: the chain did NOT CONVERGE" in completed.stderr
    return base / "finished"


def copy_of(finished: Path, tmp_path: Path) -> Path:
    """A copy of the finished run and its record, same relative layout."""
    shutil.copy2(finished.parent / "rec.csv", tmp_path / "rec.csv")
    shutil.copytree(finished, tmp_path / "finished")
    return tmp_path / "finished"


RESUMABLE = ["--seed", "3", "--max-steps", "1500", "--check-every", "500", *STUDY]


@pytest.fixture(scope="module")
def uninterrupted(base) -> Path:
    completed = cli("study", "rec.csv", "--out", "whole", *RESUMABLE, cwd=base)
    assert completed.returncode == verdict_code(base / "whole"), completed.stderr[-3000:]
    return base / "whole"


# -- 1. two writers on one folder -----------------------------------------------------------------


def test_two_studies_on_one_folder_one_runs_the_other_refuses_at_once(base, tmp_path, uninterrupted):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    first = start("study", "rec.csv", "--out", "run", *RESUMABLE, cwd=tmp_path)
    wait_for(lambda: steps(tmp_path / "run") >= 20, first, "the first study's steps")
    # the first is held (alive, holding its lock) while the second runs: a loaded machine can
    # start the second more slowly than the first finishes its steps. A second command that
    # waited for the lock would wait for the held first one forever: the timeout fails the test.
    first.send_signal(signal.SIGSTOP)
    try:
        second = cli("study", "rec.csv", "--out", "run", *RESUMABLE, cwd=tmp_path, timeout=120)
    finally:
        first.send_signal(signal.SIGCONT)
    one_error(second, "is in use by process", str(first.pid))
    out, err = first.communicate(timeout=600)
    assert first.returncode == verdict_code(tmp_path / "run") and "Traceback" not in err, err[-3000:]
    # the one that ran is exactly the run made alone
    assert_same_results(tmp_path / "run", uninterrupted)
    assert not (tmp_path / "run" / ".identify.lock").exists(), "the lock is released"


def test_a_stale_lock_of_a_dead_process_is_taken_over(base, tmp_path):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / ".identify.lock").write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename}))
    completed = cli("fit", "rec.csv", "--n-starts", "1", "--out", "out", cwd=tmp_path)
    assert completed.returncode == 0, completed.stderr[-3000:]
    assert f"took over the lock of process {dead.pid}" in completed.stderr
    assert (tmp_path / "out" / "fit.json").is_file() and not (tmp_path / "out" / ".identify.lock").exists()


# -- 3. resumed and finished runs ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "signum", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)], ids=["SIGTERM", "SIGINT"]
)
def test_an_interrupted_study_resumes_to_every_figure_of_the_uninterrupted_one(signum, base, tmp_path, uninterrupted):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    proc = start("study", "rec.csv", "--out", "run", *RESUMABLE, cwd=tmp_path)
    wait_for(lambda: steps(tmp_path / "run") >= 200, proc, "200 steps")
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, (proc.returncode, err[-3000:])
    assert "interrupted; completed work is kept" in err
    kept = steps(tmp_path / "run")
    assert 200 <= kept < 1500
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["runs"][-1]["status"] == "interrupted"
    again = cli("study", "rec.csv", "--out", "run", *RESUMABLE, cwd=tmp_path)
    assert again.returncode == verdict_code(uninterrupted) and "resuming" in again.stderr, again.stderr[-3000:]
    assert_same_results(tmp_path / "run", uninterrupted)


def test_a_finished_study_rerun_leaves_every_byte_unchanged(finished, tmp_path):
    run = copy_of(finished, tmp_path)
    before = digests(run)
    completed = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=tmp_path)
    assert completed.returncode == NOT_CONVERGED, completed.stderr[-3000:]  # still the finding it was
    assert "already holds this study, finished" in completed.stderr
    assert digests(run) == before


def test_a_finished_fit_rerun_leaves_every_byte_unchanged(base, tmp_path):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    first = cli("fit", "rec.csv", "--n-starts", "1", "--out", "out", cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    before = digests(tmp_path / "out")
    again = cli("fit", "rec.csv", "--n-starts", "1", "--out", "out", cwd=tmp_path)
    assert again.returncode == 0 and "already holds this fit" in again.stderr, again.stderr[-3000:]
    assert again.stdout == first.stdout  # the same table
    assert digests(tmp_path / "out") == before


def test_extending_a_finished_chain_never_damages_it_even_under_kill_9(finished, tmp_path):
    """A raised --max-steps extends a copy of the finished chain: killed with SIGKILL while
    it writes, the finished result stays byte for byte; interrupted with SIGTERM, the
    completed steps replace it and the next run resumes from them."""
    run = copy_of(finished, tmp_path)
    before = digests(run)
    longer = list(FINISHED)
    longer[longer.index("--max-steps") + 1] = "3000"
    proc = start("study", "rec.csv", "--out", "finished", *longer, cwd=tmp_path)
    wait_for(lambda: _extending_steps(run) > 400, proc, "steps of the extension")
    proc.kill()
    proc.communicate(timeout=60)
    assert {k: v for k, v in digests(run).items() if not k.startswith(".")} == before
    again = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=tmp_path)
    assert again.returncode == NOT_CONVERGED and "already holds this study, finished" in again.stderr, again.stderr[
        -3000:
    ]
    assert digests(run) == before and not (run / ".chain.h5.extending").exists()
    proc = start("study", "rec.csv", "--out", "finished", *longer, cwd=tmp_path)
    wait_for(lambda: _extending_steps(run) > 400, proc, "steps of the extension")
    proc.terminate()
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    assert steps(run) > 400 and not (run / ".chain.h5.extending").exists()


def _extending_steps(run: Path) -> int:
    try:
        with h5py.File(run / ".chain.h5.extending", "r") as f:
            return int(f["mcmc"].attrs["iteration"])
    except Exception:
        return 0


# -- 4. changed settings, reproduce into an existing study ---------------------------------------------


@pytest.mark.parametrize(
    "change, needle",
    [
        (["--max-steps", "100"], "max_steps: 300 -> 100, but its chain already holds 300 steps"),
        (["--check-every", "50"], "check_every: 100 -> 50"),
        (["--seed", "9"], "seed 2 -> 9"),
    ],
    ids=["lower max-steps", "check-every", "seed"],
)
def test_a_changed_setting_is_refused_before_anything_is_touched(finished, tmp_path, change, needle):
    run = copy_of(finished, tmp_path)
    before = digests(run)
    options = list(FINISHED)
    for flag, value in zip(change[::2], change[1::2]):
        options[options.index(flag) + 1] = value
    completed = cli("study", "rec.csv", "--out", "finished", *options, cwd=tmp_path)
    one_error(completed, "holds a run with different data or settings", needle, "--force")
    assert digests(run) == before


def test_reproduce_never_writes_into_an_existing_study(finished, tmp_path):
    run = copy_of(finished, tmp_path)
    other = tmp_path / "other"
    shutil.copytree(run, other)
    before = digests(other)
    completed = cli("reproduce", "finished", "--out", "other", cwd=tmp_path)
    one_error(completed, "holds a study", "never into an existing one")
    assert digests(other) == before and digests(run) == digests(finished)


# -- 5. damaged files -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, needles",
    [
        ("chain.h5", ["chain.h5 is damaged", "delete", "--force"]),
        ("fit.json", ["fit.json is damaged", "delete it", "--force"]),
        ("manifest.json", ["manifest.json is damaged", "--force"]),
    ],
)
def test_a_damaged_file_is_one_error_and_damages_nothing_else(finished, tmp_path, name, needles):
    run = copy_of(finished, tmp_path)
    path = run / name
    os.truncate(path, path.stat().st_size // 2)
    before = digests(run)
    completed = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=tmp_path)
    one_error(completed, *needles)
    assert digests(run) == before  # summary.json (and everything else) untouched
    for command in (["report", "finished"], ["reproduce", "finished", "--out", "again"]):
        completed = cli(*command, cwd=tmp_path)
        assert completed.returncode == 2 and "Traceback" not in completed.stderr, completed.stderr[-3000:]
        assert digests(run) == before
    assert not (tmp_path / "again").exists()
    if name == "chain.h5":  # following the advice: the chain is recomputed, equal to the original
        path.unlink()
        completed = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=tmp_path)
        assert completed.returncode == NOT_CONVERGED, completed.stderr[-3000:]
        assert "least squares: reusing" in completed.stderr
        assert_same_results(run, finished)


# -- bad input ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "column, value, name",
    [
        (3, "1e308", "displacement"),
        (3, "-1e200", "displacement"),
        (2, "1e308", "current"),
        (3, "1e154", "displacement"),
    ],
    ids=["displacement 1e308", "displacement -1e200", "current 1e308", "spike 1e154"],
)
def test_a_value_beyond_any_physical_range_is_an_error_with_line_and_column(base, tmp_path, column, value, name):
    path = tmp_path / "bad.csv"
    shutil.copy2(base / "rec.csv", path)
    replace_cell(path, 120, column, value)
    for command in (["fit", path.name], ["study", path.name, "--out", "run", *FINISHED]):
        completed = cli(*command, cwd=tmp_path)
        one_error(completed, "bad.csv, line 120", f"column {name!r} (column {column})", "beyond any physical range")
        assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "command, needle",
    [
        (["fit", "rec.csv", "--n-operators", "0"], "argument --n-operators"),
        (["study", "rec.csv", "--out", "run", "--seed", "-1"], "argument --seed"),
        (["study", "rec.csv", "--out", "afile"], "argument --out: afile exists and is not a folder"),
        (["fit", "rec.csv", "--out", "afile"], "argument --out: afile exists and is not a folder"),
        (["fit", "rec.csv", "--json", "adir"], "argument --json: adir is a folder"),
        (["study", "rec.csv", "--out", "run", "--max-steps", "0"], "argument --max-steps"),
        (["study", "rec.csv", "--out", "run", "--max-steps", "-5"], "argument --max-steps"),
        (["study", "rec.csv", "--out", "run", "--check-every", "0"], "argument --check-every"),
        (["study", "rec.csv", "--out", "run", "--walkers", "3"], "--walkers 3: needs an even number >= 36"),
        (["study", "rec.csv", "--out", "run", "--walkers", "37"], "--walkers 37: needs an even number >= 36"),
        (["study", "rec.csv", "--out", "run", "--walkers", "0"], "argument --walkers"),
        (["fit", "rec.csv", "--noise-sigma", "-0.5"], "argument --noise-sigma"),
        (["fit", "rec.csv", "--n-starts", "0"], "argument --n-starts"),
        (["fit", "rec.csv", "--every", "0"], "argument --every"),
        (["fit", "rec.csv", "--input-column", "time"], "--time-column and --input-column both name the column 'time'"),
        (["study", "rec.csv", "--out", "run", "--effects", "warp"], "unknown effect(s) 'warp'"),
        (["report", "nowhere"], "argument DIR: nowhere: no such folder"),
        (["report", "adir", "--draws", "1"], "argument --draws"),
        (["simulate", "--out", "x.csv", "--noise-rho", "1"], "noise rho must lie strictly between -1 and 1"),
        (["simulate", "--out", "x.csv", "--noise", "-1"], "noise sigma must be a finite number >= 0"),
        (["simulate", "--out", "x.csv", "--seed", "-1"], "argument --seed"),
        (["paper", "--out", "figs", "--fs", "0"], "fs must be a positive sampling rate"),
        (["paper", "--out", "afile"], "argument --out: afile exists and is not a folder"),
        (["batch", "nothing.toml", "--workers", "0"], "argument --workers"),
        (["fit", "rec.csv", "--jso", "x.json"], "unrecognized arguments: --jso x.json"),
        (["study", "rec.csv", "--ou", "run"], "the following arguments are required: --out"),
        (["batch", "nothing.toml", "--work", "1"], "unrecognized arguments: --work 1"),
        (["reproduce", "adir", "--ou", "x"], "unrecognized arguments: --ou x"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else None,
)
def test_every_option_is_checked_up_front_in_one_line(base, tmp_path, command, needle):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    (tmp_path / "afile").write_text("precious\n")
    (tmp_path / "adir").mkdir()
    before = digests(tmp_path)
    completed = cli(*command, cwd=tmp_path)
    one_error(completed, needle)
    assert digests(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile", "rec.csv"]


def test_a_failed_study_leaves_nothing_that_blocks_the_corrected_one(base, tmp_path):
    record_csv(tmp_path / "busy.csv", quiet=False)  # no unenergised start: no noise estimate
    completed = cli("study", "busy.csv", "--out", "run", *FINISHED, cwd=tmp_path)
    one_error(completed, "--noise-sigma VALUE", "--noise-sigma free")
    assert not (tmp_path / "run").exists()
    (tmp_path / "run").mkdir()  # an existing empty folder is kept empty
    completed = cli("study", "busy.csv", "--out", "run", *FINISHED, cwd=tmp_path)
    one_error(completed, "--noise-sigma VALUE")
    assert list((tmp_path / "run").iterdir()) == []
    completed = cli("study", "busy.csv", "--out", "run", "--noise-sigma", "0.5", *FINISHED, cwd=tmp_path)
    assert completed.returncode == NOT_CONVERGED, completed.stderr[-3000:]
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["posterior"]["n_steps"] == 300


def test_exit_codes_are_documented_in_the_help(tmp_path):
    for command in ([], ["study"], ["batch"]):
        completed = cli(*command, "--help", cwd=tmp_path)
        assert completed.returncode == 0
        for code in ("0 ", "1 ", "2 ", "130 "):
            assert f"  {code}" in completed.stdout.split("exit codes:")[1], completed.stdout


def test_an_unexpected_failure_is_one_line_with_exit_code_1(monkeypatch, capsys):
    from identify import cli
    from identify.cli import report as cmd_report

    def broken(args):
        raise RuntimeError("something nobody expected")

    monkeypatch.setattr(cmd_report, "run", broken)
    monkeypatch.delenv("IDENTIFY_DEBUG", raising=False)
    assert cli.main(["report", "."]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        "error: unexpected RuntimeError: something nobody expected (rerun with IDENTIFY_DEBUG=1 for the traceback)"
    ]
    monkeypatch.setenv("IDENTIFY_DEBUG", "1")
    with pytest.raises(RuntimeError):
        cli.main(["report", "."])


def test_folder_lock_semantics(tmp_path):
    """In one process too: a second lock on a held folder is refused naming this PID; the
    lock file goes with the release; a folder the lock created and left empty goes too;
    a child given the lock's environment and descriptor holds it as well."""
    from identify.data.locks import FolderBusyError, FolderLock, lock_holder

    folder = tmp_path / "new"
    lock = FolderLock(folder, command="test").acquire()
    assert lock_holder(folder)["pid"] == os.getpid()
    with pytest.raises(FolderBusyError, match=f"in use by process {os.getpid()} running 'test'"):
        FolderLock(folder).acquire()
    child_env, fds = lock.child_environment(env())
    probe = (
        "from identify.data.locks import FolderLock, FolderBusyError\n"
        "import sys\n"
        "lock = FolderLock(sys.argv[1]).acquire(); print('inherited', lock.inherited)\n"
    )
    inherited = subprocess.run(
        [sys.executable, "-c", probe, str(folder)], env=child_env, pass_fds=fds, capture_output=True, text=True
    )
    assert inherited.stdout.strip() == "inherited True", inherited.stderr
    stranger = subprocess.run([sys.executable, "-c", probe, str(folder)], env=env(), capture_output=True, text=True)
    assert stranger.returncode != 0 and "FolderBusyError" in stranger.stderr
    lock.release()
    assert not folder.exists()
    (tmp_path / "kept").mkdir()
    with FolderLock(tmp_path / "kept"):
        pass
    assert (tmp_path / "kept").is_dir() and not list((tmp_path / "kept").iterdir())


# -- long records ------------------------------------------------------------------------------------------------


def test_a_long_record_loads_in_memory_proportional_to_it_with_progress_and_an_every_hint(tmp_path):
    """400,000 samples (21 MB of CSV): loading raises the resident set by < 100 bytes per
    sample (the three float columns are 24; the loader before this change took ~460), the
    command prints progress while loading and suggests --every."""
    n = 400_000
    t = np.arange(n) / 5000.0  # 5 kHz, a 1 Hz drive after a 2 s quiet start
    current = np.where(t < 2.0, 0.0, 2.5 - 2.5 * np.cos(2 * np.pi * (t - 2.0)))
    rng = np.random.default_rng(0)
    displacement = 50.0 * current + rng.normal(0.0, 0.1, n)
    write_record(tmp_path / "long.csv", (t, current, displacement))
    assert (tmp_path / "long.csv").stat().st_size > 20 * 2**20
    probe = (
        "import sys\n"
        "def status(key):\n"
        "    return next(int(l.split()[1]) * 1024 for l in open('/proc/self/status') if l.startswith(key))\n"
        "from identify.data.records import load_record\n"
        "before = status('VmRSS:')\n"
        "record = load_record(sys.argv[1])\n"
        "print(len(record), status('VmHWM:') - before)\n"
    )
    completed = subprocess.run(
        [sys.executable, "-c", probe, "long.csv"], cwd=tmp_path, env=env(), capture_output=True, text=True
    )
    assert completed.returncode == 0, completed.stderr
    samples, growth = map(int, completed.stdout.split())
    assert samples == n and growth < 100 * n, f"loading took {growth / n:.0f} bytes per sample"
    # the command: progress while loading, then the hint; the unknown effect stops it right after
    completed = cli("fit", "long.csv", "--noise-sigma", "free", "--effects", "warp", cwd=tmp_path)
    one_error(completed, "unknown effect")
    assert "reading long.csv" in completed.stderr and f"read {n} samples" in completed.stderr
    assert "--every 10 keeps every input reversal" in completed.stderr, completed.stderr


# -- 2. batches that stop ----------------------------------------------------------------------------------------


def batch_config(folder: Path, out="runs", workers=2, max_steps=1500, check_every=500) -> Path:
    for seed in (4, 5, 6):
        if not (folder / f"r{seed}.csv").exists():
            record_csv(folder / f"r{seed}.csv", seed=seed)
            (folder / f"r{seed}.json").unlink(missing_ok=True)
    path = folder / f"{out}.toml"
    path.write_text(
        f'task = "study"\nout = "{out}"\nworkers = {workers}\n[options]\nn_starts = 1\nmax_steps = {max_steps}\n'
        f'check_every = {check_every}\nprogress = "off"\nno_report = true\n[[records]]\nglob = "r*.csv"\n'
    )
    return path


def summary_rows(out: Path) -> dict:
    with open(out / "summary.csv", newline="") as fh:
        return {row["key"]: row for row in csv.DictReader(fh)}


def batch_code(out: Path) -> int:
    """The exit code a finished batch of studies must end with: 1 when some run's chain did
    NOT converge (its row says so), else 0; every run finished (ok or skipped)."""
    rows = summary_rows(out).values()
    assert rows and all(r["status"] in ("ok", "skipped") for r in rows), rows
    return 1 if any("NOT converged" in r["verdict"] for r in rows) else 0


def test_ctrl_c_stops_a_batch_its_commands_and_its_queue(tmp_path):
    """One worker, three study jobs: Ctrl-C while the first samples stops it between two
    steps (its steps kept), cancels the other two, marks all three interrupted, exits 130
    and leaves no process. While it runs, a second batch and a study started by hand in
    its run folder are refused. The first job is long (60000 steps, no convergence check
    before its cap), so it cannot finish while the checks run on a loaded machine."""
    config = batch_config(tmp_path, workers=1, max_steps=60000, check_every=60000)
    batch = start("batch", config.name, "--no-progress", cwd=tmp_path)
    first = tmp_path / "runs" / "r4__default"
    wait_for(lambda: steps(first) >= 100, batch, "100 steps of the first job")
    children = descendants(batch.pid)
    assert any("identify study" in c for c in children.values()), children
    second = cli("batch", config.name, "--no-progress", cwd=tmp_path)
    one_error(second, "runs is in use by process", str(batch.pid))
    by_hand = cli("study", "r4.csv", "--out", first, *FINISHED, cwd=tmp_path)
    one_error(by_hand, "r4__default is in use by process")
    batch.send_signal(signal.SIGINT)
    out, err = batch.communicate(timeout=180)
    assert batch.returncode == 130 and "Traceback" not in err + out, (batch.returncode, err[-3000:])
    assert not [pid for pid, command in children.items() if alive(pid, command)], "processes outlived the batch"
    rows = summary_rows(tmp_path / "runs")
    assert {k: r["status"] for k, r in rows.items()} == dict.fromkeys(
        ("r4__default", "r5__default", "r6__default"), "interrupted"
    )
    assert "stopped by SIGINT" in rows["r4__default"]["error"] and "before it started" in rows["r6__default"]["error"]
    assert 100 <= steps(first) < 60000
    assert not (first / "batch_done.json").exists() and not (first / "batch_failed.json").exists()
    assert not list((tmp_path / "runs").glob(".batch_stop*")) and not (tmp_path / "runs" / ".identify.lock").exists()


@pytest.fixture(scope="module")
def whole_batch(tmp_path_factory) -> Path:
    """The batch of three short studies, run without interruption."""
    folder = tmp_path_factory.mktemp("batch")
    whole = batch_config(folder, out="whole")
    completed = cli("batch", whole.name, "--no-progress", cwd=folder)
    assert completed.returncode == batch_code(folder / "whole"), completed.stderr[-3000:]
    return folder / "whole"


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_batch_killed_and_rerun_equals_an_uninterrupted_batch(tmp_path, whole_batch, signum):
    """SIGTERM: the batch stops its commands, exits 130 and leaves no process. SIGKILL
    cannot be caught: its commands get SIGTERM from the kernel (PR_SET_PDEATHSIG), stop
    between steps and end too. Either way the rerun (which takes over a stale lock after
    SIGKILL) ends with the uninterrupted batch's summary and chains."""
    for name in ("r4.csv", "r5.csv", "r6.csv"):
        shutil.copy2(whole_batch.parent / name, tmp_path / name)
    config = batch_config(tmp_path)
    batch = start("batch", config.name, "--no-progress", cwd=tmp_path)
    wait_for(lambda: steps(tmp_path / "runs" / "r4__default") >= 300, batch, "300 steps of a job")
    children = descendants(batch.pid)
    assert len(children) >= 2, children
    batch.send_signal(signum)
    out, err = batch.communicate(timeout=180)
    if signum == signal.SIGKILL:
        assert batch.returncode == -signal.SIGKILL
        deadline = time.monotonic() + 120
        while [pid for pid, command in children.items() if alive(pid, command)] and time.monotonic() < deadline:
            time.sleep(0.2)
    else:
        assert batch.returncode == 130 and "Traceback" not in err, err[-3000:]
        rows = summary_rows(tmp_path / "runs")
        assert "interrupted" in {r["status"] for r in rows.values()}, rows
    assert not [pid for pid, command in children.items() if alive(pid, command)], "processes outlived the batch"
    for job in children.values():
        assert "Traceback" not in job
    for log in (tmp_path / "runs").glob("*/batch.log"):
        assert "Traceback" not in log.read_text()

    completed = cli("batch", config.name, "--no-progress", cwd=tmp_path)
    assert completed.returncode == batch_code(tmp_path / "runs"), completed.stderr[-3000:]
    if signum == signal.SIGKILL:
        assert "took over the lock of process" in completed.stderr
    resumed, reference = summary_rows(tmp_path / "runs"), summary_rows(whole_batch)
    assert set(resumed) == set(reference)
    for key, row in resumed.items():
        assert row["status"] in ("ok", "skipped") and reference[key]["status"] == "ok"
        same = {c: row[c] for c in row if c not in ("status", "seconds")}
        assert same == {c: reference[key][c] for c in same}, key
        assert_same_results(tmp_path / "runs" / key, whole_batch / key)


# == round two (issue 64): a full disk never corrupts a study; a results folder or a unit cannot write or script ==


@contextlib.contextmanager
def small_disk(folder: Path, size: str):
    """A real file system of ``size`` (a tmpfs) mounted at ``folder``; the test is skipped, with
    the reason, where one cannot be mounted (not root, no mount permission in CI)."""
    folder.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("a real full disk needs a tmpfs: mounting one needs root and the mount command")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a {size} tmpfs for a real full disk: {done.stderr.strip() or done.returncode}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def resize_disk(folder: Path, size: str) -> None:
    """Free space on the disk of :func:`small_disk` (what a user does before the rerun)."""
    done = subprocess.run(["mount", "-o", f"remount,size={size}", str(folder)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def fill_disk(folder: Path) -> Path:
    """Fill the file system of ``folder`` to the last byte with the file ``filler``."""
    filler = folder / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        for size in (65536, 4096, 1):
            try:
                while os.write(fd, b"\0" * size):
                    pass
            except OSError:
                pass
    finally:
        os.close(fd)
    return filler


def others(folder: Path, inside: str) -> dict:
    """:func:`digests` of ``folder`` except what lies in its subfolder ``inside``."""
    return {k: v for k, v in digests(folder).items() if not k.startswith(inside + os.sep)}


# Sizes from the chain's space bound (chain_file: every chunk a flush touches, raw, plus 256 kB):
# the first flush (steps 0-99, two 64-step chunks) needs about 0.63 MB free, the second (steps
# 100-199, three chunks) about 0.81 MB; the record and the run's files before sampling take
# about 0.1 MB. So 600k fills at the first flush, 850k at the second. A flush also comes after a
# second of sampling (BufferedHDFBackend.flush_seconds): on a loaded machine that second holds fewer
# steps than a chunk, whose flush fits in 600k, and the disk fills at the next one.
@pytest.mark.parametrize(
    "size, fills", [("600k", "by the first 100 steps"), ("850k", "after some steps")], ids=["600k", "850k"]
)
def test_a_disk_that_fills_while_sampling_is_one_error_and_the_rerun_gives_the_chain_bit_for_bit(
    finished, tmp_path, size, fills
):
    """A real small file system: the study stops with one error line naming chain.h5 (exit 1,
    no crash by a signal, no HDF5 traceback); the chain holds exactly the steps its count
    claims (none never written), nothing else on the disk changed; once space is freed the
    same command resumes and ends with the chain of the uninterrupted run, bit for bit."""
    with small_disk(tmp_path / "disk", size) as disk:
        shutil.copy2(finished.parent / "rec.csv", disk / "rec.csv")
        before = others(disk, "run")
        completed = cli("study", "rec.csv", "--out", "run", *FINISHED, cwd=disk)
        one_error(completed, "run/chain.h5: no space left on the device", "rerun the same command", code=1)
        run = disk / "run"
        from identify.fitting.posterior import chain_info

        kept = chain_info(run / "chain.h5")[0]  # every counted step is stored (else ChainFileError)
        assert (kept < 100) if size == "600k" else (0 < kept < 300), (fills, kept)
        assert others(disk, "run") == before and not list(run.glob(".*"))  # no temporary file, no lock left
        resize_disk(disk, "64m")
        again = cli("study", "rec.csv", "--out", "run", *FINISHED, cwd=disk)
        assert again.returncode == NOT_CONVERGED and "Traceback" not in again.stderr, again.stderr[-3000:]
        assert ("resuming the chain" in again.stderr) == (kept > 0)
        assert_same_results(run, finished)


def test_a_full_disk_while_writing_the_posterior_leaves_no_temporary_file_and_no_lock(tmp_path):
    """posterior.nc does not fit: one error line naming it (exit 1), no .posterior.nc temporary
    left; a rerun on a disk full to the last byte cannot even take its lock: one line naming
    the lock file, which is not left behind (nor anything else); once space is freed the rerun
    finishes with the uninterrupted run's results."""
    # A 30 Hz record (2101 samples): its posterior.nc (about 5 MB, compressed) is larger than the
    # chain's space bound (under 1 MB: the 64-step chunks a flush touches, raw, and the HDF5
    # metadata), so a 4.5 MB disk has room for the chain but not for posterior.nc.
    write_record(tmp_path / "rec.csv", simulate(fs=30.0, seed=4).record)
    reference = cli("study", "rec.csv", "--out", "finished", *FINISHED, cwd=tmp_path)
    assert reference.returncode == NOT_CONVERGED, reference.stderr[-3000:]
    finished = tmp_path / "finished"
    with small_disk(tmp_path / "disk", "4500k") as disk:
        shutil.copy2(tmp_path / "rec.csv", disk / "rec.csv")
        completed = cli("study", "rec.csv", "--out", "run", *FINISHED, cwd=disk)
        one_error(completed, "run/posterior.nc: no space left on the device", code=1)
        run = disk / "run"
        assert steps(run) == 300 and not list(run.glob(".*")) and not (run / "posterior.nc").exists()
        filler = fill_disk(disk)
        before = digests(run)
        for command in (["study", "rec.csv", "--out", "run", *FINISHED], ["report", "run"]):
            full = cli(*command, cwd=disk)
            one_error(full, "run/.identify.lock: no space left on the device", code=1)
            assert digests(run) == before and not list(run.glob(".*"))
        filler.unlink()
        resize_disk(disk, "64m")
        again = cli("study", "rec.csv", "--out", "run", *FINISHED, cwd=disk)
        assert again.returncode == NOT_CONVERGED and "Traceback" not in again.stderr, again.stderr[-3000:]
        assert (run / "posterior.nc").is_file() and not list(run.glob(".*"))
        assert_same_results(run, finished)


def test_an_unwritable_temporary_is_removed_and_the_error_names_the_destination(tmp_path):
    """The writer behind posterior.nc: the disk fills while the library writes (after the
    space check passed): DiskFullError naming the destination, the temporary file removed,
    the destination as it was."""
    from identify.data.fileio import DiskFullError, write_via_temporary

    with small_disk(tmp_path / "disk", "1m") as disk:
        (disk / "posterior.nc").write_bytes(b"old")

        def too_big(path):
            with open(path, "wb") as fh:
                fh.write(b"\1" * (2 << 20))

        with pytest.raises(DiskFullError, match="posterior.nc: no space left on the device"):
            write_via_temporary(disk / "posterior.nc", too_big)
        assert sorted(p.name for p in disk.iterdir()) == ["posterior.nc"]
        assert (disk / "posterior.nc").read_bytes() == b"old"
        with pytest.raises(DiskFullError, match=r"posterior.nc: no space left on the device \(up to 2\.1 MB needed"):
            write_via_temporary(disk / "posterior.nc", too_big, need_bytes=2 << 20)
        assert sorted(p.name for p in disk.iterdir()) == ["posterior.nc"]


def _claim_unwritten_steps(chain: Path, extra: int) -> None:
    """What a full disk did to a chain before: the count advanced, the steps never written (zeros)."""
    with h5py.File(chain, "a") as f:
        g = f["mcmc"]
        n = int(g.attrs["iteration"])
        g["chain"].resize(n + extra, axis=0)
        g["log_prob"].resize(n + extra, axis=0)
        g.attrs["iteration"] = n + extra


def _change_last_step(chain: Path) -> None:
    """A last step that is not the one written with the count (stale data under a newer count)."""
    with h5py.File(chain, "a") as f:
        g = f["mcmc"]
        n = int(g.attrs["iteration"])
        g["chain"][n - 1] = g["chain"][n - 2] * 1.001


@pytest.mark.parametrize(
    "damage, needles",
    [
        (_claim_unwritten_steps, ["chain.h5 is damaged", "claims 356 steps, but step 300 was never written"]),
        (_change_last_step, ["chain.h5 is damaged", "its last stored step (step 300) is not the one written with"]),
    ],
    ids=["counted, never written", "last step not the one counted"],
)
def test_a_chain_whose_steps_do_not_match_its_count_is_refused_never_resumed(finished, tmp_path, damage, needles):
    """The chain the full disk left in issue 64 (its count 56 steps beyond its data, zeros), and
    one whose last step is not the one written with its count: the rerun that would extend it
    refuses in one line saying what to do (exit 2) and changes nothing; report and reproduce
    refuse too."""
    run = copy_of(finished, tmp_path)
    if damage is _claim_unwritten_steps:
        damage(run / "chain.h5", 56)
    else:
        damage(run / "chain.h5")
    before = digests(run)
    longer = list(FINISHED)
    longer[longer.index("--max-steps") + 1] = "600"
    completed = cli("study", "rec.csv", "--out", "finished", *longer, cwd=tmp_path)
    one_error(completed, *needles, "delete", "--force")
    assert digests(run) == before
    for command in (["report", "finished"], ["reproduce", "finished", "--out", "again"]):
        refused = cli(*command, cwd=tmp_path)
        one_error(refused, *needles)
        assert digests(run) == before and not (tmp_path / "again").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["report", "finished"],
        ["study", "rec.csv", "--out", "finished", *FINISHED],
        ["reproduce", "finished", "--out", "again"],
    ],
    ids=["report", "study", "reproduce"],
)
@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_a_lock_file_planted_as_a_link_is_refused_and_its_target_untouched(finished, tmp_path, command, link):
    run = copy_of(finished, tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    if link == "symbolic":
        (run / ".identify.lock").symlink_to(victim)
    else:
        os.link(victim, run / ".identify.lock")
    before = digests(tmp_path)
    completed = cli(*command, cwd=tmp_path)
    one_error(completed, "finished/.identify.lock", "symbolic link" if link == "symbolic" else "2 hard links")
    assert victim.read_text() == "precious\n" and digests(tmp_path) == before
    assert not (tmp_path / "again").exists()


def test_a_chain_planted_as_a_link_is_refused_and_its_target_untouched(finished, tmp_path):
    run = copy_of(finished, tmp_path)
    victim = tmp_path / "victim.h5"
    os.replace(run / "chain.h5", victim)
    (run / "chain.h5").symlink_to(victim)
    before = digests(tmp_path)
    longer = list(FINISHED)
    longer[longer.index("--max-steps") + 1] = "600"
    for command in (["study", "rec.csv", "--out", "finished", *longer], ["report", "finished"]):
        completed = cli(*command, cwd=tmp_path)
        one_error(completed, "chain.h5 is a symbolic link")
        assert digests(tmp_path) == before


def test_posterior_nc_is_written_under_a_fresh_name_never_through_a_link(tmp_path):
    """The old fixed temporary name and the destination itself planted as links to a user's
    files: both targets stay as they were, posterior.nc becomes a regular file."""
    import arviz as az

    from identify.fitting.inference import write_netcdf

    targets = {name: tmp_path / f"{name}.victim" for name in (".tmp-posterior.nc", "posterior.nc")}
    for name, target in targets.items():
        target.write_text("precious\n")
        (tmp_path / name).symlink_to(target)
    coords = {"chain": np.arange(2), "draw": np.arange(6)}
    groups = {"posterior": (coords, {"a": (("chain", "draw"), np.arange(12.0).reshape(2, 6), {}, None)}, {})}
    write_netcdf(tmp_path / "posterior.nc", groups)
    assert all(t.read_text() == "precious\n" for t in targets.values())
    assert not (tmp_path / "posterior.nc").is_symlink()
    assert az.from_netcdf(tmp_path / "posterior.nc").posterior["a"].shape == (2, 6)
    assert not list(tmp_path.glob(".posterior.nc.*"))


def test_a_batch_option_is_matched_exactly_and_never_writes_outside(tmp_path):
    """``jso = "/path"`` (argparse would expand it to --json) is an unknown option of the
    config: one line naming the key, exit 2, the file never written."""
    record_csv(tmp_path / "r4.csv", seed=4)
    victim = tmp_path / "elsewhere" / "owned.json"
    (tmp_path / "jso.toml").write_text(
        f'task = "fit"\nout = "runs"\n[options]\nn_starts = 1\njso = "{victim}"\n[[records]]\npath = "r4.csv"\n'
    )
    for extra in ([], ["--dry-run"]):
        completed = cli("batch", "jso.toml", "--no-progress", *extra, cwd=tmp_path)
        one_error(completed, "options.jso", "unrecognized arguments: --jso")
        assert not victim.parent.exists() and not (tmp_path / "runs").exists()


def test_every_command_takes_its_options_only_spelt_in_full(tmp_path):
    from identify.cli.app import build_parser

    parser = build_parser()
    assert parser.allow_abbrev is False
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert all(p.allow_abbrev is False for p in subparsers.choices.values())


def test_reproduce_never_takes_an_output_path_from_a_manifest(base, tmp_path):
    """A fit's manifest edited to hold ``"json": "/any/path"`` in its settings: reproduce refuses
    in one line (exit 2) before running anything; the path is never written."""
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    made = cli("fit", "rec.csv", "--n-starts", "1", "--out", "fitrun", cwd=tmp_path)
    assert made.returncode == 0, made.stderr[-3000:]
    victim = tmp_path / "elsewhere.json"
    victim.write_text("precious\n")
    manifest = json.loads((tmp_path / "fitrun" / "manifest.json").read_text())
    manifest["settings"]["json"] = str(victim)
    (tmp_path / "fitrun" / "manifest.json").write_text(json.dumps(manifest))
    before = digests(tmp_path)
    completed = cli("reproduce", "fitrun", "--out", "again", cwd=tmp_path)
    one_error(completed, f"json = '{victim}'", "never takes from a manifest")
    assert digests(tmp_path) == before and not (tmp_path / "again").exists()


def test_rerun_arguments_replay_only_the_computation(tmp_path):
    """Every option of fit and study is either replayed from a manifest or never (outputs)."""
    import importlib

    from identify.commands import COMMANDS, add_command_arguments
    from identify.workflows import reproduce as R

    for name in R.REPRODUCIBLE_COMMANDS:
        parser = argparse.ArgumentParser(add_help=False)
        add_command_arguments(parser, importlib.import_module(COMMANDS[name]))
        options = {a.dest for a in parser._actions if a.option_strings}
        assert options <= R.REPLAYED_OPTIONS | R.NOT_REPLAYED_OPTIONS, options - R.REPLAYED_OPTIONS
    assert not R.REPLAYED_OPTIONS & R.NOT_REPLAYED_OPTIONS
    manifest = {"task": "simulate", "settings": {"out": "x.csv"}, "data": {"file": "r.csv", "sha256": "0"}}
    with pytest.raises(R.ManifestError, match="reruns only study, fit runs"):
        R.rerun_arguments(manifest, "r.csv", tmp_path / "new")


def test_markup_in_a_results_folder_is_text_on_the_report_page(finished, tmp_path):
    """A data.npz whose units are markup: ``report DIR`` shows them as text, escaped in the
    summary at the top and in the per-cycle table's header alike."""
    run = copy_of(finished, tmp_path)
    with np.load(run / "data.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["input_unit"] = np.array("<script>alert(3)</script>")
    arrays["output_unit"] = np.array("<img src=x onerror=alert(4)>")
    np.savez(run / "data.npz", **arrays)
    completed = cli("report", "finished", "--draws", "4", cwd=tmp_path)
    assert completed.returncode == 0, completed.stderr[-3000:]
    page = (run / "report.html").read_text()
    assert "<script>alert" not in page and "<img src=x" not in page
    assert "RMS [&lt;img src=x onerror=alert(4)&gt;]" in page  # the per-cycle table's header
    assert "input peak [&lt;script&gt;alert(3)&lt;/script&gt;]" in page
    assert "Residual RMS" in page and "&lt;img src=x onerror=alert(4)&gt; = " in page  # the summary at the top


def test_one_helper_escapes_every_string_of_a_table():
    from identify.output.page import escape, html_table, number_cell, text_cell

    table = html_table("t<", ["<b>h</b>"], [[text_cell("<i>"), number_cell("<s>", key='k"')]], caption="<u>c</u>")
    assert "<b>" not in table and "<i>" not in table and "<s>" not in table and "<u>" not in table
    assert "&lt;b&gt;h&lt;/b&gt;" in table and 'data-key="k&quot;"' in table and 'id="t&lt;"' in table
    assert escape("a & 'b'") == "a &amp; &#x27;b&#x27;"


def test_summary_md_shows_markup_and_markdown_as_written(tmp_path):
    from identify.workflows import batch as B

    evil = "error: <img src=x onerror=alert(1)> | *bold* [link](javascript:alert(2)) `code`"
    B.write_summary(
        tmp_path,
        [
            B.JobResult("a__v", "fit", "a", "v", "failed", error=evil, report="a__v/report (1).html"),
            B.JobResult("b__v", "fit", "b", "v", "ok", rms=0.3, output_unit="<b>um</b>", verdict="_x_"),
        ],
    )
    md = (tmp_path / "summary.md").read_text()
    assert "<img" not in md and "<b>" not in md and "&lt;img src=x onerror=alert(1)&gt;" in md
    assert r"\| \*bold\* \[link\](javascript:alert(2)) \`code\`" in md
    assert "[a__v](a__v/report%20%281%29.html)" in md and r"\_x\_" in md
    assert md.count("\n| ") == 3  # the header and two rows: no cell split by a '|'


@pytest.mark.parametrize(
    "command",
    [
        ["fit", "rec.csv", "--input-unit", "<script>alert(3)</script>"],
        ["study", "rec.csv", "--out", "run", "--output-unit", "<img src=x onerror=alert(4)>"],
        ["diagnose", "rec.csv", "--output-unit", "um\n"],
        ["predict", "adir", "rec.csv", "--input-unit", "A" * 40],
    ],
    ids=["fit", "study", "diagnose", "predict"],
)
def test_a_unit_is_checked_as_a_unit_when_parsed(base, tmp_path, command):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    (tmp_path / "adir").mkdir()
    before = digests(tmp_path)
    completed = cli(*command, cwd=tmp_path)
    flag = next(w for w in command if w.endswith("-unit"))
    one_error(completed, f"argument {flag}: a unit is")
    assert digests(tmp_path) == before and not (tmp_path / "run").exists()


def _batch_of(folder: Path, name: str, n_starts: int = 1, glob: str = "r4.csv") -> Path:
    path = folder / name
    path.write_text(f'task = "fit"\nout = "runs"\n[options]\nn_starts = {n_starts}\n[[records]]\nglob = "{glob}"\n')
    return path


def test_a_batch_folder_belongs_to_one_configuration(tmp_path):
    """Another configuration run into the same out is refused in one line naming both (exit 2),
    prints no header and changes nothing; the same file edited, or a copy of it, may run there."""
    record_csv(tmp_path / "r4.csv", seed=4)
    first = cli("batch", _batch_of(tmp_path, "a.toml").name, "--no-progress", cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    before = digests(tmp_path / "runs")
    other = cli("batch", _batch_of(tmp_path, "b.toml", n_starts=2).name, "--no-progress", cwd=tmp_path)
    one_error(other, "runs belongs to the batch configuration", "a.toml", "b.toml", "is another one")
    assert "batch:" not in other.stdout and digests(tmp_path / "runs") == before
    copy = cli("batch", _batch_of(tmp_path, "a2.toml").name, "--no-progress", cwd=tmp_path)  # identical content
    assert copy.returncode == 0 and "1 finished earlier, skipped" in copy.stdout, copy.stdout + copy.stderr
    record_csv(tmp_path / "r5.csv", seed=5)
    edited = cli("batch", _batch_of(tmp_path, "a.toml", glob="r[45].csv").name, "--no-progress", cwd=tmp_path)
    assert edited.returncode == 0 and "2 ok (1 finished earlier" in edited.stdout, edited.stdout + edited.stderr


def test_a_batch_refused_by_the_lock_prints_only_its_error(tmp_path):
    from identify.data.locks import FolderLock

    record_csv(tmp_path / "r4.csv", seed=4)
    with FolderLock(tmp_path / "runs", command="the other batch"):
        completed = cli("batch", _batch_of(tmp_path, "a.toml").name, "--no-progress", cwd=tmp_path)
    one_error(completed, "runs is in use by process", "the other batch")
    assert completed.stdout == ""


def test_a_planted_batch_log_link_is_refused_and_its_target_untouched(tmp_path):
    record_csv(tmp_path / "r4.csv", seed=4)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (tmp_path / "runs" / "r4__default").mkdir(parents=True)
    (tmp_path / "runs" / "r4__default" / "batch.log").symlink_to(victim)
    completed = cli("batch", _batch_of(tmp_path, "a.toml").name, "--no-progress", cwd=tmp_path)
    assert completed.returncode == 1 and "Traceback" not in completed.stderr, completed.stderr[-3000:]
    assert "batch.log is a symbolic link" in completed.stderr
    assert victim.read_text() == "precious\n"


def test_a_signal_after_the_command_finished_ends_it_with_its_exit_code_and_a_note(tmp_path):
    """Ctrl-C while Python waits for a thread at exit (as after diagnose's 'done in'): exit code
    of the finished command and one note, never death by the signal with no word."""
    probe = (
        "import runpy, sys, threading, time\n"
        "from identify.cli import report\n"
        "def run(args):\n"
        "    threading.Thread(target=time.sleep, args=(60,)).start()  # Python waits for it at exit\n"
        "    print('done in 0.0 s', file=sys.stderr, flush=True)\n"
        "    return 0\n"
        "report.run = run\n"
        "sys.argv = ['identify', 'report', '.']\n"
        "runpy.run_module('identify', run_name='__main__')\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stderr.readline().strip() == "done in 0.0 s"
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, (proc.returncode, err)
    assert err.strip() == "note: SIGINT after the command had finished; its work is complete (exit code 0)"


@pytest.mark.slow
def test_ctrl_c_right_after_diagnose_is_done_is_no_death_by_signal(base, tmp_path):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    proc = start("diagnose", "rec.csv", "--n-starts", "1", cwd=tmp_path)
    for line in proc.stderr:
        if "done in" in line:
            proc.send_signal(signal.SIGINT)
            break
    out, err = proc.communicate(timeout=120)
    assert proc.returncode in (0, 130), (proc.returncode, err)


def test_an_input_that_never_moves_is_said_so(base, tmp_path):
    lines = (base / "rec.csv").read_text().splitlines()
    rows = [lines[0]] + [",".join([r.split(",")[0], "0", r.split(",")[2]]) for r in lines[1:]]
    (tmp_path / "zero.csv").write_text("\n".join(rows) + "\n")
    for command in (["fit", "zero.csv"], ["diagnose", "zero.csv"], ["study", "zero.csv", "--out", "run", *FINISHED]):
        completed = cli(*command, cwd=tmp_path)
        one_error(completed, "zero.csv: the input never moves", "column 'current' is 0 in every sample")
        assert not (tmp_path / "run").exists()


def test_a_missing_column_names_the_command_line_flags(base, tmp_path):
    shutil.copy2(base / "rec.csv", tmp_path / "rec.csv")
    completed = cli("fit", "rec.csv", "--input-column", "curent", cwd=tmp_path)
    one_error(completed, "missing column(s) 'curent'", "--input-column", "--time-column none")
