"""Batch identification runs: many records times many model variants, in parallel, one summary.

A batch is described by a TOML file (see ``examples/*.toml`` and docs/batch.md)::

    task = "fit"                  # fit | diagnose | study: the command each job runs
    out = "../reports/batch"      # results folder (relative to this file)
    workers = 2                   # jobs run at the same time (default: the machine's cores)
    executor = "local"            # local (process pool, default) | dask
    timeout = 3600                # optional: seconds before a job is stopped and marked failed

    [options]                     # options of the task command, for every job
    n_starts = 4                  #   -> --n-starts 4

    [[records]]                   # one table per file or glob
    path = "../data/piezo_smarthysteresis.csv"   # or: glob = "../data/*.csv"
    name = "smarthysteresis"      # optional, default: the file's stem
    input_column = "voltage"      # any other key: a task option for this record
    input_unit = "V"

    [[variants]]                  # model variants; default: one variant with no options
    name = "gpi12"
    n_operators = 12
    effects = ["lag"]

    [executor_options]            # passed to the executor (e.g. address = "tcp://host:8786" for dask)

Jobs are the product records x variants. Each job runs the task command
``python -m identify TASK RECORD --out OUT/JOB ...`` in its **own subprocess**, so a
crash, a runaway memory use or a hang (``timeout``) in one job cannot take the others
down, and the command does exactly what it does from the shell. The options of a job are
``[options]``, updated by the record's keys, updated by the variant's keys; each
``key = value`` becomes ``--key-with-dashes value`` (``true`` -> the bare flag for switches,
``false`` -> omitted, a list -> comma-separated, or repeated values for options that take
several). Every job's arguments are checked against the command's own argument parser
before anything runs, so a misspelt option is a :class:`BatchConfigError` naming the key
and the file.

Completion and resuming
-----------------------
A job's folder ``OUT/<record>__<variant>/`` gets ``batch_job.json`` (what runs),
``batch.log`` (the command's output) and, **last and atomically**, either the completion
marker ``batch_done.json`` (the run's figures) or ``batch_failed.json`` (its error). Rerunning
the same config skips jobs whose marker is present and whose job description (arguments
and the record file's SHA-256) is unchanged, and redoes failed, interrupted or changed ones
(a ``study`` resumes its chain). After every finished job the summary is rewritten
(atomically): ``summary.csv``, ``summary.md`` and ``index.html`` (links to each run's
report) in ``OUT``.

One configuration per folder
----------------------------
``OUT`` belongs to the configuration that first ran into it: ``OUT/batch_config.json``
records its file and the SHA-256 of what defines its runs (task, options, records,
variants). The same file (edited: changed runs are redone) or an identical configuration
may run there again; another configuration is refused in one line naming both, before
anything in ``OUT`` is touched (it would replace the summary and the runs' bookkeeping).

One writer, and stopping
------------------------
The batch locks ``OUT`` and each job locks its run folder (:mod:`identify.data.locks`) before
writing there; the job's command inherits that lock, so a second batch on the same
folder is refused at once, and so is a command started by hand in a run folder.
Ctrl-C or SIGTERM stops the batch: the queue is cancelled, every running command gets
one SIGTERM (a ``study`` stops between two steps and keeps every completed one), the
batch waits for them, marks their rows and the cancelled ones ``interrupted`` and exits
with code 130; rerunning the config resumes them. A second signal kills the commands at
once. The commands run in their own sessions (the terminal's Ctrl-C reaches only the
batch) and end with SIGTERM if the batch dies (Linux ``PR_SET_PDEATHSIG``), so no process
outlives the batch. The stop request is the file ``OUT/.batch_stop``, which jobs on other
machines (dask) see too.

Executors
---------
:data:`EXECUTORS` maps a name to a class with ``submit_all(fn, jobs)`` yielding
``(job, result)`` as jobs finish, ``cancel()`` (drop the jobs not started yet) and
``close()``. ``"local"`` runs the jobs' subprocesses from ``workers`` threads of the batch
process (:class:`concurrent.futures.ThreadPoolExecutor`: each job is a subprocess already,
so no pool of worker processes is needed); ``"dask"`` runs on a
``dask.distributed`` cluster (a ``LocalCluster`` by default, or a running scheduler given
by ``executor_options.address``), installed with ``pip install .[dask]``. Register more
with :func:`register_executor`.
"""

from __future__ import annotations

import argparse
import csv
import glob as _glob
import hashlib
import html
import io
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..data.fileio import atomic_write, open_no_follow, toml_module

__all__ = [
    "TASKS",
    "BatchConfigError",
    "RecordSpec",
    "VariantSpec",
    "BatchConfig",
    "Job",
    "JobResult",
    "BatchResult",
    "load_config",
    "parse_config",
    "expand_jobs",
    "run_job",
    "finished_result",
    "run_batch",
    "write_summary",
    "EXECUTORS",
    "register_executor",
    "get_executor",
    "LocalExecutor",
    "DaskExecutor",
    "COLLECTORS",
    "DONE_MARKER",
    "FAILED_MARKER",
    "STOP_FILE",
    "CONFIG_FILE",
    "config_identity",
]

#: The commands a batch can run, each a registered ``python -m identify`` command.
TASKS = ("fit", "diagnose", "study")
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
# the file a task writes when it only has a --json option
_JSON_NAMES = {"fit": "fit.json", "diagnose": "diagnosis.json", "study": "summary.json"}
_LOG_FILE = "batch.log"

_TOP_KEYS = {"task", "out", "workers", "executor", "timeout", "options", "records", "variants", "executor_options"}
_RECORD_KEYS = {"path", "glob", "name", "paths"}
#: The tasks whose command takes several records of one transducer (an entry's ``paths``).
SEVERAL_RECORD_TASKS = ("fit", "study", "diagnose")
_VARIANT_KEYS = {"name"}
# options the batch sets itself: a config may not give them
_RESERVED_OPTIONS = {"out", "json", "data", "record", "path"}


