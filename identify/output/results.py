"""The results folder of a study: write it (atomically), read it back, check a rerun matches.

Layout (docs/CONTRACTS.md)::

    DIR/
      data.npz         time, current, displacement (the record exactly as fitted), units and
                       column names as 0-d string arrays, source, sha256
      chain.h5         emcee HDFBackend, group "mcmc" (resumable)
      fit.json         FitResult.to_dict()
      summary.json     model, units, noise, fit, identifiability, posterior, parameters
      manifest.json    seed, data file + sha256, settings, package versions, git commit, times
      report.html + *.png   written by identify.output.report

Every file is written to a temporary name in ``DIR`` and renamed into place
(:mod:`identify.data.fileio`), so a crash never leaves a half-written file. JSON is strict (NaN
and infinity written as ``null``). A file that cannot be read back (damaged from outside,
e.g. truncated) is a :class:`DamagedResultsError` naming it and saying what to do;
:func:`inspect_run` reads a whole folder's state (what is stored, whether it is finished)
before a rerun touches anything.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata as md
import json
import math
import os
import platform
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
from threadpoolctl import threadpool_info

from model import TABLE1, THETA_NAMES

from ..data.fileio import atomic_write
from ..data.records import Record
from ..fitting.lsq import FitResult, StoredModelError, parameter_units
from ..fitting.posterior import BACKEND_GROUP, DIAGNOSTICS, ChainBackend, ChainFileError, chain_info

__all__ = [
    "FILES",
    "RUN_FILES",
    "RunMismatchError",
    "DamagedResultsError",
    "StudyResults",
    "RunState",
    "inspect_run",
    "remove_run",
    "write_json",
    "read_json",
    "jsonable",
    "write_data",
    "load_data",
    "record_data_file",
    "write_fit",
    "load_fit",
    "write_summary",
    "build_summary",
    "build_manifest",
    "finish_manifest",
    "check_resumable",
    "read_manifest",
    "last_status",
    "package_versions",
    "thread_counts",
    "git_commit",
    "git_head",
    "load_results",
    "now_iso",
]

#: role -> file name inside a results folder.
FILES = {
    "data": "data.npz",
    "chain": "chain.h5",
    "fit": "fit.json",
    "summary": "summary.json",
    "manifest": "manifest.json",
    "report": "report.html",
    "inference": "posterior.nc",
}


#: Files of a run (removed by ``--force`` and by the rollback of a failed fresh run).
RUN_FILES = ("data", "chain", "fit", "summary", "manifest", "report", "inference")


class RunMismatchError(ValueError):
    """The results folder holds a run with different data or settings."""


class DamagedResultsError(ValueError):
    """A results file that cannot be read back (truncated, not JSON, wrong content); the
    message names the file and says what to do."""


def now_iso() -> str:
    """Current UTC time, ISO 8601 with seconds."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def jsonable(obj):
    """``obj`` with numpy types converted and non-finite floats replaced by None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON: {obj!r}")


def write_json(path, obj) -> None:
    """Strict JSON (sorted keys kept in insertion order, 2-space indent), atomically."""
    text = json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n"
    atomic_write(path, text.encode("utf-8"))


def read_json(path, *, hint="") -> dict:
    """Read a JSON object from a file.

    Raises
    ------
    FileNotFoundError
        The file is missing (the message names it).
    DamagedResultsError
        Unreadable, not UTF-8, not valid JSON, or not an object; the message names the
        file and ends with ``hint`` (what to do).
    """
    path = Path(path)
    hint = f"; {hint}" if hint else ""
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: missing (not a complete results folder?)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DamagedResultsError(f"{path} is damaged (cannot read it: {exc}){hint}") from None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DamagedResultsError(f"{path} is damaged (not valid JSON: {exc}){hint}") from None
    if not isinstance(value, dict):
        raise DamagedResultsError(f"{path} is damaged (a JSON object was expected, found {type(value).__name__}){hint}")
    return value


def record_data_file(r: int) -> str:
    """The data file of record ``r`` (from 1) of a folder of several records: ``data.npz`` for the
    first (what a reader of one record finds), ``data_record<r>.npz`` for the others."""
    return FILES["data"] if r == 1 else f"data_record{r}.npz"


def write_data(out_dir, record, name=None) -> None:
    """``data.npz`` (or ``name``): the record's arrays, units, column names, source and sha256
    (streamed to the file, no copy of the record in memory)."""

    def save(fh):
        np.savez(
            fh,
            time=np.asarray(record.time, dtype=float),
            current=np.asarray(record.current, dtype=float),
            displacement=np.asarray(record.displacement, dtype=float),
            input_unit=np.array(record.input_unit),
            output_unit=np.array(record.output_unit),
            input_name=np.array(record.input_name),
            output_name=np.array(record.output_name),
            source=np.array(str(record.source)),
            sha256=np.array(record.sha256),
        )

    atomic_write(Path(out_dir) / (name or FILES["data"]), save)


def load_data(out_dir, name=None):
    """The record stored in ``DIR/data.npz`` as an :class:`identify.data.records.Record`.

    Raises
    ------
    FileNotFoundError
        No ``data.npz``.
    DamagedResultsError
        The file cannot be read or does not hold a valid record.
    """
    path = Path(out_dir) / (name or FILES["data"])
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing (not a complete results folder?)")
    try:
        with np.load(path, allow_pickle=False) as z:
            return Record(
                time=z["time"],
                current=z["current"],
                displacement=z["displacement"],
                source=str(z["source"]),
                sha256=str(z["sha256"]),
                input_name=str(z["input_name"]),
                input_unit=str(z["input_unit"]),
                output_name=str(z["output_name"]),
                output_unit=str(z["output_unit"]),
            )
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise DamagedResultsError(
            f"{path} is damaged ({type(exc).__name__}: {exc}); rerun the command that wrote the folder "
            "with --force to rewrite it"
        ) from None


def write_fit(out_dir, fit) -> None:
    """``fit.json`` from a :class:`identify.fitting.lsq.FitResult`."""
    write_json(Path(out_dir) / FILES["fit"], fit.to_dict())


#: What to do about a damaged fit.json.
_FIT_HINT = (
    "delete it and rerun the same command to redo the least squares (the same seed gives the same fit; "
    "a stored chain is kept), or use --force to start the run over"
)


def load_fit(out_dir):
    """The :class:`identify.fitting.lsq.FitResult` stored in ``DIR/fit.json``.

    Raises
    ------
    FileNotFoundError
        No ``fit.json``.
    DamagedResultsError
        Not valid JSON, or not a complete fit (the message says what to do).
    """
    path = Path(out_dir) / FILES["fit"]
    content = read_json(path, hint=_FIT_HINT)
    try:
        return FitResult.from_dict(content)
    except StoredModelError as exc:  # complete, but not this version's model
        raise DamagedResultsError(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise DamagedResultsError(
            f"{path} is damaged (not a complete fit: {type(exc).__name__}: {exc}); {_FIT_HINT}"
        ) from None


def write_summary(out_dir, summary: dict) -> None:
    write_json(Path(out_dir) / FILES["summary"], summary)


def build_summary(record, fit, identifiability=None, posterior=None) -> dict:
    """``summary.json`` contents (keys as in docs/CONTRACTS.md).

    Parameters
    ----------
    record : Record
    fit : identify.fitting.lsq.FitResult
    identifiability : identify.fitting.identifiability.IdentifiabilityResult, optional
    posterior : identify.fitting.posterior.PosteriorResult, optional
        When None (sampling not done yet) the ``posterior`` block is null and the
        parameters' posterior fields are null.
    """
    model = fit.model
    units = parameter_units(model, record)
    post_index = {}
    quantiles = None
    if posterior is not None:
        post_index = {n: j for j, n in enumerate(posterior.names)}
        quantiles = posterior.quantiles((0.025, 0.5, 0.975))
    parameters = []
    for i, name in enumerate(model.names):
        entry = {
            "name": name,
            "unit": units[i],
            "table1": float(TABLE1[THETA_NAMES.index(name)]) if name in THETA_NAMES else None,
            "lsq": float(fit.theta[i]),
            "lsq_stderr": float(fit.stderr[i]),
            "mean": None,
            "sd": None,
            "median": None,
            "lo95": None,
            "hi95": None,
            "tau": None,
            "ess": None,
            **{k: None for k in DIAGNOSTICS},
            "vary": bool(fit.vary[i]),
        }
        if not fit.vary[i]:
            entry.update(median=float(fit.theta[i]), lo95=float(fit.theta[i]), hi95=float(fit.theta[i]))
        elif name in post_index:
            j = post_index[name]
            entry.update(
                lo95=float(quantiles[0, j]),
                median=float(quantiles[1, j]),
                hi95=float(quantiles[2, j]),
                tau=float(posterior.tau[j]),
                ess=float(posterior.ess[j]),
                mean=float(np.mean(posterior.samples[:, j])),
                sd=float(np.std(posterior.samples[:, j], ddof=1)),
                **{k: posterior.diagnostic(k, j) for k in DIAGNOSTICS},
            )
        parameters.append(entry)
    noise = {
        "sigma": fit.noise.sigma,
        "rho": fit.noise.rho,
        "kind": fit.noise.kind,
        "source": fit.noise.source,
        "n_quiet": fit.noise.n_quiet,
    }
    if posterior is not None and "noise_log_sigma" in post_index:
        j = post_index["noise_log_sigma"]
        lo, med, hi = np.exp(quantiles[:, j])
        noise["posterior"] = {
            "median": med,
            "lo95": lo,
            "hi95": hi,
            "tau": posterior.tau[j],
            "ess": posterior.ess[j],
            **{k: posterior.diagnostic(k, j) for k in DIAGNOSTICS},
        }
    ident = None
    if identifiability is not None:
        ident = identifiability.to_dict()
    return jsonable(
        {
            "model": model.to_dict(),
            "units": {"input": record.input_unit, "output": record.output_unit},
            "noise": noise,
            "fit": {
                "rms": fit.rms,
                "max_error_pct": fit.max_error_pct,
                "reduced_chi2": fit.reduced_chi2,
                "seconds": fit.seconds,
                "n_starts": fit.n_starts,
                "n_agree": fit.n_agree,
                "success": fit.success,
                "terms": [dict(t) for t in getattr(fit, "terms", [])],
            },
            "identifiability": ident,
            "posterior": None if posterior is None else posterior.to_dict(),
            "parameters": parameters,
        }
    )


def package_versions() -> dict:
    """Versions of Python, the platform and the packages the results depend on."""
    versions = {"python": sys.version.split()[0], "platform": platform.platform()}
    for dist in ("msma-gpi", "numpy", "scipy", "numba", "emcee", "h5py", "matplotlib", "threadpoolctl", "arviz"):
        try:
            versions[dist] = md.version(dist)
        except md.PackageNotFoundError:
            versions[dist] = None
    return versions


def thread_counts() -> dict:
    """The thread counts the numbers of a run may depend on, JSON-ready.

    Returns
    -------
    dict
        ``numba``: threads numba uses now (``numba.get_num_threads()``; the least squares
        picks 1 or ``numba_max`` by speed, which never changes its results: every
        parameter set is computed independently); ``numba_max``: ``NUMBA_NUM_THREADS``;
        ``blas``: ``[{"library", "api", "threads"}]`` per BLAS/OpenMP pool loaded
        (``threadpoolctl``; BLAS reductions change in the last bits with the thread count;
        the least squares limits BLAS to ``least_squares_blas`` threads); ``cpu_count``.
    """
    counts: dict = {"cpu_count": os.cpu_count(), "least_squares_blas": 1}
    counts["numba"] = int(numba.get_num_threads())
    counts["numba_max"] = int(numba.config.NUMBA_NUM_THREADS)
    counts["blas"] = [
        {"library": info.get("internal_api"), "api": info.get("user_api"), "threads": info.get("num_threads")}
        for info in threadpool_info()
    ]
    return counts


def git_head(path=None) -> str | None:
    """The commit (HEAD) of the git work tree holding ``path`` (this package by default), or None.

    None when git is missing, ``path`` is not in a work tree, or git answers anything but a
    40-character commit (the one home of this look-up: :func:`git_commit` and the bench's
    truth, :mod:`identify.cli.simulate`, use it).
    """
    root = Path(path) if path is not None else Path(__file__).resolve().parent.parent
    try:
        result = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = result.stdout.strip()
    return commit if result.returncode == 0 and len(commit) == 40 else None


def git_commit(path=None) -> dict:
    """``{"commit": sha or None, "dirty": bool or None}`` of the project's git work tree (:func:`git_head`)."""
    root = Path(path) if path is not None else Path(__file__).resolve().parent.parent
    sha = git_head(root)
    if sha is None:
        return {"commit": None, "dirty": None}
    try:
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": sha, "dirty": bool(status.strip())}


