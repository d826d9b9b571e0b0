"""``python -m identify study DATA.csv --out DIR``: the whole identification, resumable.

Steps: load the record; noise model from its unenergised start; least squares
(multi-start) of the normalised model (alpha pinned, see
:mod:`identify.identifiability`); identifiability (exact and near-degenerate
directions); emcee posterior until converged or the step cap; the report
(:func:`identify.report.write_report`, when that module is installed). Results go to DIR
as described in :mod:`identify.results`.

Rerunning the same command resumes: the stored least-squares fit is reused and the
chain continues from its last saved step. A folder holding a run with other data, seed
or settings is refused unless ``--force`` (which deletes that run's files first).
Only ``--max-steps`` (to extend a chain that did not converge) and the path of the data
file (the data are compared by SHA-256) may change between runs.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time as _time
from pathlib import Path

from .cmd_fit import add_model_arguments, add_record_arguments

__all__ = ["HELP", "add_arguments", "run", "run_study", "RESUMABLE_SETTINGS", "DEFAULT_MAX_STEPS", "settings_from_args"]

HELP = "whole study (noise, least squares, identifiability, emcee posterior, report) into a results folder"

#: Default cap on the chain length [steps]. The bundled record's posterior converges after
#: 35500-54000 steps depending on the random stream (tau_max 708-1080 with the corrected
#: snooker move); the cap leaves room for an autocorrelation time up to 1200 steps
#: (docs/method.md).
DEFAULT_MAX_STEPS = 60000
#: Settings that may differ when a run is resumed.
RESUMABLE_SETTINGS = ("max_steps", "data", "no_report")  # data compared by sha256; no_report changes no number
#: Options that are not settings of the computation (not compared, not all recorded).
_NOT_SETTINGS = ("out", "force", "progress", "command", "_module", "quiet")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser)
    parser.add_argument("--out", required=True, metavar="DIR", help="results folder (created; a rerun resumes)")
    add_model_arguments(parser)
    parser.add_argument("--walkers", type=int, default=None, help="emcee walkers (default: 2 x dimension, even, >= 32)")
    parser.add_argument(
        "--max-steps", type=int, default=DEFAULT_MAX_STEPS, help=f"cap on the chain length (default {DEFAULT_MAX_STEPS})"
    )
    parser.add_argument("--check-every", type=int, default=500, help="convergence check interval in steps (default 500)")
    parser.add_argument("--moves", default="de", choices=("de", "stretch"), help="emcee moves (default de: differential evolution)")
    parser.add_argument("--force", action="store_true", help="discard a different run already in DIR")
    parser.add_argument("--no-report", action="store_true", help="skip the report (report.html); write it later with 'report DIR'")
    parser.add_argument(
        "--progress", choices=("auto", "on", "off"), default="auto", help="progress bar (default: when stderr is a terminal)"
    )


def settings_from_args(args) -> dict:
    """Every option of the computation, JSON-ready (the manifest's ``settings``)."""
    settings = {}
    for key, value in sorted(vars(args).items()):
        if key in _NOT_SETTINGS or key.startswith("_"):
            continue
        settings[key] = value
    settings["data"] = str(args.data)
    return settings


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _remove_run(out: Path) -> None:
    from .results import FILES

    for name in FILES.values():
        path = out / name
        if path.exists():
            path.unlink()
    for png in out.glob("*.png"):
        png.unlink()


def run(args) -> int:
    from .cmd_fit import FitFailedError
    from .noise import NoQuietSegmentError
    from .records import RecordError
    from .results import RunMismatchError

    with _sigterm_as_interrupt():
        try:
            return run_study(args)
        except (RecordError, NoQuietSegmentError, RunMismatchError, FitFailedError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Turn SIGTERM (``kill PID``) into KeyboardInterrupt, so the chain is flushed and the
    manifest records the interruption, exactly as for Ctrl-C (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_study(args) -> int:
    """The study (see the module docstring); returns the exit code (0 = done, converged or not)."""
    import numpy as np

    from .cmd_fit import fit_or_explain, format_fit_table, model_from_args, noise_from_args, print_record_notes
    from .cmd_fit import record_from_args
    from .identifiability import analyse_fit
    from .posterior import LogPosterior, default_n_walkers, initial_walkers, sample_posterior
    from .results import (
        FILES,
        build_manifest,
        build_summary,
        check_resumable,
        finish_manifest,
        load_fit,
        now_iso,
        write_data,
        write_fit,
        write_json,
        write_summary,
    )

    t_start = _time.perf_counter()
    started = now_iso()
    try:
        model = model_from_args(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    record = record_from_args(args)
    print_record_notes(record)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = settings_from_args(args)
    manifest = build_manifest(seed=args.seed, record=record, settings=settings, started=started, task="study")
    if args.force:
        _remove_run(out)
        old = None
    else:
        old = check_resumable(out, manifest, ignore=RESUMABLE_SETTINGS)
    if old is not None:
        manifest["started"] = old.get("started", started)
        manifest["runs"] = old.get("runs", [])
        _say(f"resuming the run in {out} (same data, seed and settings)")
    write_json(out / FILES["manifest"], manifest)
    write_data(out, record)

    status = "interrupted"
    phases: dict[str, float] = {}
    clock = _time.perf_counter()

    def lap(name):
        nonlocal clock
        now = _time.perf_counter()
        phases[name] = now - clock
        clock = now

    try:
        rng = np.random.default_rng(args.seed)
        lsq_rng, posterior_rng = rng.spawn(2)

        # 1. noise (raises NoQuietSegmentError naming the fallbacks)
        noise = noise_from_args(args, record)
        _say(f"noise: sigma = {noise.sigma:.4g} {record.output_unit}, {noise.kind}, source {noise.source}")
        lap("load_and_noise")

        # 2. least squares (reused when the folder already holds it)
        fit_path = out / FILES["fit"]
        if old is not None and fit_path.exists():
            fit = load_fit(out)
            _say(f"least squares: reusing {fit_path}")
        else:
            _say(f"least squares: {model!r}, {args.n_starts} starts ...")
            fit = fit_or_explain(record, model, noise=noise, n_starts=args.n_starts, rng=lsq_rng)
            write_fit(out, fit)
        print(format_fit_table(fit, record))
        lap("least_squares")

        # 3. identifiability
        ident = analyse_fit(fit, record)
        print(ident.describe())
        write_summary(out, build_summary(record, fit, ident, None))
        lap("identifiability")

        # 4. posterior
        log_post = LogPosterior(record, fit.model, fit.noise)
        free = log_post.free
        mean = fit.theta[free]
        cov = fit.covariance[np.ix_(free, free)]
        if log_post.free_sigma:
            dof = len(record.time) - free.size
            mean = np.append(mean, np.log(fit.noise.sigma))
            cov = np.pad(cov, ((0, 1), (0, 1)))
            cov[-1, -1] = 1.0 / (2.0 * dof)
        n_walkers = args.walkers or default_n_walkers(log_post.ndim)
        progress = {"auto": None, "on": True, "off": False}[args.progress]
        _say(f"posterior: {n_walkers} walkers x {log_post.ndim} parameters, up to {args.max_steps} steps ({args.moves} moves)")
        posterior = sample_posterior(
            log_post,
            lambda n, r: initial_walkers(log_post, mean, cov, n, r),
            out / FILES["chain"],
            posterior_rng,
            n_walkers=n_walkers,
            max_steps=args.max_steps,
            check_every=args.check_every,
            moves=args.moves,
            progress=progress,
            log=_say,
        )
        summary = build_summary(record, fit, ident, posterior)
        write_summary(out, summary)
        print(f"posterior: {posterior.message}")
        print(
            f"acceptance fraction {posterior.acceptance_fraction:.3f}; tau_max {posterior.tau_max:.1f} steps; "
            f"{posterior.samples.shape[0]} samples after discarding {posterior.discard} and thinning by {posterior.thin}"
        )
        status = "converged" if posterior.converged else "not converged"
        lap("posterior")

        # 5. report
        if getattr(args, "no_report", False):
            _say(f"report skipped (--no-report); write it with: python -m identify report {out}")
        else:
            try:
                from .report import write_report
            except ImportError as exc:
                _say(f"report skipped: identify.report is not available ({exc})")
            else:
                path = write_report(out)
                _say(f"report: {path}")
            lap("report")
    finally:
        manifest = finish_manifest(
            manifest, started=started, seconds=_time.perf_counter() - t_start, status=status, phases=phases
        )
        write_json(out / FILES["manifest"], manifest)
    _say("times: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in phases.items()))
    _say(f"study finished in {_time.perf_counter() - t_start:.1f} s: {out}")
    return 0
