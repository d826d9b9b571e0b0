"""``python -m identify study DATA.csv --out DIR``: the whole identification, resumable.

Steps: load the record; noise model from its unenergised start; least squares
(multi-start) of the normalised model (alpha pinned, see
:mod:`identify.identifiability`); identifiability (exact and near-degenerate
directions); emcee posterior until converged or the step cap; the report
(:func:`identify.report.write_report`, when that module is installed). Results go to DIR
as described in :mod:`identify.results`.

Rerunning the same command resumes: the stored least-squares fit is reused and the
chain continues from its last saved step; a finished study is left as it is (nothing is
rewritten). Before anything is written the folder is locked (:mod:`identify.locks`: a
second process is refused at once), the options are checked (``--walkers`` against the
model's dimension), the record is loaded and its noise estimated, and the folder's state
is read (:func:`identify.results.inspect_run`): a damaged ``manifest.json``,
``fit.json`` or ``chain.h5`` is one error saying what to do, and a folder holding a run
with other data, seed or settings is refused unless ``--force`` (which deletes that
run's files first). Only ``--max-steps`` (to extend a chain that did not converge, never
below the steps the chain holds), ``--no-report`` and the path of the data file (the data
are compared by SHA-256) may change between runs. A fresh run that fails before its first
result leaves nothing behind; one that fails later is marked ``failed`` in the manifest
and is replaced by the next run with other settings. See docs/reliability.md.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shutil
import sys
import time as _time
from pathlib import Path

from . import options
from .cmd_fit import add_model_arguments, add_record_arguments
from .defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS, EXIT_FINDING
from .logs import say as log_line

__all__ = ["HELP", "add_arguments", "run", "run_study", "RESUMABLE_SETTINGS", "DEFAULT_MAX_STEPS", "settings_from_args"]

HELP = "whole study (noise, least squares, identifiability, emcee posterior, report) into a results folder"

#: Settings that may differ when a run is resumed (``max_steps`` is checked against the
#: stored chain instead, :func:`identify.results.check_resumable`).
RESUMABLE_SETTINGS = ("data", "no_report")  # data compared by sha256; no_report changes no number
#: Options that are not settings of the computation (not compared, not all recorded).
_NOT_SETTINGS = ("out", "force", "progress", "command", "_module", "quiet", "verbose")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_record_arguments(parser)
    parser.add_argument(
        "--out", required=True, type=options.folder_path, metavar="DIR",
        help="results folder (created; a rerun resumes; locked while the study runs)",
    )  # fmt: skip
    add_model_arguments(parser)
    parser.add_argument(
        "--walkers", type=options.positive_int, default=None,
        help="emcee walkers: an even number >= 2 x the sampled parameters (default: 2 x dimension, even, >= 32)",
    )  # fmt: skip
    parser.add_argument(
        "--max-steps", type=options.positive_int, default=DEFAULT_MAX_STEPS,
        help=f"cap on the chain length, >= 1 (default {DEFAULT_MAX_STEPS}); raise it to extend a chain that did not converge",
    )  # fmt: skip
    parser.add_argument(
        "--check-every", type=options.positive_int, default=DEFAULT_CHECK_EVERY,
        help=f"convergence check interval in steps, >= 1 (default {DEFAULT_CHECK_EVERY})"
    )
    parser.add_argument(
        "--priors", default=None, type=options.existing_file, metavar="FILE.toml",
        help="priors of some parameters (distribution and bounds, TOML; docs/method.md 'Priors file'); "
        "the others keep the defaults",
    )  # fmt: skip
    parser.add_argument("--moves", default="de", choices=("de", "stretch"), help="emcee moves (default de: differential evolution)")
    parser.add_argument("--force", action="store_true", help="discard a different (or damaged) run already in DIR")
    parser.add_argument("--no-report", action="store_true", help="skip the report (report.html); write it later with 'report DIR'")
    parser.add_argument(
        "--progress", choices=("auto", "on", "off"), default="auto",
        help="the chain's progress: auto (default) = a bar with the projected steps (50 tau) in a terminal, "
        "else a log line every 10 s (IDENTIFY_PROGRESS_SECONDS); on = the bar; off = neither (-q implies off)",
    )  # fmt: skip


def settings_from_args(args) -> dict:
    """Every option of the computation, JSON-ready (the manifest's ``settings``)."""
    settings = {}
    for key, value in sorted(vars(args).items()):
        if key in _NOT_SETTINGS or key.startswith("_"):
            continue
        settings[key] = value
    settings["data"] = str(args.data)
    if getattr(args, "priors", None):  # the file's content counts, not only its name
        import hashlib

        try:
            settings["priors_sha256"] = hashlib.sha256(Path(args.priors).read_bytes()).hexdigest()
        except OSError:
            pass  # reported by the priors check with the file's name
    return settings


def _say(message: str, level: int = logging.INFO) -> None:
    log_line(message, level)


def run(args) -> int:
    """The study; exit code 0 done and converged, 1 done but the chain did NOT CONVERGE, 2 bad input,
    130 interrupted (:data:`identify.cli.EXIT_CODES`)."""
    from .cli import _input_errors
    from .cmd_fit import FitFailedError
    from .noise import NoQuietSegmentError

    try:
        return run_study(args)
    except (*_input_errors(), NoQuietSegmentError, FitFailedError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _sampled_dimension(model, noise_sigma) -> int:
    """Coordinates the sampler moves: the free parameters, plus ``noise_log_sigma`` when sigma is free."""
    free = int(sum(bool(v) for v in model.parameters.vary))
    return free + (1 if str(noise_sigma or "").strip().lower() == "free" else 0)


def _check_walkers(args, model) -> None:
    from .posterior import default_n_walkers

    if args.walkers is None:
        return
    ndim = _sampled_dimension(model, args.noise_sigma)
    if args.walkers < 2 * ndim or args.walkers % 2:
        raise options.OptionError(
            f"--walkers {args.walkers}: needs an even number >= {2 * ndim} (twice the {ndim} sampled parameters); "
            f"omit it for the default {default_n_walkers(ndim)}"
        )


def run_study(args) -> int:
    """The study (see the module docstring); returns the exit code (0 converged, 1 NOT CONVERGED)."""
    from .cmd_fit import model_from_args
    from .locks import FolderLock

    out = Path(args.out)
    lock = FolderLock(out, command=f"python -m identify study {args.data} --out {args.out}")
    lock.acquire()  # first: a second writer is refused at once, before anything is written
    try:
        if lock.stale_note():
            _say(f"note: {lock.stale_note()}")
        try:
            model = model_from_args(args)
        except ValueError as exc:
            raise options.OptionError(str(exc)) from None
        _check_walkers(args, model)
        if getattr(args, "priors", None):  # checked before anything is written (exit code 2)
            from .priors import apply_priors

            apply_priors(model, args.priors)
        return _run_locked(args, model, out)
    finally:
        lock.release()


def _write_report(out: Path) -> None:
    try:
        from .report import ResultsError, write_report
    except ImportError as exc:
        _say(f"report skipped: identify.report is not available ({exc})")
        return
    try:
        path = write_report(out)
    except ResultsError as exc:  # the results are complete; only the page could not be drawn
        _say(f"report not written: {exc}")
        return
    _say(f"report: {path}")


def _holds_finished_result(state) -> bool:
    """The folder holds a complete result (a posterior summary of the stored chain) that a
    raised ``--max-steps`` is about to extend."""
    post = state.posterior
    return bool(post is not None and state.chain_steps and post.get("n_steps") == state.chain_steps)


#: The copy of a finished chain that a raised --max-steps extends (renamed over chain.h5 when done).
_EXTENDING = ".chain.h5.extending"


@contextlib.contextmanager
def _chain_to_extend(chain: Path, state):
    """The chain file to sample into. A finished chain (its summary describes it) is
    extended on a copy that replaces it when sampling ends, by convergence, the cap or an
    interruption, so a crash (``kill -9``, power loss) during an HDF5 write can never
    damage the finished result; an unfinished chain is continued in place (a ``kill -9``
    loses at most its last second)."""
    work = chain.with_name(_EXTENDING)
    work.unlink(missing_ok=True)  # left by a crash: the finished chain.h5 is intact
    if not _holds_finished_result(state):
        yield chain
        return
    shutil.copyfile(chain, work)
    try:
        yield work
    except KeyboardInterrupt:
        os.replace(work, chain)  # the completed steps are kept, as for any interrupted run
        raise
    except BaseException:
        work.unlink(missing_ok=True)
        raise
    os.replace(work, chain)


def _run_locked(args, model, out: Path) -> int:
    import numpy as np

    from .cmd_fit import LONG_RECORD_SAMPLES, fit_or_explain, format_fit_table, noise_from_args, print_record_notes
    from .cmd_fit import record_from_args
    from .identifiability import analyse_fit
    from .posterior import LogPosterior, default_n_walkers, initial_walkers, sample_posterior
    from .results import (
        FILES,
        RunMismatchError,
        RunState,
        build_manifest,
        build_summary,
        check_resumable,
        finish_manifest,
        inspect_run,
        load_fit,
        now_iso,
        remove_run,
        write_data,
        write_fit,
        write_json,
        write_summary,
    )

    t_start = _time.perf_counter()
    started = now_iso()
    # everything that can be checked is checked before the first write
    record = record_from_args(args)
    print_record_notes(record)
    noise = noise_from_args(args, record)
    settings = settings_from_args(args)
    manifest = build_manifest(seed=args.seed, record=record, settings=settings, started=started, task="study")
    (out / _EXTENDING).unlink(missing_ok=True)  # an extension's copy left by a crash; chain.h5 is intact
    if args.force:
        removed = remove_run(out)
        if removed:
            _say(f"--force: removed the run in {out} ({', '.join(removed)})")
        state = RunState()
    else:
        state = inspect_run(out)
        if state.manifest is None and (state.has_fit or state.chain_steps is not None):
            raise RunMismatchError(
                f"{out} holds results ({FILES['fit'] if state.has_fit else FILES['chain']}) but no manifest.json, so "
                "they cannot be matched with this command. Nothing was changed. Use --force to discard them, or "
                "another --out folder"
            )
        try:
            check_resumable(out, manifest, ignore=RESUMABLE_SETTINGS, chain_steps=state.chain_steps)
        except RunMismatchError:
            if state.status != "failed" or state.chain_steps:
                raise
            # a run that failed before sampling holds nothing of value: replaced
            _say(f"note: {out} held a run with other settings that failed before sampling; it is replaced")
            remove_run(out)
            state = RunState()
        if state.finished(args.max_steps):
            if not state.has_data:  # derived from the record, whose SHA-256 matched: repaired
                write_data(out, record)
                _say(f"rewrote {out / FILES['data']} (it was missing or damaged) from {args.data}")
            post = state.posterior
            verdict = "converged" if post.get("converged") else "NOT converged, at the cap"
            _say(
                f"{out} already holds this study, finished ({verdict}: {state.chain_steps} steps); "
                "nothing to do, no result rewritten (raise --max-steps to extend a chain that did not converge)"
            )
            if not args.no_report and not (out / FILES["report"]).exists():
                _write_report(out)
            return 0 if post.get("converged") else EXIT_FINDING
    if state.manifest is not None:
        manifest["started"] = state.manifest.get("started", started)
        manifest["runs"] = state.manifest.get("runs", [])
        _say(f"resuming the run in {out} (same data, seed and settings)")

    status = "interrupted"
    error = None
    wrote_manifest = False
    extending = _holds_finished_result(state)
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
        _say(f"noise: sigma = {noise.sigma:.4g} {record.output_unit}, {noise.kind}, source {noise.source}")
        lap("load_and_noise")

        # 2. least squares (reused when the folder already holds it)
        fit_path = out / FILES["fit"]
        if state.has_fit:
            fit = load_fit(out)
            _say(f"least squares: reusing {fit_path}")
        else:
            _say(f"least squares: {model!r}, {args.n_starts} starts ...")
            verbose = len(record) >= LONG_RECORD_SAMPLES
            fit = fit_or_explain(record, model, noise=noise, n_starts=args.n_starts, rng=lsq_rng, verbose=verbose)
        # the first writes: the record, the manifest (the run is in progress), the fit
        if not state.has_data:
            write_data(out, record)
        if not extending:  # a finished result's manifest changes only when its extension ends
            write_json(out / FILES["manifest"], manifest)
        wrote_manifest = True
        if not state.has_fit:
            write_fit(out, fit)
        print(format_fit_table(fit, record))
        lap("least_squares")

        # 3. identifiability
        ident = analyse_fit(fit, record)
        print(ident.describe())
        if state.posterior is None:  # never replace a finished posterior summary by an unfinished one
            write_summary(out, build_summary(record, fit, ident, None))
        lap("identifiability")

        # 4. posterior
        post_model, priors = fit.model, None
        if getattr(args, "priors", None):
            from .priors import apply_priors

            post_model, priors = apply_priors(fit.model, args.priors, start=fit.theta,
                                              start_name="least-squares estimate")  # fmt: skip
            _say(f"priors: {', '.join(f'{n} {p.distribution}' for n, p in priors.items())} from {args.priors}")
        log_post = LogPosterior(record, post_model, fit.noise, priors=priors)
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
        if progress is None and getattr(args, "quiet", 0):
            progress = False  # -q: no bar and no progress lines
        _say(f"posterior: {n_walkers} walkers x {log_post.ndim} parameters, up to {args.max_steps} steps ({args.moves} moves)")
        with _chain_to_extend(out / FILES["chain"], state) as chain_path:
            posterior = sample_posterior(
                log_post,
                lambda n, r: initial_walkers(log_post, mean, cov, n, r),
                chain_path,
                posterior_rng,
                n_walkers=n_walkers,
                max_steps=args.max_steps,
                check_every=args.check_every,
                moves=args.moves,
                progress=progress,
                log=_say,
            )
        summary = build_summary(record, fit, ident, posterior)
        from .priors import prior_table

        summary["priors"] = prior_table(log_post)
        write_summary(out, summary)
        from .inference import sampled_units, write_chain_attributes, write_inference_data

        write_chain_attributes(out / FILES["chain"], log_post.names, sampled_units(log_post, record))
        write_inference_data(out, record, log_post, posterior, seed=args.seed)
        _say(f"posterior: ArviZ InferenceData in {out / 'posterior.nc'}")
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
            _write_report(out)
            lap("report")
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except BaseException as exc:
        if status == "interrupted":  # failed before the posterior was summarised
            status, error = "failed", f"{type(exc).__name__}: {exc}"
        raise
    finally:
        if wrote_manifest and not (extending and status == "failed"):  # a failed extension leaves all as it was
            manifest = finish_manifest(
                manifest, started=started, seconds=_time.perf_counter() - t_start, status=status, phases=phases, error=error
            )
            write_json(out / FILES["manifest"], manifest)
    _say("times: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in phases.items()))
    _say(f"study finished in {_time.perf_counter() - t_start:.1f} s: {out}")
    if not posterior.converged:
        _say(f"exit code {EXIT_FINDING}: the chain did NOT CONVERGE (raise --max-steps to extend it)", logging.WARNING)
        return EXIT_FINDING
    return 0