def build_manifest(*, seed, record, settings: dict, started=None, command=None, task=None) -> dict:
    """``manifest.json`` contents at the start of a run.

    Parameters
    ----------
    seed : int
        The ``--seed`` every random draw derives from.
    record : Record
        Its ``source`` and ``sha256`` identify the data; its ``notes`` (what was assumed
        while loading it, e.g. no time column) are recorded with them.
    settings : dict
        Every option of the command (JSON-ready values).
    started : str, optional
        ISO time; default now.
    command : list of str, optional
        The command line; default ``sys.argv``.
    task : str, optional
        The ``python -m identify`` command that made the run (``"fit"``, ``"study"``);
        ``reproduce`` reruns that command.

    Returns
    -------
    dict
        Keys ``seed``, ``task``, ``data`` ({file, sha256, n_samples, notes}), ``settings``,
        ``versions``, ``threads`` (:func:`thread_counts`), ``git``, ``command``,
        ``started``, ``finished`` (None until :func:`finish_manifest`), ``runs``.
    """
    return jsonable(
        {
            "seed": seed,
            "task": task,
            "data": {
                "file": str(record.source),
                "sha256": record.sha256,
                "n_samples": len(record.time),
                "notes": list(getattr(record, "notes", ())),
            },
            "settings": settings,
            "versions": package_versions(),
            "threads": thread_counts(),
            "git": git_commit(),
            "command": list(sys.argv if command is None else command),
            "started": started or now_iso(),
            "finished": None,
            "runs": [],
        }
    )