class BatchConfigError(ValueError):
    """A batch configuration that cannot run; the message names the file and the key."""


@dataclass(frozen=True)
class RecordSpec:
    """One record of a batch.

    Attributes
    ----------
    name : str
        Short name used in job folder names and the summary.
    path : Path
        The record file (absolute); of several records, the first.
    options : dict
        Task options for this record (e.g. load options ``input_column``, ``input_unit``).
    more : tuple of Path
        The further records of one transducer that the job studies together with ``path``
        (an entry's ``paths = [...]``); empty for one record.
    """

    name: str
    path: Path
    options: dict = field(default_factory=dict)
    more: tuple = ()

    @property
    def files(self) -> tuple:
        """Every record file of the job, ``path`` first."""
        return (self.path, *self.more)


@dataclass(frozen=True)
class VariantSpec:
    """One model variant of a batch: a name and the task options that define it."""

    name: str
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BatchConfig:
    """A validated batch configuration (see the module docstring for the file format).

    Attributes
    ----------
    source : Path
        The TOML file (relative paths in it are relative to its folder).
    task : str
        One of :data:`TASKS`.
    out : Path
        Results folder (absolute).
    workers : int
        Jobs run at the same time, >= 1.
    executor : str
        A name in :data:`EXECUTORS`.
    executor_options : dict
        Keyword arguments for the executor.
    timeout : float or None
        Seconds before a job's subprocess is stopped (None: no limit).
    options : dict
        Task options for every job.
    records : tuple of RecordSpec
    variants : tuple of VariantSpec
    """

    source: Path
    task: str
    out: Path
    workers: int
    executor: str
    executor_options: dict
    timeout: float | None
    options: dict
    records: tuple
    variants: tuple


@dataclass(frozen=True)
class Job:
    """One run of the batch: a record, a variant, and the exact command line.

    Attributes
    ----------
    key : str
        ``<record>__<variant>``: the job's folder name and its id in the summary.
    task : str
    record : str
        Record name.
    variant : str
        Variant name.
    record_path : str
        The record file.
    argv : tuple of str
        Arguments after ``python -m identify`` (task, record, ``--out``, options).
    out_dir : str
        The job's folder.
    fingerprint : str
        SHA-256 of the arguments (without the folder) and the record file's SHA-256: a
        finished job is redone when it changes.
    threads : int
        Numba/BLAS threads the job's process may use (cores / workers).
    timeout : float or None
    """

    key: str
    task: str
    record: str
    variant: str
    record_path: str
    argv: tuple
    out_dir: str
    fingerprint: str
    threads: int = 1
    timeout: float | None = None


@dataclass
class JobResult:
    """How one job ended, and its figures (one row of the summary).

    Attributes
    ----------
    key, task, record, variant : str
        As in :class:`Job`.
    status : {"ok", "failed", "skipped", "interrupted", "pending"}
        ``"skipped"``: finished by an earlier run of the same config (figures from its marker);
        ``"interrupted"``: stopped (or cancelled before it started) by Ctrl-C or SIGTERM, redone
        (resumed) by the next run of the config.
    rms : float or None
        Residual RMS over the energised part [output unit].
    max_error_pct : float or None
        Largest residual over the energised part, % of the measured range.
    statistic_name : str
        Which comparison statistic ``statistic`` is (``"reduced_chi2"`` for fit and
        study; the diagnosis' ranking statistic for diagnose).
    statistic : float or None
    verdict : str
        Fit: ``converged``/``not converged``; study: the posterior's convergence; diagnose:
        the diagnosis status (and its top-ranked effect).
    seconds : float
        Wall time of the job's command [s] (of the original run for ``"skipped"``).
    error : str
        The error, for a failed job (``""`` otherwise).
    output_unit : str
        Unit of ``rms`` when the run states it.
    report : str
        The run's report relative to the batch folder: ``report.html`` (study), else its
        result JSON (``diagnosis.json``, ``fit.json``); ``""`` for a run that wrote none.
    notes : str
        Assumptions the run states (e.g. no time column, noise fallback), ``"; "``-joined.
    """

    key: str
    task: str
    record: str
    variant: str
    status: str
    rms: float | None = None
    max_error_pct: float | None = None
    statistic_name: str = ""
    statistic: float | None = None
    verdict: str = ""
    seconds: float = 0.0
    error: str = ""
    output_unit: str = ""
    report: str = ""
    notes: str = ""

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def not_converged(self) -> bool:
        """A finished run (ok or skipped) whose solver or chain did not converge (its verdict
        says ``not converged``): a finding, exit code 1 of the batch."""
        return self.status in ("ok", "skipped") and "not converged" in self.verdict.lower()

    @classmethod
    def from_dict(cls, d: dict) -> JobResult:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


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


# -- configuration ------------------------------------------------------------------------


