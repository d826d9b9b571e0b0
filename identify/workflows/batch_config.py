"""A batch's configuration and its jobs: the TOML file read and checked, records x variants
expanded into command lines.

:func:`load_config` reads a batch TOML file (format in :mod:`identify.workflows.batch`) and
:func:`parse_config` checks every key into a :class:`BatchConfig` of :class:`RecordSpec` and
:class:`VariantSpec`; any invalid key is a :class:`BatchConfigError` naming the file and the
key. :func:`expand_jobs` makes the :class:`Job` of every record x variant: the exact
``python -m identify TASK ...`` arguments, each checked against the task command's own
argument parser before anything runs, and a fingerprint that changes when the arguments or
the record files change. :func:`config_identity` is what makes two configurations the same
one (the batch folder belongs to one configuration). Nothing here runs or writes anything.
"""

from __future__ import annotations

import argparse
import glob as _glob
import hashlib
import importlib
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..commands import COMMANDS, add_command_arguments
from ..data.fileio import toml_module
from .batch_executors import EXECUTORS

__all__ = [
    "TASKS",
    "SEVERAL_RECORD_TASKS",
    "BatchConfigError",
    "RecordSpec",
    "VariantSpec",
    "BatchConfig",
    "Job",
    "load_config",
    "parse_config",
    "expand_jobs",
    "config_identity",
]

#: The commands a batch can run, each a registered ``python -m identify`` command.
TASKS = ("fit", "diagnose", "study")
# the file a task writes when it only has a --json option
_JSON_NAMES = {"fit": "fit.json", "diagnose": "diagnosis.json", "study": "summary.json"}

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
    """A validated batch configuration (the file format: :mod:`identify.workflows.batch`).

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
        The parsed TOML (the keys: :mod:`identify.workflows.batch`).
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
    """``key = value`` as command-line words for ``parser`` (the rules: :mod:`identify.workflows.batch`)."""
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


# -- the configuration's identity ----------------------------------------------------------


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