def finish_manifest(manifest: dict, *, started, seconds: float, status: str, phases=None, error=None) -> dict:
    """Record one (possibly resumed) run's times and status in ``manifest["runs"]``.

    ``phases`` is ``{phase: seconds}`` (e.g. least_squares, posterior, report); ``error``
    the one-line reason of a ``failed`` run.
    """
    finished = now_iso()
    manifest = dict(manifest)
    run = {"started": started, "finished": finished, "seconds": float(seconds), "status": status}
    if error:
        run["error"] = str(error)[:500]
    if phases:
        run["phases"] = {k: float(v) for k, v in phases.items()}
    manifest["runs"] = list(manifest.get("runs", [])) + [run]
    manifest["finished"] = finished
    return manifest


#: What to do about a damaged manifest.json.
_MANIFEST_HINT = (
    "the run's settings cannot be compared with this command's. Use --force to discard the run in the folder "
    "and start over, or another output folder"
)


def read_manifest(out_dir) -> dict | None:
    """``DIR/manifest.json`` (None when absent); :class:`DamagedResultsError` when unreadable."""
    path = Path(out_dir) / FILES["manifest"]
    if not path.exists():
        return None
    manifest = read_json(path, hint=_MANIFEST_HINT)
    if not isinstance(manifest.get("settings"), dict) or not isinstance(manifest.get("data"), dict):
        raise DamagedResultsError(f"{path} is damaged (no 'settings' or 'data'); {_MANIFEST_HINT}")
    return manifest