def load_config(path) -> BatchConfig:
    """Read and validate a batch TOML file.

    Parameters
    ----------
    path : path-like
        The TOML file.

    Returns
    -------
    BatchConfig

    Raises
    ------
    BatchConfigError
        Unreadable or invalid TOML, or any invalid key (the message names the file and key).
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise BatchConfigError(f"{path}: no such batch config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BatchConfigError(f"{path}: cannot read the batch config ({exc})") from None
    tomllib = toml_module()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BatchConfigError(f"{path}: not valid TOML: {exc}") from None
    return parse_config(data, source=path)


def _slug(text: str) -> str:
    slug = re.sub(r"[^A-Za-z0-9_.+-]+", "-", str(text)).strip("-.")
    return slug or "x"


def _check_options(table: dict, where: str, source: Path) -> dict:
    options = {}
    for key, value in table.items():
        if not isinstance(key, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", key):
            raise BatchConfigError(f"{source}: {where}: option name {key!r} is not a valid option name")
        if key.replace("-", "_") in _RESERVED_OPTIONS:
            raise BatchConfigError(f"{source}: {where}.{key}: set by the batch itself; remove it from the config")
        if isinstance(value, dict):
            raise BatchConfigError(f"{source}: {where}.{key}: a table is not a valid option value")
        if isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value):
            raise BatchConfigError(f"{source}: {where}.{key}: a list option may hold only plain values")
        if isinstance(value, float) and not math.isfinite(value):
            raise BatchConfigError(f"{source}: {where}.{key}: {value} is not a finite number")
        if key.replace("-", "_") == "priors" and isinstance(value, str):  # a priors file, relative to this config
            priors = (source.parent if source.suffix else Path.cwd()) / value
            if not priors.is_file():
                raise BatchConfigError(f"{source}: {where}.{key}: no such priors file {str(priors)!r}")
            value = str(priors.resolve())
        options[key.replace("-", "_")] = value
    return options


def parse_config(data: dict, source="<config>") -> BatchConfig:
    """Validate a parsed TOML mapping and resolve it into a :class:`BatchConfig`.

    Parameters
    ----------
    data : dict
        The parsed TOML (see the module docstring for the keys).
    source : path-like, default "<config>"
        The file it came from: relative paths are resolved against its folder, and error
        messages name it.

    Returns
    -------
    BatchConfig

    Raises
    ------
    BatchConfigError
        An unknown key, a missing or mistyped value, a glob matching nothing, duplicate
        record or variant names, an unknown task or executor. The message names the
        file and the key (e.g. ``records[2].glob``).

    The keys are checked in order: the top-level keys, the task, the output folder and
    the execution settings (:func:`_execution`), the options, the records
    (:func:`_records`) and the variants (:func:`_variants`).
    """
    source = Path(source)
    base = source.parent if source.suffix else Path.cwd()
    if not isinstance(data, dict):
        raise BatchConfigError(f"{source}: the config must be a TOML table")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise BatchConfigError(
            f"{source}: unknown key(s) {', '.join(unknown)}; known top-level keys: {', '.join(sorted(_TOP_KEYS))}"
        )
    task = _task(data, source)
    out = data.get("out")
    if not isinstance(out, str) or not out.strip():
        raise BatchConfigError(f"{source}: out must be a folder path (string), got {out!r}")
    out_path = (base / out).resolve()
    workers, executor, executor_options, timeout = _execution(data, source)
    options_table = data.get("options", {})
    if not isinstance(options_table, dict):
        raise BatchConfigError(f"{source}: options must be a table ([options])")
    options = _check_options(options_table, "options", source)
    records = _records(data, source, base)
    variants = _variants(data, source)
    return BatchConfig(
        source=source,
        task=task,
        out=out_path,
        workers=workers,
        executor=executor,
        executor_options=dict(executor_options),
        timeout=None if timeout is None else float(timeout),
        options=options,
        records=tuple(records),
        variants=tuple(variants),
    )


def _task(data: dict, source: Path) -> str:
    """The ``task``: one of :data:`TASKS` and a registered command."""
    task = data.get("task")
    if task not in TASKS:
        raise BatchConfigError(f"{source}: task must be one of {', '.join(TASKS)}, got {task!r}")
    from ..commands import COMMANDS

    if task not in COMMANDS:
        raise BatchConfigError(
            f"{source}: task {task!r} is not available: 'python -m identify {task}' is not a registered command"
        )
    return task


def _execution(data: dict, source: Path) -> tuple:
    """``(workers, executor, executor_options, timeout)``: workers default to the CPU count."""
    cores = os.cpu_count() or 1
    workers = data.get("workers", cores)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise BatchConfigError(f"{source}: workers must be an integer >= 1, got {workers!r}")

    executor = data.get("executor", "local")
    if executor not in EXECUTORS:
        raise BatchConfigError(f"{source}: executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    executor_options = data.get("executor_options", {})
    if not isinstance(executor_options, dict):
        raise BatchConfigError(f"{source}: executor_options must be a table")

    timeout = data.get("timeout")
    if timeout is not None and (
        isinstance(timeout, bool)
        or not isinstance(timeout, (int, float))
        or not (math.isfinite(timeout) and timeout > 0)
    ):
        raise BatchConfigError(f"{source}: timeout must be a positive number of seconds, got {timeout!r}")
    return workers, executor, executor_options, timeout


def _records(data: dict, source: Path, base: Path) -> list:
    """The :class:`RecordSpec` of every ``[[records]]`` entry (a path, or the files of a glob), names unique."""
    records = []
    for where, entry in _array_of_tables(data, "records", source):
        if "paths" in entry:
            records.append(_several_records(entry, where, source, base, data.get("task")))
            continue
        has_path, has_glob = "path" in entry, "glob" in entry
        if has_path == has_glob:
            raise BatchConfigError(f"{source}: {where} needs exactly one of 'path', 'paths' or 'glob'")
        record_options = _check_options({k: v for k, v in entry.items() if k not in _RECORD_KEYS}, where, source)
        paths = _record_paths(entry, where, source, base, has_path)
        name = entry.get("name")
        if name is not None and (not isinstance(name, str) or not name.strip()):
            raise BatchConfigError(f"{source}: {where}.name must be a non-empty string")
        if name is not None and len(paths) > 1:
            raise BatchConfigError(f"{source}: {where}.name cannot name the {len(paths)} files of a glob")
        for p in paths:
            records.append(RecordSpec(_slug(name if name else p.stem), p, record_options))
    _check_unique([r.name for r in records], "record", source, "give the records a 'name'")
    return records


def _several_records(entry: dict, where: str, source: Path, base: Path, task) -> RecordSpec:
    """The :class:`RecordSpec` of an entry ``paths = ["a.csv", "b.csv"]``: several records of one
    transducer that one job fits, studies or diagnoses together (a ``name`` is required)."""
    if "path" in entry or "glob" in entry:
        raise BatchConfigError(f"{source}: {where} needs exactly one of 'path', 'paths' or 'glob'")
    if task not in SEVERAL_RECORD_TASKS:
        raise BatchConfigError(
            f"{source}: {where}.paths: several records in one job are for the tasks {', '.join(SEVERAL_RECORD_TASKS)}, "
            f"not {task!r}"
        )
    files = entry["paths"]
    if not isinstance(files, list) or len(files) < 2 or not all(isinstance(f, str) and f.strip() for f in files):
        raise BatchConfigError(f"{source}: {where}.paths must list two or more record files (strings)")
    paths = [(base / f).resolve() for f in files]
    repeated = next((p for i, p in enumerate(paths) if p in paths[:i]), None)
    if repeated is not None:
        raise BatchConfigError(f"{source}: {where}.paths names {repeated} twice")
    name = entry.get("name")
    if not isinstance(name, str) or not name.strip():
        raise BatchConfigError(f"{source}: {where}.name is required with 'paths' (it names the job's folder)")
    record_options = _check_options({k: v for k, v in entry.items() if k not in _RECORD_KEYS}, where, source)
    return RecordSpec(_slug(name), paths[0], record_options, tuple(paths[1:]))


def _record_paths(entry: dict, where: str, source: Path, base: Path, has_path: bool) -> list:
    """The files of one ``[[records]]`` entry: its ``path``, or the files its ``glob`` matches (at least one)."""
    if has_path:
        if not isinstance(entry["path"], str) or not entry["path"].strip():
            raise BatchConfigError(f"{source}: {where}.path must be a file path (string)")
        return [(base / entry["path"]).resolve()]
    pattern = entry["glob"]
    if not isinstance(pattern, str) or not pattern.strip():
        raise BatchConfigError(f"{source}: {where}.glob must be a glob pattern (string)")
    paths = [Path(p).resolve() for p in sorted(_glob.glob(str(base / pattern), recursive=True))]
    paths = [p for p in paths if p.is_file()]
    if not paths:
        raise BatchConfigError(f"{source}: {where}.glob {pattern!r} matches no file (relative to {base})")
    return paths


def _variants(data: dict, source: Path) -> list:
    """The :class:`VariantSpec` of every ``[[variants]]`` entry (default one named ``default``), names unique."""
    variants = []
    for where, entry in _array_of_tables(data, "variants", source, default=[{"name": "default"}]):
        name = entry.get("name")
        if not isinstance(name, str) or not name.strip():
            raise BatchConfigError(f"{source}: {where}.name is required (a short string naming the variant)")
        variant_options = _check_options({k: v for k, v in entry.items() if k not in _VARIANT_KEYS}, where, source)
        variants.append(VariantSpec(_slug(name), variant_options))
    _check_unique([v.name for v in variants], "variant", source, "rename them")
    return variants


def _array_of_tables(data: dict, key: str, source: Path, default=None) -> list:
    """``(where, entry)`` of each table of the config's ``[[key]]`` array (``default`` when absent), checked."""
    table = data.get(key, default)
    if not isinstance(table, list) or not table:
        raise BatchConfigError(f"{source}: {key} must be a non-empty array of tables ([[{key}]])")
    entries = []
    for i, entry in enumerate(table):
        where = f"{key}[{i}]"
        if not isinstance(entry, dict):
            raise BatchConfigError(f"{source}: {where} must be a table")
        entries.append((where, entry))
    return entries


