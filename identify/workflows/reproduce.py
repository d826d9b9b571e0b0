"""Rerun a finished run from its manifest and check that it gives the same numbers.

``python -m identify reproduce DIR [--out NEWDIR]`` (see docs/reproducibility.md):

1. read ``DIR/manifest.json`` (seed, data file + SHA-256, settings, package versions,
   git commit, command line);
2. check the data file still has the recorded SHA-256: a changed (or missing) file is a
   :class:`DataChangedError` that says which file and both hashes, and nothing runs;
3. rerun the same command with the same settings and seed into ``NEWDIR`` (default
   ``DIR-reproduced``), as a subprocess ``python -m identify COMMAND ...``. ``NEWDIR``
   must be new (or an empty folder): a reproduction never writes into an existing study
   (:class:`OutputExistsError`). ``DIR`` is locked while it is read, ``NEWDIR`` while the
   rerun writes it (:mod:`identify.data.locks`);
4. compare the two folders:

   * every dataset of ``chain.h5`` (the emcee chain, log-probabilities, acceptance
     counts, random state) and of ``data.npz``: **bit-identical**, or the largest absolute
     difference and how many elements differ;
   * every number in ``fit.json``, ``summary.json`` and any diagnosis JSON, except wall
     times: equal, or the path of each number that differs with both values;
   * package versions and the git commit of the two runs (the usual cause of differences).

The verdict (:class:`ReproductionReport`) is written to ``NEWDIR/reproduction.json`` and
printed. Bit-identical results need the same platform, package versions and thread
counts: numba's parallel GPI kernel computes every parameter set independently, but BLAS
reductions in the least squares change in the last bits with the thread count. A run made
by ``batch`` records its thread count in ``DIR/batch_job.json``, and the rerun gets the same.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib
import json
import math
import subprocess
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import h5py
import numpy as np

from ..commands import COMMANDS, add_command_arguments, package_environment, package_root
from ..data.fileio import atomic_write
from ..data.hdf5 import open_hdf5
from ..data.locks import FolderLock
from ..defaults import EXIT_FINDING
from ..fitting.posterior import ChainFileError, chain_info
from ..output.results import DamagedResultsError, jsonable, load_data, read_json

__all__ = [
    "DataChangedError",
    "ManifestError",
    "OutputExistsError",
    "ArrayComparison",
    "NumberDifference",
    "ReproductionReport",
    "read_manifest",
    "locate_data",
    "DataLocation",
    "rerun_arguments",
    "compare_arrays",
    "compare_json",
    "compare_runs",
    "reproduce",
    "recorded_threads",
    "TIMING_KEYS",
    "REPORT_FILE",
    "REPRODUCIBLE_COMMANDS",
    "REPLAYED_OPTIONS",
    "NOT_REPLAYED_OPTIONS",
]

#: JSON keys whose values are wall times or timestamps: never compared.
TIMING_KEYS = frozenset(
    {"seconds", "started", "finished", "start_time", "end_time", "time_seconds", "wall_seconds", "runs"}
)
#: The verdict file written into the new folder.
REPORT_FILE = "reproduction.json"
#: JSON result files compared number by number (those present in either folder).
_JSON_FILES = ("fit.json", "summary.json", "diagnosis.json")
#: Array files compared dataset by dataset.
_ARRAY_FILES = ("chain.h5", "data.npz")
#: The commands whose runs are reproduced (those that write a manifest).
REPRODUCIBLE_COMMANDS = ("study", "fit")
#: Options a rerun takes from the manifest's settings: the computation's, never where it writes.
REPLAYED_OPTIONS = frozenset(
    {
        "time_column",
        "input_column",
        "output_column",
        "input_unit",
        "output_unit",
        "every",
        "effects",
        "n_operators",
        "reading",
        "noise_sigma",
        "seed",
        "n_starts",
        "free_alpha",
        "walkers",
        "max_steps",
        "check_every",
        "priors",
        "all_terms",
        "moves",
        "no_report",
        "no_diagnose",
        "progress",
    }
)
#: Options never taken from a manifest: where the run wrote (the rerun writes only into
#: NEWDIR, given by ``reproduce`` itself), how it spoke, and the earlier study its report was
#: compared with (another folder, which changes no number of the run).
NOT_REPLAYED_OPTIONS = frozenset({"out", "json", "force", "verbose", "quiet", "help", "compare"})
_MAX_LISTED = 25


class ManifestError(ValueError):
    """A results folder without a usable manifest.json."""


class DataChangedError(ValueError):
    """The data file of a run is missing or no longer has the SHA-256 recorded in its manifest."""


class OutputExistsError(ValueError):
    """The folder for the rerun already holds something (e.g. another study)."""


@dataclass(frozen=True)
class ArrayComparison:
    """One array (an HDF5 dataset or an npz member) in the original run and the rerun.

    Attributes
    ----------
    file : str
        ``chain.h5`` or ``data.npz``.
    name : str
        Dataset path inside the file (e.g. ``mcmc/chain``).
    identical : bool
        Same shape, dtype and bytes (NaNs in the same places count as equal).
    shape_original, shape_rerun : tuple of int or None
        None when the array is missing from that run.
    max_abs_difference : float or None
        Largest ``|a - b|`` over numeric arrays of equal shape (None otherwise).
    n_different : int
        Elements that differ (equal shapes), else the larger size.
    numeric : bool
        False for text arrays (metadata such as the data file's name).
    values : tuple or None
        ``(original, rerun)`` of a differing 0-d text array.
    """

    file: str
    name: str
    identical: bool
    shape_original: tuple | None
    shape_rerun: tuple | None
    max_abs_difference: float | None = None
    n_different: int = 0
    numeric: bool = True
    values: tuple | None = None

    def describe(self) -> str:
        where = f"{self.file}:{self.name}"
        if not self.numeric and not self.identical and self.values is not None:
            return f"{where}: {self.values[0]!r} -> {self.values[1]!r}"
        if self.identical:
            return f"{where}: bit-identical {self.shape_original}"
        if self.shape_original is None or self.shape_rerun is None:
            missing = "original" if self.shape_original is None else "rerun"
            return f"{where}: missing in the {missing}"
        if self.shape_original != self.shape_rerun:
            return f"{where}: shape {self.shape_original} -> {self.shape_rerun}"
        diff = "" if self.max_abs_difference is None else f", max |difference| {self.max_abs_difference:.3g}"
        return f"{where}: {self.n_different} element(s) differ{diff}"


@dataclass(frozen=True)
class NumberDifference:
    """A value in a result JSON that differs between the two runs.

    Attributes
    ----------
    file : str
    path : str
        Location inside the JSON, e.g. ``fit.rms`` or ``parameters[3].median``.
    original, rerun : object
        The two values (None when missing on one side).
    abs_difference : float or None
        ``|original - rerun|`` for two numbers.
    """

    file: str
    path: str
    original: object
    rerun: object
    abs_difference: float | None = None

    def describe(self) -> str:
        diff = "" if self.abs_difference is None else f" (|difference| {self.abs_difference:.3g})"
        return f"{self.file}:{self.path}: {self.original!r} -> {self.rerun!r}{diff}"


@dataclass
class ReproductionReport:
    """The verdict of a reproduction.

    Attributes
    ----------
    original, rerun : str
        The two results folders.
    command : list of str
        The arguments given to ``python -m identify`` for the rerun.
    data_file : str
        The data file, whose SHA-256 matched the manifest.
    returncode : int
        Exit code of the rerun command.
    arrays : list of ArrayComparison
    numbers : list of NumberDifference
        Only the values that differ.
    n_numbers_compared : int
    version_differences : dict
        ``{package: [original, rerun]}`` for every package whose version differs.
    commit_difference : list or None
        ``[original, rerun]`` git commits (and dirty flags) when they differ.
    threads : int or None
        The numba/BLAS thread count the rerun was given (from the batch that ran the
        original, ``DIR/batch_job.json``); None: the current environment's.
    expected_returncode : int, default 0
        The exit code the original run had (:func:`original_returncode`): 1 for a study
        whose chain did not converge or a fit whose solver did not; the rerun must end the
        same way.
    """

    original: str
    rerun: str
    command: list
    data_file: str
    returncode: int
    arrays: list = field(default_factory=list)
    numbers: list = field(default_factory=list)
    n_numbers_compared: int = 0
    version_differences: dict = field(default_factory=dict)
    commit_difference: list | None = None
    threads: int | None = None
    expected_returncode: int = 0

    @property
    def chain_identical(self) -> bool | None:
        """True/False for the chain.h5 datasets; None when the run has no chain."""
        chain = [a for a in self.arrays if a.file == "chain.h5"]
        return None if not chain else all(a.identical for a in chain)

    @property
    def max_chain_difference(self) -> float | None:
        values = [
            a.max_abs_difference for a in self.arrays if a.file == "chain.h5" and a.max_abs_difference is not None
        ]
        return max(values) if values else None

    @property
    def identical(self) -> bool:
        """The rerun succeeded and every numeric array and every result value is the same.

        Text metadata arrays (e.g. the data file's name in ``data.npz`` after ``--data``)
        are listed when they differ but do not count.
        """
        return (
            self.returncode == self.expected_returncode
            and all(a.identical for a in self.arrays if a.numeric)
            and not self.numbers
        )

    def describe(self) -> str:
        """Plain-words verdict: what matched, what differs and by how much, and likely causes."""
        lines = [f"reproduce {self.original} -> {self.rerun}", f"  data {self.data_file}: SHA-256 matches the manifest"]
        if self.returncode != self.expected_returncode:
            lines.append(
                f"  the rerun FAILED with exit code {self.returncode}, the original's was {self.expected_returncode} "
                f"(see {self.rerun}/reproduce.log)"
            )
        metadata = [a for a in self.arrays if not a.numeric and not a.identical]
        if self.identical:
            what = "chain.h5 bit-identical, " if self.chain_identical else ""
            n_numeric = sum(a.numeric for a in self.arrays)
            lines.append(
                f"  IDENTICAL: {what}{n_numeric} numeric array(s) and {self.n_numbers_compared} result value(s) all "
                "equal"
            )
            for a in metadata:
                lines.append("    metadata differs (not a result): " + a.describe())
        else:
            n_same = sum(a.identical for a in self.arrays)
            lines.append(f"  arrays: {n_same} of {len(self.arrays)} bit-identical")
            for a in self.arrays:
                if not a.identical:
                    lines.append("    " + a.describe())
            lines.append(f"  result values: {len(self.numbers)} of {self.n_numbers_compared} differ")
            for d in self.numbers[:_MAX_LISTED]:
                lines.append("    " + d.describe())
            if len(self.numbers) > _MAX_LISTED:
                lines.append(f"    ... and {len(self.numbers) - _MAX_LISTED} more (see {REPORT_FILE})")
        if self.version_differences:
            changed = ", ".join(f"{k} {v[0]} -> {v[1]}" for k, v in sorted(self.version_differences.items()))
            lines.append(f"  versions differ: {changed}")
        if self.commit_difference:
            lines.append(f"  git commit differs: {self.commit_difference[0]} -> {self.commit_difference[1]}")
        if self.threads is not None:
            lines.append(f"  rerun with {self.threads} numba/BLAS thread(s), as the batch ran the original")
        if not self.identical and not self.version_differences and not self.commit_difference:
            lines.append(
                "  same versions and commit: differences come from the platform (thread counts, CPU, libraries)"
            )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.update(
            identical=self.identical,
            chain_identical=self.chain_identical,
            max_chain_difference=self.max_chain_difference,
        )
        return d


# -- manifest and data --------------------------------------------------------------------------


def read_manifest(directory) -> dict:
    """``DIR/manifest.json`` checked for the keys a rerun needs.

    Raises
    ------
    ManifestError
        Missing folder or file, invalid JSON, or missing ``data.file``/``data.sha256``/``settings``.
    """
    directory = Path(directory)
    path = directory / "manifest.json"
    if not directory.is_dir():
        raise ManifestError(f"{directory}: no such results folder")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ManifestError(
            f"{path}: missing; only a folder written by a run with a manifest can be reproduced"
        ) from None
    except (OSError, ValueError) as exc:
        raise ManifestError(f"{path}: unreadable or not valid JSON ({exc})") from None
    data = manifest.get("data") if isinstance(manifest, dict) else None
    if not isinstance(data, dict) or not data.get("file") or not data.get("sha256"):
        raise ManifestError(f"{path}: needs data.file and data.sha256 (the data the run used)")
    if not isinstance(manifest.get("settings"), dict):
        raise ManifestError(f"{path}: needs a 'settings' object (the run's options)")
    return manifest


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True)
class DataLocation:
    """Where a run's data file was found.

    Attributes
    ----------
    path : Path
        The file (absolute), whose SHA-256 matches the manifest.
    argument : str
        What to pass to the rerun: the manifest's own (relative) path when the file was
        found relative to ``cwd``, else the absolute path.
    cwd : Path or None
        The folder to rerun from so that ``argument`` names the file (None: any).
    """

    path: Path
    argument: str
    cwd: Path | None


def locate_data(manifest: dict, directory, data=None) -> DataLocation:
    """The run's data file, checked against the manifest's SHA-256.

    A relative ``data.file`` is looked up relative to the current folder, the folder the
    run was started from (``manifest["cwd"]`` when recorded), the project root and the
    results folder's parent; the rerun then starts from that folder with the same
    relative path, so even the recorded file name is the same.

    Parameters
    ----------
    manifest : dict
    directory : path-like
        The results folder.
    data : path-like, optional
        Use this file instead of ``data.file`` (e.g. the record moved); its hash must match.

    Returns
    -------
    DataLocation

    Raises
    ------
    DataChangedError
        The file is missing, or its SHA-256 differs from the manifest's (both hashes named).
    """
    recorded = manifest["data"]["file"]
    expected = manifest["data"]["sha256"]
    if data is not None:
        candidates = [(Path(data), None)]
    else:
        p = Path(recorded)
        bases = [Path.cwd()]
        if manifest.get("cwd"):
            bases.append(Path(manifest["cwd"]))
        bases += [package_root(), Path(directory).resolve().parent]
        candidates = [(p, None)] if p.is_absolute() else [(b / p, b) for b in bases]
    found = next(((c, b) for c, b in candidates if c.is_file()), None)
    if found is None:
        tried = ", ".join(str(c) for c, _ in candidates)
        raise DataChangedError(
            f"the run's data file {recorded} is missing (looked for {tried}); pass --data PATH if it moved"
        )
    path, base = found
    actual = _sha256(path)
    if actual != expected:
        raise DataChangedError(
            f"{path}: the data changed since the run: SHA-256 is {actual}, the manifest records {expected}. "
            "A rerun would not reproduce the run; restore the original file (or pass --data PATH to it)."
        )
    if base is not None:
        return DataLocation(path.resolve(), recorded, base.resolve())
    return DataLocation(path.resolve(), str(path.resolve()), None)


def _locate_records(manifest: dict, directory, first: DataLocation) -> list[str] | None:
    """The rerun's arguments of a run of several records (``manifest["data"]["records"]``), each
    file found as :func:`locate_data` finds one and checked against its own SHA-256 (a changed
    or missing record is a :class:`DataChangedError` naming it); None for a run of one record.
    Every record is named as the first is (the manifest's relative path from the same folder)
    when found there, else by its absolute path."""
    records = manifest["data"].get("records")
    if not isinstance(records, list) or len(records) < 2:
        return None
    arguments = [first.argument]
    for entry in records[1:]:
        one = {**manifest, "data": {"file": entry["file"], "sha256": entry["sha256"]}}
        location = locate_data(one, directory)
        same_base = first.cwd is not None and location.cwd == first.cwd
        arguments.append(location.argument if same_base else str(location.path))
    return arguments


def _command_name(manifest: dict) -> str:
    name = manifest.get("settings", {}).get("command") or manifest.get("task")
    if isinstance(name, str) and name in COMMANDS:
        return _reproducible(name)
    command = manifest.get("command")
    for word in (command if isinstance(command, list) else [])[1:]:
        if word in COMMANDS:
            return _reproducible(word)
    # no command line (e.g. run from Python): the one command whose options cover the settings
    settings = set(manifest.get("settings", {}))
    matches = []
    for name, module_name in COMMANDS.items():
        if name not in REPRODUCIBLE_COMMANDS:
            continue
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
        add_command_arguments(parser, module)
        if settings <= {a.dest for a in parser._actions}:
            matches.append(name)
    if len(matches) == 1:
        return matches[0]
    raise ManifestError(
        "the manifest does not say which command produced the run (no 'command' list naming one of "
        f"{', '.join(COMMANDS)})"
    )


def _reproducible(name: str) -> str:
    if name not in REPRODUCIBLE_COMMANDS:
        raise ManifestError(
            f"the manifest names the command {name!r}; reproduce reruns only {', '.join(REPRODUCIBLE_COMMANDS)} runs"
        )
    return name


def _check_settings(settings: dict, parser) -> None:
    """Refuse a manifest whose settings name an option ``reproduce`` never replays (an output
    path such as ``json``: the rerun writes only into its new folder)."""
    options = {action.dest for action in parser._actions if action.option_strings}
    refused = sorted(k for k in settings if k in options and k not in REPLAYED_OPTIONS)
    if refused:
        shown = ", ".join(f"{k} = {settings[k]!r}" for k in refused)
        raise ManifestError(
            f"the manifest's settings hold {shown}, which reproduce never takes from a manifest (it replays only "
            "the computation's options; the rerun writes only into its new folder). Nothing was run; a manifest "
            "written by fit or study holds no such setting"
        )


def rerun_arguments(manifest: dict, data_file, out) -> list[str]:
    """The ``python -m identify`` arguments that redo the run into ``out``.

    Built from the manifest's ``settings`` through the command's own argument parser:
    each setting whose name is an option's destination becomes that option, the record
    path becomes ``data_file``, the output folder ``out`` and the seed the manifest's.
    Options left at their defaults are passed explicitly too, so a changed default cannot
    change the rerun. Only :data:`REPLAYED_OPTIONS` are taken from the manifest; output
    paths never are.

    Raises
    ------
    ManifestError
        Unknown command (or one not in :data:`REPRODUCIBLE_COMMANDS`), a setting naming an
        option that is never replayed (e.g. ``json``: an output path), or a setting the
        command's parser no longer accepts.
    """
    name = _command_name(manifest)
    module = importlib.import_module(COMMANDS[name])
    parser = argparse.ArgumentParser(prog=f"python -m identify {name}", add_help=False, allow_abbrev=False)
    add_command_arguments(parser, module)
    settings = dict(manifest["settings"])
    _check_settings(settings, parser)
    if manifest.get("seed") is not None:
        settings["seed"] = manifest["seed"]
    positional, optional = [], []
    for action in parser._actions:
        dest = action.dest
        if not action.option_strings:  # positional: the record
            if dest in ("record", "data", "path", "csv", "record_path", "input", "file") or not positional:
                several = isinstance(data_file, (list, tuple))
                positional += [str(f) for f in data_file] if several else [str(data_file)]
            continue
        flag = next((s for s in action.option_strings if s.startswith("--")), action.option_strings[0])
        if dest in ("out", "out_dir", "output", "outdir"):
            optional += [flag, str(out)]
            continue
        if dest not in REPLAYED_OPTIONS or dest not in settings:
            continue
        value = settings[dest]
        if action.nargs == 0:
            const = action.const if action.const is not None else True
            if isinstance(action, argparse.BooleanOptionalAction):
                optional.append(flag if value else "--no-" + flag[2:])
            elif value == const:
                optional.append(flag)
            continue
        if value is None:
            continue
        if isinstance(value, list):
            if action.nargs in ("+", "*") or isinstance(action.nargs, int):
                optional += [flag, *map(str, value)]
            else:
                optional += [flag, ",".join(map(str, value))]
        else:
            optional += [flag, repr(value) if isinstance(value, float) else str(value)]
    args = [name, *positional, *optional]
    try:
        parser.parse_args(args[1:])
    except SystemExit:
        raise ManifestError(f"the {name!r} command no longer accepts the recorded settings: {args}") from None
    return args


def original_returncode(directory) -> int:
    """The exit code the run in ``directory`` ended with, from its results: 1 (a finding) for a
    study whose chain did NOT CONVERGE (``summary.json``) or a fit whose solver did not
    converge (``fit.json`` without a posterior), else 0."""
    directory = Path(directory)
    for name, verdict in (
        ("summary.json", lambda d: (d.get("posterior") or {}).get("converged")),
        ("fit.json", lambda d: d.get("success")),
    ):
        try:
            data = json.loads((directory / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict):  # a study's summary.json decides alone (its fit.json is not the verdict)
            return EXIT_FINDING if verdict(data) is False else 0
    return 0


# -- comparisons -----------------------------------------------------------------------------------


def compare_arrays(file: str, name: str, a, b) -> ArrayComparison:
    """Compare two arrays bit for bit; the largest absolute difference when they differ."""
    if a is None or b is None:
        return ArrayComparison(
            file, name, False, None if a is None else tuple(a.shape), None if b is None else tuple(b.shape)
        )
    a, b = np.asarray(a), np.asarray(b)
    shape_a, shape_b = tuple(a.shape), tuple(b.shape)
    if shape_a != shape_b or a.dtype != b.dtype:
        return ArrayComparison(file, name, False, shape_a, shape_b, None, max(a.size, b.size))
    if a.dtype.kind in "fc":
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        # bit-identical also means the same sign of zero and the same NaN payload
        identical = bool(same.all()) and a.tobytes() == b.tobytes()
        if identical:
            return ArrayComparison(file, name, True, shape_a, shape_b, 0.0, 0)
        finite = np.isfinite(a) & np.isfinite(b)
        diff = np.abs(a[finite] - b[finite]) if finite.any() else np.array([])
        n_diff = int((~same).sum()) or int(a.size)
        return ArrayComparison(file, name, False, shape_a, shape_b, float(diff.max()) if diff.size else None, n_diff)
    if a.dtype.kind in "biu":
        identical = np.array_equal(a, b)
        diff = np.abs(a.astype(float) - b.astype(float))
        return ArrayComparison(
            file, name, identical, shape_a, shape_b, float(diff.max()) if diff.size else 0.0, int((a != b).sum())
        )
    identical = a.tobytes() == b.tobytes()
    values = (str(a), str(b)) if (a.ndim == 0 and not identical) else None
    return ArrayComparison(
        file, name, identical, shape_a, shape_b, None, 0 if identical else int(a.size), False, values
    )


def _h5_datasets(path: Path) -> dict:
    out = {}
    with open_hdf5(path, "r") as f:

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[()]

        f.visititems(visit)

        # attributes (e.g. the emcee iteration count) count as scalars
        def visit_attrs(name, obj):
            for key, value in obj.attrs.items():
                if isinstance(value, (int, float, np.number, np.ndarray)):
                    out[f"{name}@{key}"] = np.asarray(value)

        f.visititems(visit_attrs)
    return out


def _npz_arrays(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _walk(value, path=""):
    """Yield ``(path, leaf)`` for every non-container value of a JSON tree, skipping timing keys."""
    if isinstance(value, dict):
        for k, v in value.items():
            if k in TIMING_KEYS:
                continue
            yield from _walk(v, f"{path}.{k}" if path else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _walk(v, f"{path}[{i}]")
    else:
        yield path, value


def compare_json(file: str, a: dict, b: dict) -> tuple[int, list[NumberDifference]]:
    """Compare every leaf of two JSON documents (timing keys ignored).

    Returns
    -------
    n_compared : int
    differences : list of NumberDifference
    """
    left, right = dict(_walk(a)), dict(_walk(b))
    differences = []
    for path in list(left) + [p for p in right if p not in left]:
        x, y = left.get(path), right.get(path)
        if x == y and (path in left) == (path in right):
            continue
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (x, y))
        diff = abs(float(x) - float(y)) if numeric and math.isfinite(float(x)) and math.isfinite(float(y)) else None
        differences.append(NumberDifference(file, path, x, y, diff))
    return len(set(left) | set(right)), differences


def _versions_and_commit(manifest_a: dict, manifest_b: dict):
    va, vb = manifest_a.get("versions") or {}, manifest_b.get("versions") or {}
    versions = {k: [va.get(k), vb.get(k)] for k in sorted(set(va) | set(vb)) if va.get(k) != vb.get(k)}
    ga, gb = manifest_a.get("git") or {}, manifest_b.get("git") or {}
    commit = None
    if (ga.get("commit"), ga.get("dirty")) != (gb.get("commit"), gb.get("dirty")):

        def fmt(g):
            return f"{g.get('commit')}{' (uncommitted changes)' if g.get('dirty') else ''}"

        commit = [fmt(ga), fmt(gb)]
    return versions, commit


def compare_runs(original, rerun) -> tuple[list, int, list, dict, list | None]:
    """Compare two results folders (arrays, result numbers, versions, commit).

    Returns
    -------
    arrays : list of ArrayComparison
    n_numbers : int
    numbers : list of NumberDifference
    version_differences : dict
    commit_difference : list or None
    """
    original, rerun = Path(original), Path(rerun)
    arrays = []
    further = sorted({p.name for p in [*original.glob("data_record*.npz"), *rerun.glob("data_record*.npz")]})
    for file in [*_ARRAY_FILES, *further]:  # a run of several records: each record's data too
        pa, pb = original / file, rerun / file
        if not pa.exists() and not pb.exists():
            continue
        reader = _h5_datasets if file.endswith(".h5") else _npz_arrays
        da = reader(pa) if pa.exists() else {}
        db = reader(pb) if pb.exists() else {}
        for name in list(da) + [n for n in db if n not in da]:
            arrays.append(compare_arrays(file, name, da.get(name), db.get(name)))
    n_numbers, numbers = 0, []
    json_files = list(_JSON_FILES) + sorted({p.name for p in original.glob("diagnos*.json")} - set(_JSON_FILES))
    for file in json_files:
        pa, pb = original / file, rerun / file
        if not pa.exists() and not pb.exists():
            continue
        a = json.loads(pa.read_text(encoding="utf-8")) if pa.exists() else {}
        b = json.loads(pb.read_text(encoding="utf-8")) if pb.exists() else {}
        n, diffs = compare_json(file, a, b)
        n_numbers += n
        numbers += diffs
    ma = json.loads((original / "manifest.json").read_text(encoding="utf-8"))
    mb_path = rerun / "manifest.json"
    mb = json.loads(mb_path.read_text(encoding="utf-8")) if mb_path.exists() else {}
    versions, commit = _versions_and_commit(ma, mb)
    return arrays, n_numbers, numbers, versions, commit


#: Environment variables that set the thread counts of numba and the BLAS libraries.
_THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def recorded_threads(directory: Path) -> int | None:
    """Threads a batch gave the run (``DIR/batch_job.json``), or None for a run started by hand.

    BLAS reductions in the least squares depend on the thread count in the last bits, so a
    bit-identical rerun needs the same count.
    """
    try:
        job = json.loads((directory / "batch_job.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    threads = job.get("threads") if isinstance(job, dict) else None
    return int(threads) if isinstance(threads, int) and threads >= 1 else None


def _check_readable(directory: Path) -> None:
    """Every result file of the original run reads back (else nothing is rerun).

    Raises
    ------
    identify.output.results.DamagedResultsError
    """
    for name in _JSON_FILES:
        if (directory / name).exists():
            read_json(directory / name, hint="the run cannot be compared with a rerun")
    if (directory / "data.npz").exists():
        load_data(directory)
    try:
        chain_info(directory / "chain.h5")
    except ChainFileError as exc:
        raise DamagedResultsError(f"{exc}; the run cannot be compared with a rerun") from None


def reproduce(directory, out=None, *, data=None, stream=None) -> ReproductionReport:
    """Rerun the run in ``directory`` into ``out`` and compare (see the module docstring).

    Parameters
    ----------
    directory : path-like
        A finished results folder with ``manifest.json``.
    out : path-like, optional
        New folder for the rerun; default ``<directory>-reproduced``. It must not be
        ``directory`` itself.
    data : path-like, optional
        The data file, when it is no longer where the manifest says (hash still checked).
    stream : file-like, optional
        Where the rerun's output goes (besides ``out/reproduce.log``); default none.

    Returns
    -------
    ReproductionReport
        Also written to ``out/reproduction.json``.

    Raises
    ------
    ManifestError, DataChangedError
        Before anything runs.
    """
    directory = Path(directory).resolve()
    manifest = read_manifest(directory)
    _check_readable(directory)
    records = manifest["data"].get("records")
    if isinstance(records, list) and len(records) > 1:  # several records: the first by its own hash
        first = {**manifest, "data": {"file": records[0]["file"], "sha256": records[0]["sha256"]}}
    else:
        first = manifest
    location = locate_data(first, directory, data)
    out = Path(out).resolve() if out is not None else directory.with_name(directory.name + "-reproduced")
    if out == directory:
        raise OutputExistsError("--out must be a new folder, not the run being reproduced")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        what = (
            "is a file"
            if not out.is_dir()
            else ("holds a study (manifest.json)" if (out / "manifest.json").exists() else "is not empty")
        )
        raise OutputExistsError(
            f"{out} {what}: a reproduction writes into a new folder and never into an existing one. "
            "Remove it, or pass --out NEWDIR"
        )
    several = _locate_records(manifest, directory, location)
    args = rerun_arguments(manifest, location.argument if several is None else several, out)
    env = package_environment()
    threads = recorded_threads(directory)
    if threads is not None:
        for name in _THREAD_VARIABLES:
            env[name] = str(threads)

    with contextlib.ExitStack() as stack:
        reading = FolderLock(directory, command=f"python -m identify reproduce {directory} (reading it)")
        try:
            stack.enter_context(reading)  # no study may write into it while it is read
        except PermissionError:  # a read-only results folder: nobody can write into it either
            pass
        new_lock = stack.enter_context(FolderLock(out, command=f"python -m identify reproduce {directory} --out {out}"))
        env, pass_fds = new_lock.child_environment(env)  # the rerun writes under this lock
        with open(out / "reproduce.log", "w", encoding="utf-8") as log:
            log.write("$ python -m identify " + " ".join(args) + "\n")
            log.flush()
            completed = subprocess.run(
                [sys.executable, "-m", "identify", *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                cwd=location.cwd,
                pass_fds=pass_fds,
            )
        if stream is not None:
            stream.write((out / "reproduce.log").read_text(encoding="utf-8", errors="replace"))
        arrays, n_numbers, numbers, versions, commit = compare_runs(directory, out)
        report = ReproductionReport(
            original=str(directory),
            rerun=str(out),
            command=args,
            data_file=str(location.path),
            returncode=int(completed.returncode),
            arrays=arrays,
            numbers=numbers,
            n_numbers_compared=n_numbers,
            version_differences=versions,
            commit_difference=commit,
            threads=threads,
            expected_returncode=original_returncode(directory),
        )

        atomic_write(out / REPORT_FILE, json.dumps(jsonable(report.to_dict()), indent=2, default=str) + "\n")
    return report