def last_status(manifest: dict | None) -> str | None:
    """Status of the last run recorded in a manifest (``converged``, ``not converged``,
    ``done``, ``interrupted``, ``failed``, ``running``), or None."""
    if not manifest:
        return None
    runs = manifest.get("runs") or []
    if runs and isinstance(runs[-1], dict):
        return runs[-1].get("status")
    return "running" if manifest.get("finished") is None else None


def check_resumable(out_dir, manifest: dict, *, ignore=(), chain_steps=None) -> dict | None:
    """Compare a new run with the one stored in ``DIR/manifest.json``, before anything is written.

    Parameters
    ----------
    out_dir : path-like
    manifest : dict
        The new run's (:func:`build_manifest`).
    ignore : sequence of str
        Settings that may differ (e.g. ``no_report``, the data file's path; the data
        are compared by SHA-256).
    chain_steps : int, optional
        Steps the folder's chain holds. When given, ``max_steps`` may change only to a
        cap the stored chain does not exceed: a lower cap would not give the result a
        run with that cap gives.

    Returns
    -------
    dict or None
        The stored manifest (None when the folder holds no run yet).

    Raises
    ------
    RunMismatchError
        Different task, data (sha256), seed or settings; the message lists every difference.
    DamagedResultsError
        The stored manifest cannot be read.
    """
    old = read_manifest(out_dir)
    if old is None:
        return None
    diffs = []
    if old.get("task") is not None and manifest.get("task") is not None and old.get("task") != manifest.get("task"):
        diffs.append(f"command {old.get('task')} -> {manifest.get('task')}")
    if old.get("data", {}).get("sha256") != manifest["data"]["sha256"]:
        diffs.append(f"data sha256 {old.get('data', {}).get('sha256')} -> {manifest['data']['sha256']}")
    if old.get("seed") != manifest["seed"]:
        diffs.append(f"seed {old.get('seed')} -> {manifest['seed']}")
    old_settings, new_settings = old.get("settings", {}), manifest["settings"]
    for key in sorted(set(old_settings) | set(new_settings)):
        if key in ignore or (key == "max_steps" and chain_steps is not None):
            continue
        if old_settings.get(key) != new_settings.get(key):
            diffs.append(f"{key}: {old_settings.get(key)!r} -> {new_settings.get(key)!r}")
    if chain_steps is not None:
        new_cap = new_settings.get("max_steps")
        if isinstance(new_cap, int) and chain_steps > new_cap:
            diffs.append(
                f"max_steps: {old_settings.get('max_steps')!r} -> {new_cap!r}, but its chain already holds "
                f"{chain_steps} steps (give --max-steps {chain_steps} or more to extend it)"
            )
    if diffs:
        raise RunMismatchError(
            f"{out_dir} holds a run with different data or settings ("
            + "; ".join(diffs)
            + "). Nothing was changed. Use another --out folder, or --force to discard that run."
        )
    return old