def _check_unique(names, what, source, hint):
    seen = set()
    for n in names:
        if n in seen:
            raise BatchConfigError(f"{source}: two {what}s are named {n!r}; {hint}")
        seen.add(n)


# -- command lines --------------------------------------------------------------------------


class _ArgumentError(Exception):
    pass


class _RaisingParser(argparse.ArgumentParser):
    """An argument parser that raises instead of printing usage and exiting, and knows an
    option only by its full name (``allow_abbrev=False``, as the command line itself): a
    config's ``jso = "..."`` is an unknown option, never ``--json``."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message):
        raise _ArgumentError(message)

    def exit(self, status=0, message=None):
        raise _ArgumentError(message or f"exit {status}")


def _command_parser(task: str) -> argparse.ArgumentParser:
    import importlib

    from ..commands import COMMANDS, add_command_arguments

    module = importlib.import_module(COMMANDS[task])
    parser = _RaisingParser(prog=f"python -m identify {task}", add_help=False)
    add_command_arguments(parser, module)
    return parser


def _option_action(parser: argparse.ArgumentParser, flag: str):
    for action in parser._actions:
        if flag in action.option_strings:
            return action
    return None


def _option_args(parser, key: str, value) -> list[str]:
    """``key = value`` as command-line words for ``parser`` (see the module docstring)."""
    flag = "--" + key.replace("_", "-")
    action = _option_action(parser, flag)
    if action is None:
        return [flag, str(value)]  # unknown: the parse check reports it with the key
    is_switch = action.nargs == 0
    if is_switch:
        if not isinstance(value, bool):
            raise _ArgumentError(f"{flag} is a switch: give true or false, got {value!r}")
        if isinstance(action, argparse.BooleanOptionalAction):
            return [flag if value else "--no-" + key.replace("_", "-")]
        return [flag] if value else []
    if isinstance(value, bool):
        raise _ArgumentError(f"{flag} takes a value, got {value!r}")
    if isinstance(value, list):
        if action.nargs in ("+", "*") or isinstance(action.nargs, int):
            return [flag, *map(str, value)] if value else ([flag] if action.nargs == "*" else [])
        return [flag, ",".join(map(str, value))]
    return [flag, str(value)]


def _output_words(parser, out_dir: Path, config) -> list[str]:
    """Where the task command writes: ``--out DIR`` (a results folder) or ``--json DIR/fit.json``."""
    if _option_action(parser, "--out") is not None:
        return ["--out", str(out_dir)]
    if _option_action(parser, "--json") is not None:
        return ["--json", str(out_dir / _JSON_NAMES[config.task])]
    raise BatchConfigError(
        f"{config.source}: 'python -m identify {config.task}' has neither --out nor --json: a batch cannot collect "
        "its results"
    )


def _file_sha256(path: Path) -> str:
    try:
        digest = hashlib.sha256()
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                digest.update(chunk)
        return digest.hexdigest()
    except OSError:
        return "unreadable"


def expand_jobs(config: BatchConfig) -> list[Job]:
    """The jobs of a batch: records x variants, each with a checked command line.

    Returns
    -------
    list of Job
        In record order, then variant order.

    Raises
    ------
    BatchConfigError
        An option the task command does not accept (or a bad value for it), naming the
        key, where it was set, and the config file.
    """
    parser = _command_parser(config.task)
    cores = os.cpu_count() or 1
    threads = max(1, cores // config.workers)
    jobs = []
    for record in config.records:
        for variant in config.variants:
            merged: dict = {}
            origin: dict = {}
            for where, table in (
                ("options", config.options),
                (f"records[{record.name}]", record.options),
                (f"variants[{variant.name}]", variant.options),
            ):
                for k, v in table.items():
                    merged[k] = v
                    origin[k] = where
            key = f"{record.name}__{variant.name}"
            out_dir = config.out / key
            out_words = _output_words(parser, out_dir, config)
            files = [str(f) for f in record.files]
            argv = [config.task, *files, *out_words]
            for k, v in merged.items():
                try:
                    words = _option_args(parser, k, v)
                    parser.parse_args([*files, *out_words, *words])
                except _ArgumentError as exc:
                    raise BatchConfigError(
                        f"{config.source}: {origin[k]}.{k} = {v!r}: not accepted by 'python -m identify "
                        f"{config.task}': {exc}"
                    ) from None
                argv.extend(words)
            try:
                parser.parse_args(argv[1:])
            except _ArgumentError as exc:  # e.g. two options that exclude each other
                raise BatchConfigError(
                    f"{config.source}: job {key}: 'python -m identify {config.task}' rejects the options: {exc}"
                ) from None
            stable = [w.replace(str(out_dir), "<out>") for w in argv]
            fingerprint = hashlib.sha256(
                json.dumps(
                    {"argv": stable, "record_sha256": "+".join(_file_sha256(f) for f in record.files)}, sort_keys=True
                ).encode()
            ).hexdigest()
            jobs.append(
                Job(
                    key=key,
                    task=config.task,
                    record=record.name,
                    variant=variant.name,
                    record_path=str(record.path),
                    argv=tuple(argv),
                    out_dir=str(out_dir),
                    fingerprint=fingerprint,
                    threads=threads,
                    timeout=config.timeout,
                )
            )
    return jobs


# -- the folder's configuration ----------------------------------------------------------------


def config_identity(config: BatchConfig) -> dict:
    """``{"config": file, "sha256": digest}``: the configuration's file and the SHA-256 of what
    defines its runs (task, options, records with their files and options, variants);
    comments, ``workers``, ``executor`` and ``timeout`` do not count."""
    source = Path(config.source)
    content = {
        "task": config.task,
        "options": config.options,
        "records": [
            [r.name, str(r.path), r.options, *([[str(f) for f in r.more]] if r.more else [])] for r in config.records
        ],
        "variants": [[v.name, v.options] for v in config.variants],
    }
    digest = hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode("utf-8")).hexdigest()
    return {"config": str(source.resolve()) if source.is_file() else str(source), "sha256": digest}


def _claim_folder(config: BatchConfig) -> None:
    """Make ``config.out`` this configuration's (under the batch lock), or refuse: a folder that
    another configuration ran into (another file, other runs) is never touched."""
    path = config.out / CONFIG_FILE
    mine = config_identity(config)
    if path.exists():
        recorded = _read_json(path)
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


def _read_json(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _notes_from(*documents) -> str:
    notes = []
    for doc in documents:
        if not isinstance(doc, dict):
            continue
        for key in ("notes", "assumptions"):
            value = doc.get(key)
            if isinstance(value, str):
                value = [value]
            if isinstance(value, list):
                notes.extend(str(v) for v in value if str(v) not in notes)
        record = doc.get("record")
        if isinstance(record, dict):
            notes.extend(str(v) for v in record.get("notes", []) or [] if str(v) not in notes)
    return "; ".join(notes)


def _output_unit(folder: Path) -> str:
    summary = _read_json(folder / "summary.json")
    if isinstance(summary, dict) and isinstance(summary.get("units"), dict):
        return str(summary["units"].get("output", ""))
    data = folder / "data.npz"
    if data.is_file():
        try:
            import numpy as np

            with np.load(data, allow_pickle=False) as z:
                return str(z["output_unit"]) if "output_unit" in z.files else ""
        except (OSError, ValueError, KeyError):
            return ""
    return ""


def _collect_fit(folder: Path) -> dict:
    fit = _read_json(folder / "fit.json")
    if not isinstance(fit, dict):
        raise RuntimeError("the command finished but wrote no readable fit.json")
    success = fit.get("success")
    return _fit_columns(folder, fit, "" if success is None else ("converged" if success else "not converged"), fit)


def _fit_columns(folder: Path, fit: dict, verdict: str, source: dict) -> dict:
    """A summary row of a fit's numbers (``fit``: rms, max_error_pct, reduced_chi2), the
    ``verdict``, the output unit and the notes of ``source`` and the manifest."""
    return dict(
        rms=_number(fit.get("rms")),
        max_error_pct=_number(fit.get("max_error_pct")),
        statistic_name="reduced_chi2",
        statistic=_number(fit.get("reduced_chi2")),
        verdict=verdict,
        output_unit=_output_unit(folder),
        notes=_notes_from(source, _read_json(folder / "manifest.json")),
    )


def _collect_study(folder: Path) -> dict:
    summary = _read_json(folder / "summary.json")
    if not isinstance(summary, dict):
        raise RuntimeError("the command finished but wrote no readable summary.json")
    fit = summary.get("fit") or {}
    posterior = summary.get("posterior") or {}
    converged = posterior.get("converged")
    verdict = "" if converged is None else ("posterior converged" if converged else "posterior NOT converged")
    return _fit_columns(folder, fit, verdict, summary)


def _collect_diagnose(folder: Path) -> dict:
    candidates = [folder / "diagnosis.json", *sorted(folder.glob("diagnos*.json"))]
    diagnosis = next((d for d in map(_read_json, candidates) if isinstance(d, dict)), None)
    if diagnosis is None:
        raise RuntimeError("the command finished but wrote no readable diagnosis JSON")
    ranking = [c for c in diagnosis.get("ranking") or [] if isinstance(c, dict)]
    statistic_name = str(diagnosis.get("statistic") or "delta_bic")
    statistic, top = None, ""
    if ranking:
        top = str(ranking[0].get("effect") or "")
        statistic = _number(ranking[0].get(statistic_name))
    status = str(diagnosis.get("status", ""))
    missing = diagnosis.get("missing")
    tied = [str(name) for name in diagnosis.get("tied") or []]
    if missing:
        verdict = f"{status}: add {missing}"
    elif tied:
        verdict = f"{status}: {' | '.join(tied)}"
    elif top:
        verdict = f"{status} (best candidate {top})"
    else:
        verdict = status
    return dict(
        rms=_number(diagnosis.get("rms")),
        max_error_pct=_number(diagnosis.get("max_error_pct")),
        statistic_name=f"{statistic_name}[{top}]" if top else statistic_name,
        statistic=statistic,
        verdict=verdict,
        output_unit=_output_unit(folder),
        notes=_notes_from(diagnosis, _read_json(folder / "manifest.json")),
    )


#: task -> function reading a finished run's folder into summary figures.
COLLECTORS: dict[str, Callable[[Path], dict]] = {
    "fit": _collect_fit,
    "study": _collect_study,
    "diagnose": _collect_diagnose,
}


def _assumptions(argv) -> list[str]:
    """What a job's options make the run assume, in plain words (for the summary's notes)."""
    argv = list(argv)

    def value(flag):
        return argv[argv.index(flag) + 1] if flag in argv[:-1] else None

    notes = []
    time_column = value("--time-column")
    if time_column is not None and time_column.lower() == "none":
        notes.append("no time column: time is the sample index (time constants in samples)")
    sigma = value("--noise-sigma")
    if sigma is not None and sigma.lower() == "free":
        notes.append("no quiet segment used: noise sigma is a free parameter, estimated from the residual")
    elif sigma is not None:
        notes.append(f"no quiet segment used: noise sigma = {sigma} given in the config")
    return notes


def _error_from_log(log_text: str, returncode: int) -> str:
    """The most telling line of a failed command's output (its last error line)."""
    lines = [ln.strip() for ln in log_text.splitlines() if ln.strip()]
    for line in reversed(lines):
        if re.match(r"^(error|[A-Za-z_.]*(Error|Exception))\b", line, flags=re.IGNORECASE):
            return line[:500]
    tail = lines[-1][:500] if lines else "(no output)"
    return f"exit code {returncode}: {tail}"


