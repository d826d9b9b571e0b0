"""Running a batch: each job's command in its own subprocess, resuming, stopping, the batch folder.

:func:`run_batch` locks the batch folder, claims it for its configuration
(:data:`CONFIG_FILE`), skips the jobs an earlier run finished (:func:`finished_result`: same
fingerprint, completion marker present), runs the others on the configuration's executor
(:mod:`identify.workflows.batch_executors`) and rewrites the summary after every finished
job (:func:`identify.workflows.batch_summary.write_summary`). :func:`run_job` runs one job:
it locks the job's folder, runs ``python -m identify TASK ...`` in its own session with the
job's environment (:func:`job_environment`), stops it on a stop request or a timeout, and
writes last, atomically, :data:`DONE_MARKER` or :data:`FAILED_MARKER`. How stopping and
resuming behave is described in :mod:`identify.workflows.batch`.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from tqdm import tqdm

from ..commands import PARENT_VARIABLE, package_environment
from ..data.fileio import atomic_write, open_no_follow
from ..data.locks import FolderBusyError, FolderLock
from .batch_config import BatchConfig, BatchConfigError, Job, config_identity, expand_jobs
from .batch_executors import get_executor
from .batch_summary import (
    COLLECTORS,
    LOG_FILE,
    JobResult,
    assumptions_from_options,
    error_from_log,
    exit_is_finding,
    read_json_or_none,
    write_summary,
)

__all__ = [
    "DONE_MARKER",
    "FAILED_MARKER",
    "STOP_FILE",
    "STOP_GRACE_SECONDS",
    "CONFIG_FILE",
    "BatchResult",
    "job_environment",
    "run_job",
    "finished_result",
    "run_batch",
]

#: Written last and atomically into a job's folder when the job succeeded.
DONE_MARKER = "batch_done.json"
#: Written into a job's folder when the job failed (the job is redone on the next run).
FAILED_MARKER = "batch_failed.json"
#: Present in the batch folder while the batch is stopping: running jobs end their commands.
STOP_FILE = ".batch_stop"
#: Seconds a stopped command gets to end after SIGTERM before it is killed.
STOP_GRACE_SECONDS = 120.0
#: In the batch folder: the configuration the folder belongs to (file and SHA-256).
CONFIG_FILE = "batch_config.json"
_JOB_FILE = "batch_job.json"


@dataclass
class BatchResult:
    """What a batch run produced.

    Attributes
    ----------
    out : Path
        Results folder.
    results : list of JobResult
        One per job, in job order (records, then variants).
    seconds : float
        Wall time of this run [s].
    """

    out: Path
    results: list
    seconds: float

    @property
    def n_failed(self) -> int:
        return sum(r.status == "failed" for r in self.results)

    @property
    def n_ok(self) -> int:
        return sum(r.status in ("ok", "skipped") for r in self.results)

    @property
    def n_interrupted(self) -> int:
        return sum(r.status == "interrupted" for r in self.results)

    @property
    def n_not_converged(self) -> int:
        """Finished runs whose solver or chain did not converge (:attr:`JobResult.not_converged`)."""
        return sum(r.not_converged for r in self.results)


# -- the folder's configuration ----------------------------------------------------------------


def _claim_folder(config: BatchConfig) -> None:
    """Make ``config.out`` this configuration's (under the batch lock), or refuse: a folder that
    another configuration ran into (another file, other runs) is never touched."""
    path = config.out / CONFIG_FILE
    mine = config_identity(config)
    if path.exists():
        recorded = read_json_or_none(path)
        if not isinstance(recorded, dict) or not isinstance(recorded.get("sha256"), str):
            raise BatchConfigError(
                f"{path} is damaged, so the configuration that owns {config.out} is unknown. Nothing was changed: "
                f"delete {path} if {config.out} is this configuration's, or give {config.source} another out"
            )
        if recorded == mine or (recorded["sha256"] == mine["sha256"]):  # a copy of it does not take the folder over
            return
        if recorded.get("config") != mine["config"]:
            raise BatchConfigError(
                f"{config.out} belongs to the batch configuration {recorded.get('config')} (sha256 "
                f"{recorded['sha256'][:12]}); {mine['config']} (sha256 {mine['sha256'][:12]}) is another one and "
                "would replace its summary and its runs' bookkeeping. Nothing was changed: give this configuration "
                f"another out, or delete {path} to hand the folder over"
            )
    atomic_write(path, json.dumps(mine, indent=2) + "\n")


# -- running one job ---------------------------------------------------------------------------


def job_environment(threads: int) -> dict:
    """The environment of a job's command: this package importable, ``threads`` numerical threads.

    Parameters
    ----------
    threads : int
        Numba/OpenMP/BLAS threads the command may use (:attr:`identify.workflows.batch_config.Job.threads`).

    Returns
    -------
    dict
        The variables of :func:`identify.commands.package_environment` (the job imports this very
        package, wherever the batch was started from), with ``NUMBA_NUM_THREADS``,
        ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` set to ``threads``
        and ``PYTHONUNBUFFERED=1`` (the log shows the output as it comes).
    """
    env = package_environment()  # the job must import this very package, wherever the batch was started from
    for name in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = str(threads)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _report_link(folder: Path, batch_out: Path) -> str:
    """The run's report relative to the batch folder: report.html (study), else its result JSON."""
    for name in ("report.html", "diagnosis.json", "summary.json", "fit.json"):
        report = folder / name
        if report.is_file():
            return os.path.relpath(report, batch_out)
    return ""


def _stop_requested(job: Job) -> bool:
    return (Path(job.out_dir).parent / STOP_FILE).exists()


def _stop_now(job: Job) -> bool:
    """A second Ctrl-C/SIGTERM: kill the commands without waiting for their next step."""
    return (Path(job.out_dir).parent / (STOP_FILE + ".now")).exists()


def _signal_group(proc, sig) -> None:
    """Send ``sig`` to the job's process group (the command and anything it started)."""
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError, AttributeError):
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            pass


def run_job(job: Job) -> JobResult:
    """Run one job in a subprocess and record how it ended (never raises for a job failure).

    Locks the job's folder (the command inherits the lock), writes ``batch_job.json``
    first, the command's output to ``batch.log``, and last, atomically,
    ``batch_done.json`` (success) or ``batch_failed.json`` (failure). A stop request
    (:data:`STOP_FILE`) or the config's ``timeout`` sends the command SIGTERM (it stops
    between steps), then SIGKILL after :data:`STOP_GRACE_SECONDS`; a stopped job is
    ``interrupted`` and gets no marker, so the next run of the config redoes it.

    Parameters
    ----------
    job : Job

    Returns
    -------
    JobResult
    """
    folder = Path(job.out_dir)
    base = dict(key=job.key, task=job.task, record=job.record, variant=job.variant)
    if _stop_requested(job):
        return JobResult(**base, status="interrupted", error="stopped before it started; rerun the batch to run it")
    lock = FolderLock(folder, command=f"python -m identify batch (run {job.key})")
    try:
        lock.acquire()
    except FolderBusyError as exc:  # touch nothing: another process writes there
        return JobResult(**base, status="failed", error=f"error: {exc}")
    try:
        return _run_locked_job(job, folder, base, lock)
    finally:
        lock.release()


def _run_locked_job(job: Job, folder: Path, base: dict, lock) -> JobResult:
    for marker in (DONE_MARKER, FAILED_MARKER):
        (folder / marker).unlink(missing_ok=True)
    atomic_write(folder / _JOB_FILE, json.dumps(asdict(job), indent=2) + "\n")
    command = [sys.executable, "-m", "identify", *job.argv]
    started = time.perf_counter()
    error = ""
    stopped = ""
    env, pass_fds = lock.child_environment(job_environment(job.threads))
    env[PARENT_VARIABLE] = str(os.getpid())  # the command ends (SIGTERM) if the batch dies
    log_fd = open_no_follow(folder / LOG_FILE, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)  # never through a link
    with os.fdopen(log_fd, "w", encoding="utf-8") as log:
        if lock.stale_note():
            log.write(f"note: {lock.stale_note()}\n")
        log.write("$ " + " ".join(command) + "\n")
        log.flush()
        try:
            proc = subprocess.Popen(
                command,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                pass_fds=pass_fds,
                start_new_session=True,
            )
        except OSError as exc:
            proc = None
            error = f"could not start the command: {exc}"
        returncode = None
        if proc is not None:
            deadline = None if job.timeout is None else started + job.timeout
            kill_at = math.inf
            while returncode is None:
                # poll every 0.2 s, and wake at the deadline itself (a short timeout is kept to ~10 ms)
                poll = 0.2 if deadline is None or stopped else min(0.2, max(0.01, deadline - time.perf_counter()))
                try:
                    returncode = proc.wait(timeout=poll)
                    continue
                except subprocess.TimeoutExpired:
                    pass
                now = time.perf_counter()
                if not stopped:
                    if _stop_requested(job):
                        stopped = "stop"
                    elif deadline is not None and now > deadline:
                        stopped = "timeout"
                    if stopped:  # one SIGTERM: the command stops between two steps
                        _signal_group(proc, signal.SIGTERM)
                        kill_at = now + STOP_GRACE_SECONDS
                if stopped and (now > kill_at or _stop_now(job)):
                    _signal_group(proc, signal.SIGKILL)
    seconds = time.perf_counter() - started
    log_text = (folder / LOG_FILE).read_text(encoding="utf-8", errors="replace")
    if stopped == "timeout" and returncode != 0:
        error = f"timed out after {job.timeout:g} s (the config's timeout); stopped"
    elif (stopped == "stop" and returncode != 0) or returncode == 130:
        return JobResult(
            **base,
            status="interrupted",
            seconds=seconds,
            error="interrupted (its completed work is kept); rerun the batch to resume it",
        )
    elif returncode not in (0, None) and not (returncode == 1 and exit_is_finding(log_text)):
        error = error_from_log(log_text, returncode)
    result = None
    if not error:
        try:
            figures = COLLECTORS[job.task](folder)
            stated = [n for n in assumptions_from_options(job.argv) if n not in figures.get("notes", "")]
            figures["notes"] = "; ".join([n for n in [figures.get("notes", "")] if n] + stated)
            result = JobResult(**base, status="ok", seconds=seconds, **figures)
        except Exception as exc:  # a run that wrote unreadable results counts as failed
            error = str(exc)
    if result is None:
        result = JobResult(**base, status="failed", seconds=seconds, error=error)
        marker = FAILED_MARKER
    else:
        marker = DONE_MARKER
    result.report = _report_link(folder, folder.parent)
    payload = {"fingerprint": job.fingerprint, "result": result.to_dict()}
    atomic_write(folder / marker, json.dumps(payload, indent=2) + "\n")
    return result


def finished_result(job: Job) -> JobResult | None:
    """The result of ``job`` from an earlier run, if it finished with the same fingerprint."""
    payload = read_json_or_none(Path(job.out_dir) / DONE_MARKER)
    if not isinstance(payload, dict) or payload.get("fingerprint") != job.fingerprint:
        return None
    try:
        result = JobResult.from_dict(payload["result"])
    except (KeyError, TypeError):
        return None
    result.status = "skipped"
    return result


# -- the batch ----------------------------------------------------------------------------------


def run_batch(
    config: BatchConfig, *, progress: bool = True, rerun: bool = False, stream=None, announce=None
) -> BatchResult:
    """Run every job of ``config`` that has not finished yet, then write the summary.

    The batch folder is locked for the whole run; Ctrl-C and SIGTERM stop the batch as
    :mod:`identify.workflows.batch` says (the result's jobs are then ``interrupted``).

    Parameters
    ----------
    config : BatchConfig
    progress : bool, default True
        Show a tqdm progress bar (on ``stream``).
    rerun : bool, default False
        Redo finished jobs too.
    stream : file-like, default sys.stderr
    announce : callable, optional
        Called with no argument once the folder is locked and found to be this
        configuration's, before anything runs (the command line prints its header there,
        so a refused batch prints only its error).

    Returns
    -------
    BatchResult
        Every job's result, finished earlier (``"skipped"``) or now.

    Raises
    ------
    identify.data.locks.FolderBusyError
        Another process holds the batch folder.
    BatchConfigError
        The folder belongs to another configuration (:data:`CONFIG_FILE`); nothing was changed.
    """
    lock = FolderLock(config.out, command=f"python -m identify batch {config.source}")
    lock.acquire()
    try:
        _claim_folder(config)
        if announce is not None:
            announce()
        if lock.stale_note():
            print(f"note: {lock.stale_note()}", file=sys.stderr if stream is None else stream)
        return _run_batch_locked(config, progress=progress, rerun=rerun, stream=stream, lock=lock)
    finally:
        lock.release()


class _StopSignals:
    """While active (main thread only): the first SIGINT/SIGTERM asks the jobs to stop
    (:data:`STOP_FILE`), a second one to stop at once (``STOP_FILE + ".now"``)."""

    def __init__(self, out: Path, on_stop: Callable[[], None]):
        self.out = out
        self.on_stop = on_stop
        self.requested = ""
        self._previous = {}

    def _handle(self, signum, frame):
        name = signal.Signals(signum).name
        if self.requested:
            (self.out / (STOP_FILE + ".now")).touch()
            return
        self.requested = name
        (self.out / STOP_FILE).touch()
        self.on_stop()

    def __enter__(self):
        for name in (STOP_FILE, STOP_FILE + ".now"):
            (self.out / name).unlink(missing_ok=True)
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        for name in (STOP_FILE, STOP_FILE + ".now"):
            (self.out / name).unlink(missing_ok=True)


def _run_batch_locked(config: BatchConfig, *, progress, rerun, stream, lock) -> BatchResult:
    stream = sys.stderr if stream is None else stream
    started = time.perf_counter()
    jobs = expand_jobs(config)
    results: dict[str, JobResult] = {}
    pending = []
    for job in jobs:
        previous = None if rerun else finished_result(job)
        if previous is not None:
            results[job.key] = previous
        else:
            pending.append(job)
    order = [job.key for job in jobs]

    def summary_rows():
        rows = []
        for job in jobs:
            if job.key in results:
                rows.append(results[job.key])
            else:
                rows.append(JobResult(job.key, job.task, job.record, job.variant, status="pending"))
        return rows

    write_summary(config.out, summary_rows(), config)
    if pending:
        executor = get_executor(config.executor, config.workers, **config.executor_options)
        bar = tqdm(total=len(pending), desc=f"batch {config.task}", unit="run", file=stream, disable=not progress)
        n_failed = 0
        with _StopSignals(config.out, on_stop=lambda: getattr(executor, "cancel", lambda: None)()) as stop:
            try:
                for job, outcome in executor.submit_all(run_job, pending):
                    if outcome is None:  # cancelled before it started
                        outcome = JobResult(
                            job.key,
                            job.task,
                            job.record,
                            job.variant,
                            status="interrupted",
                            error=f"cancelled by {stop.requested or 'the batch'} before it started; rerun the batch "
                            "to run it",
                        )
                    elif isinstance(outcome, BaseException):
                        outcome = JobResult(
                            job.key,
                            job.task,
                            job.record,
                            job.variant,
                            status="failed",
                            error=f"the job's worker failed: {type(outcome).__name__}: {outcome}",
                        )
                        atomic_write(
                            Path(job.out_dir) / FAILED_MARKER,
                            json.dumps({"fingerprint": job.fingerprint, "result": outcome.to_dict()}, indent=2) + "\n",
                            make_parents=True,
                        )
                    elif outcome.status == "interrupted" and stop.requested:
                        outcome.error = f"stopped by {stop.requested}; " + outcome.error
                    results[job.key] = outcome
                    n_failed += outcome.status == "failed"
                    bar.set_postfix_str(f"{n_failed} failed" if n_failed else "ok")
                    bar.update(1)
                    write_summary(config.out, summary_rows(), config)
            finally:
                bar.close()
                executor.close()  # waits for the running jobs, which end their commands
    final = [results[k] for k in order if k in results]
    write_summary(config.out, final if len(final) == len(order) else summary_rows(), config)
    return BatchResult(config.out, final, time.perf_counter() - started)