def remove_run(out_dir, roles=RUN_FILES) -> list[str]:
    """Delete a run's files (and its figures) from ``DIR``; returns the names removed."""
    out = Path(out_dir)
    removed = []
    had_run = (out / FILES["manifest"]).exists() or (out / FILES["report"]).exists()
    for role in roles:
        path = out / FILES[role]
        if path.exists():
            path.unlink()
            removed.append(path.name)
    if "data" in roles:  # the further records of a run of several (record_data_file)
        for path in sorted(out.glob("data_record*.npz")):
            path.unlink()
            removed.append(path.name)
    if "report" in roles and had_run:  # the report's figures (never PNGs of a folder that held no run)
        for png in out.glob("*.png"):
            png.unlink()
            removed.append(png.name)
    return removed


@dataclass
class RunState:
    """What a results folder holds, read before a rerun touches anything (:func:`inspect_run`).

    Attributes
    ----------
    manifest : dict or None
    status : str or None
        The last run's status (:func:`last_status`).
    has_fit : bool
        ``fit.json`` exists and reads back as a fit.
    has_data : bool
        ``data.npz`` exists and reads back (when damaged it is rewritten from the record,
        whose SHA-256 the manifest check has matched).
    chain_steps : int or None
        Steps in ``chain.h5`` (None: no chain yet).
    summary : dict or None
        ``summary.json`` when it reads back (None when absent or damaged: it is rebuilt).
    """

    manifest: dict | None = None
    status: str | None = None
    has_fit: bool = False
    has_data: bool = False
    chain_steps: int | None = None
    summary: dict | None = None

    @property
    def posterior(self) -> dict | None:
        post = (self.summary or {}).get("posterior")
        return post if isinstance(post, dict) else None

    def finished(self, max_steps: int) -> bool:
        """A complete study whose result a run capped at ``max_steps`` would not change:
        its posterior summary describes the stored chain, which converged or reached the cap."""
        post = self.posterior
        if self.status not in ("converged", "not converged") or post is None or not self.has_fit:
            return False
        if self.chain_steps is None or post.get("n_steps") != self.chain_steps:
            return False
        return bool(post.get("converged")) or self.chain_steps >= max_steps