def _is_finding(log_text: str) -> bool:
    """Whether a command's exit code 1 is a finding (its solver or chain did NOT converge,
    :data:`identify.defaults.EXIT_FINDING`) rather than a failure (an ``error:`` line)."""
    lines = [ln.strip() for ln in log_text.splitlines()]
    return any("NOT CONVERGE" in ln.upper() and ln.startswith("exit code 1") for ln in lines) and not any(
        ln.lower().startswith("error") for ln in lines
    )


def _job_environment(threads: int) -> dict:
    from ..commands import package_environment

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
    from ..data.locks import FolderBusyError, FolderLock

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
    from ..commands import PARENT_VARIABLE

    for marker in (DONE_MARKER, FAILED_MARKER):
        (folder / marker).unlink(missing_ok=True)
    atomic_write(folder / _JOB_FILE, json.dumps(asdict(job), indent=2) + "\n")
    command = [sys.executable, "-m", "identify", *job.argv]
    started = time.perf_counter()
    error = ""
    stopped = ""
    env, pass_fds = lock.child_environment(_job_environment(job.threads))
    env[PARENT_VARIABLE] = str(os.getpid())  # the command ends (SIGTERM) if the batch dies
    log_fd = open_no_follow(folder / _LOG_FILE, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)  # never through a link
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
    log_text = (folder / _LOG_FILE).read_text(encoding="utf-8", errors="replace")
    if stopped == "timeout" and returncode != 0:
        error = f"timed out after {job.timeout:g} s (the config's timeout); stopped"
    elif (stopped == "stop" and returncode != 0) or returncode == 130:
        return JobResult(
            **base,
            status="interrupted",
            seconds=seconds,
            error="interrupted (its completed work is kept); rerun the batch to resume it",
        )
    elif returncode not in (0, None) and not (returncode == 1 and _is_finding(log_text)):
        error = _error_from_log(log_text, returncode)
    result = None
    if not error:
        try:
            figures = COLLECTORS[job.task](folder)
            stated = [n for n in _assumptions(job.argv) if n not in figures.get("notes", "")]
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
    payload = _read_json(Path(job.out_dir) / DONE_MARKER)
    if not isinstance(payload, dict) or payload.get("fingerprint") != job.fingerprint:
        return None
    try:
        result = JobResult.from_dict(payload["result"])
    except (KeyError, TypeError):
        return None
    result.status = "skipped"
    return result


# -- executors ----------------------------------------------------------------------------------

#: name -> executor class (``cls(workers, **executor_options)``).
EXECUTORS: dict[str, type] = {}


def register_executor(name: str):
    """Class decorator: make an executor available to configs as ``executor = name``."""

    def decorate(cls):
        EXECUTORS[name] = cls
        return cls

    return decorate


def get_executor(name: str, workers: int, **options):
    """An executor instance by name (clear error listing the known names)."""
    try:
        cls = EXECUTORS[name]
    except KeyError:
        raise ValueError(f"unknown executor {name!r}; known: {', '.join(EXECUTORS)}") from None
    return cls(workers, **options)


@register_executor("local")
class LocalExecutor:
    """Jobs run from ``workers`` threads of this process (each job is its own subprocess).

    Parameters
    ----------
    workers : int
        Jobs at the same time.
    start_method : str, optional
        Accepted for configs written for the former process pool; ignored.
    """

    def __init__(self, workers: int, start_method: str | None = None):
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="batch-job")
        self._futures: dict = {}

    def submit_all(self, fn: Callable, jobs: Iterable[Job]) -> Iterator[tuple[Job, object]]:
        """Yield ``(job, result)`` as jobs finish; an exception in ``fn`` is yielded as the result.

        A job cancelled before it started (:meth:`cancel`) is yielded with None as its result.
        """
        from concurrent.futures import CancelledError, as_completed

        self._futures = {self._pool.submit(fn, job): job for job in jobs}
        try:
            for future in as_completed(self._futures):
                job = self._futures[future]
                try:
                    yield job, future.result()
                except CancelledError:
                    yield job, None
                except Exception as exc:  # run_job itself failed
                    yield job, exc
        finally:
            self.cancel()

    def cancel(self):
        """Drop the jobs that have not started."""
        for future in self._futures:
            future.cancel()

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=True)