def inspect_run(out_dir, *, chain=True) -> RunState:
    """Read the state of ``DIR`` without writing anything.

    Raises
    ------
    DamagedResultsError
        A damaged ``manifest.json``, ``fit.json`` or ``chain.h5`` (each message says what
        to do). A damaged ``summary.json`` is not an error: it is derived from the others
        and rewritten by the rerun.
    """
    out = Path(out_dir)
    state = RunState()
    state.manifest = read_manifest(out)
    state.status = last_status(state.manifest)
    if (out / FILES["fit"]).exists():
        load_fit(out)
        state.has_fit = True
    if (out / FILES["data"]).exists():
        try:
            load_data(out)
            state.has_data = True
        except DamagedResultsError:
            state.has_data = False
    if chain:
        try:
            info = chain_info(out / FILES["chain"])
        except ChainFileError as exc:
            raise DamagedResultsError(
                f"{exc}. The other results in {out} are untouched. To redo the sampling, delete "
                f"{out / FILES['chain']} and rerun the same command (the fit is reused and the same seed gives "
                "the same chain), or use --force to start the run over"
            ) from None
        state.chain_steps = None if info is None else info[0]
    try:
        state.summary = read_json(out / FILES["summary"]) if (out / FILES["summary"]).exists() else None
    except DamagedResultsError:
        state.summary = None
    return state


@dataclass
class StudyResults:
    """A results folder read back (what ``report``, ``diagnose`` and ``reproduce`` need).

    Parameters
    ----------
    path : Path
    record : Record
        From ``data.npz``.
    fit : identify.fitting.lsq.FitResult
    summary, manifest : dict
    """

    path: Path
    record: object
    fit: object
    summary: dict
    manifest: dict

    @property
    def chain_path(self) -> Path:
        return self.path / FILES["chain"]

    def posterior_samples(self):
        """Flat posterior samples ``(N, D)`` (burn-in and thinning as in summary.json) and their names.

        Returns
        -------
        samples : ndarray, shape (N, D)
        names : tuple of str
            The sampled coordinates (free parameters, then ``noise_log_sigma`` if free).
        """
        post = self.summary.get("posterior")
        if post is None:
            raise ValueError(f"{self.path}: no posterior yet (the study has not finished sampling)")
        backend = ChainBackend(str(self.chain_path), name=BACKEND_GROUP, read_only=True)
        samples = backend.get_chain(discard=int(post["discard"]), thin=int(post["thin"]), flat=True)
        names = [p["name"] for p in self.summary["parameters"] if p["vary"]]
        if self.summary["noise"].get("source") == "free":
            names.append("noise_log_sigma")
        return samples, tuple(names)


def load_results(out_dir) -> StudyResults:
    """Read a results folder written by ``python -m identify study``."""
    path = Path(out_dir)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such results folder")
    return StudyResults(
        path=path,
        record=load_data(path),
        fit=load_fit(path),
        summary=read_json(path / FILES["summary"], hint="rerun the same study command to rewrite it"),
        manifest=read_json(path / FILES["manifest"], hint=_MANIFEST_HINT),
    )