@register_executor("dask")
class DaskExecutor:
    """Jobs on a ``dask.distributed`` cluster (``pip install .[dask]``).

    Parameters
    ----------
    workers : int
        Workers of the local cluster started when no ``address`` is given.
    address : str, optional
        A running scheduler (e.g. ``"tcp://10.0.0.5:8786"``); its workers need this
        package installed and the records and output folder on a shared file system.
    processes : bool, default True
        Local cluster only: worker processes (True) or threads in this process.
    threads_per_worker : int, default 1
        Local cluster only.
    """

    def __init__(self, workers: int, address: str | None = None, processes: bool = True, threads_per_worker: int = 1):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise RuntimeError(
                "executor 'dask' needs dask.distributed: pip install 'msma-gpi[dask]' (or pip install distributed)"
            ) from None
        self._cluster = None
        if address:
            self._client = Client(address)
        else:
            self._cluster = LocalCluster(
                n_workers=workers, threads_per_worker=threads_per_worker, processes=processes, dashboard_address=None
            )
            self._client = Client(self._cluster)

    def submit_all(self, fn: Callable, jobs: Iterable[Job]) -> Iterator[tuple[Job, object]]:
        from distributed import as_completed

        futures = {}
        for job in jobs:
            future = self._client.submit(fn, job, pure=False, key=f"msma-batch-{job.key}-{time.monotonic_ns()}")
            futures[future] = job
        self._futures = futures
        try:
            for future in as_completed(list(futures)):
                job = futures[future]
                if future.cancelled():
                    yield job, None
                    continue
                try:
                    yield job, future.result()
                except Exception as exc:
                    yield job, exc
        finally:
            self.cancel()

    def cancel(self):
        """Drop the jobs that have not started (running ones see the batch's stop file)."""
        for future in getattr(self, "_futures", {}):
            future.cancel()

    def close(self):
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


# -- summary ----------------------------------------------------------------------------------

_COLUMNS = (
    "key",
    "record",
    "variant",
    "task",
    "status",
    "rms",
    "max_error_pct",
    "statistic_name",
    "statistic",
    "verdict",
    "seconds",
    "error",
    "report",
    "notes",
)


def _fmt(value, digits=4) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _status_counts(results) -> str:
    """``"6 runs: 3 ok, 1 finished earlier (skipped), 1 failed, 1 pending."``"""
    labels = (
        ("ok", "ok"),
        ("skipped", "finished earlier (skipped)"),
        ("failed", "failed"),
        ("interrupted", "interrupted (rerun to resume)"),
        ("pending", "pending"),
    )
    parts = [f"{sum(r.status == key for r in results)} {label}" for key, label in labels]
    parts = [p for p in parts if not p.startswith("0 ")] or ["none"]
    n_not_converged = sum(r.not_converged for r in results)
    if n_not_converged:
        parts.append(f"{n_not_converged} of the finished NOT converged")
    return f"{len(results)} runs: {', '.join(parts)}."


def _md(value) -> str:
    """Text for a Markdown table cell, shown as written: HTML escaped (``<`` ``>`` ``&``), the
    Markdown marks that format or link (``\\ ` * [ ] | !`` and ``_`` outside a word) escaped
    by a backslash, line breaks as spaces."""
    text = html.escape(" ".join(str(value).split()), quote=False)
    text = re.sub(r"([\\`*\[\]|!])", r"\\\1", text)
    return re.sub(r"(?<![A-Za-z0-9_])_|_(?![A-Za-z0-9_])", r"\\_", text)


def _md_url(path: str) -> str:
    """A relative link target for Markdown: every character but ``A-Z a-z 0-9 / . - _ ~`` percent-encoded."""
    from urllib.parse import quote

    return quote(str(path), safe="/.-_~")


def write_summary(out, results: list[JobResult], config: BatchConfig | None = None) -> None:
    """Write ``summary.csv``, ``summary.md`` and ``index.html`` into ``out`` (each atomically).

    Parameters
    ----------
    out : path-like
        The batch folder.
    results : list of JobResult
        One row each, in the given order.
    config : BatchConfig, optional
        Named in the page headings.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(_COLUMNS)
    for r in results:
        row = r.to_dict()
        writer.writerow(
            [("" if row[c] is None else (repr(row[c]) if isinstance(row[c], float) else row[c])) for c in _COLUMNS]
        )
    atomic_write(out / "summary.csv", buffer.getvalue())

    title = f"Batch {config.task} runs from {config.source.name}" if config else "Batch runs"
    counts = _status_counts(results)
    md = [f"# {_md(title)}", "", _md(counts), ""]
    md.append("| run | status | RMS | max error % | statistic | verdict | time [s] | error / notes |")
    md.append("|---|---|---|---|---|---|---|---|")
    for r in results:
        link = f"[{_md(r.key)}]({_md_url(r.report)})" if r.report else _md(r.key)
        stat = f"{r.statistic_name} = {_fmt(r.statistic)}" if r.statistic is not None else ""
        unit = f" {r.output_unit}" if r.output_unit and r.rms is not None else ""
        md.append(
            f"| {link} | {_md(r.status)} | {_md(_fmt(r.rms) + unit)} | {_md(_fmt(r.max_error_pct, 3))} | {_md(stat)} | "
            f"{_md(r.verdict)} | {r.seconds:.1f} | {_md(r.error or r.notes)} |"
        )
    atomic_write(out / "summary.md", "\n".join(md) + "\n")

    atomic_write(out / "index.html", _index_page(title, counts, results))


#: A diagnosis' status in the verdict column, in words.
_STATUS_WORDS = {"missing_effect": "an effect is missing", "not_adequate": "not adequate"}


def _statistic_label(name: str) -> str:
    """A summary row's statistic name for a person: ``reduced_chi2`` -> "reduced χ²",
    ``delta_bic[thermal]`` -> "BIC gain of <code>thermal</code>" (markup)."""
    from ..output.page import escape

    base, _, effect = name.partition("[")
    label = {"reduced_chi2": "reduced χ²", "delta_bic": "BIC gain"}.get(base, base.replace("_", " "))
    return escape(label) + (f" of <code>{escape(effect.rstrip(']'))}</code>" if effect else "")


def _index_page(title: str, counts: str, results: list[JobResult]) -> str:
    """``index.html``: one row per run, links to each run's report and log (:func:`identify.output.page.html_page`)."""
    from ..output.page import escape, html_page, plain_text

    rows = []
    for r in results:
        link = f'<a href="{escape(r.report)}">{escape(r.key)}</a>' if r.report else plain_text(r.key)
        log = f' <a href="{escape(r.key)}/{_LOG_FILE}">log</a>'
        css = f' class="{r.status}"' if r.status in ("failed", "interrupted") else ""
        stat = f"{_statistic_label(r.statistic_name)} = {_fmt(r.statistic)}" if r.statistic is not None else ""
        verdict = str(r.verdict or "")
        for word, words in _STATUS_WORDS.items():
            verdict = verdict.replace(word, words)
        unit = escape(unit_text(r.output_unit)) if r.rms is not None else ""
        rows.append(
            f"<tr{css}><td>{link}{log}</td><td>{plain_text(r.record)}</td><td>{plain_text(r.variant)}</td>"
            f"<td>{escape(r.status)}</td><td>{_fmt(r.rms)} {unit}</td><td>{_fmt(r.max_error_pct, 3)}</td>"
            f"<td>{stat}</td><td>{plain_text(verdict)}</td><td>{r.seconds:.1f}</td>"
            f"<td>{plain_text(r.error or r.notes or '')}</td></tr>"
        )
    header = (
        "<tr><th>run</th><th>record</th><th>variant</th><th>status</th><th>residual RMS</th><th>max error [%]</th>"
        "<th>comparison statistic</th><th>verdict</th><th>run time [s]</th><th>error / assumptions</th></tr>"
    )
    return html_page(
        title,
        [
            f"<p>{escape(counts)} RMS and max error over the energised part of each record; max error in % of the "
            "measured output range. Each run name links to its report (when it has one).</p>",
            '<div class="table-box"><table id="runs">',
            header,
            *rows,
            "</table></div>",
        ],
    )


def unit_text(unit) -> str:
    """A unit as a page shows it (``um`` -> ``µm``)."""
    from ..output.plots import unit_label

    return unit_label(unit) if unit else ""


# -- the batch ----------------------------------------------------------------------------------


def run_batch(
    config: BatchConfig, *, progress: bool = True, rerun: bool = False, stream=None, announce=None
) -> BatchResult:
    """Run every job of ``config`` that has not finished yet, then write the summary.

    The batch folder is locked for the whole run; Ctrl-C and SIGTERM stop the batch as
    the module docstring says (the result's jobs are then ``interrupted``).

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
    from ..data.locks import FolderLock

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
        import threading

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
    from tqdm import tqdm

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
