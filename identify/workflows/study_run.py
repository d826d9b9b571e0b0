"""The steps of one study (:func:`identify.workflows.study.study`) and what they share with the
study of several records (:mod:`identify.workflows.joint_run`): the run in its results folder
(:class:`StudyRun`: noise, least squares, identifiability, posterior, diagnosis, comparison,
report, the manifest kept current), the result object and the checks made before anything
is written."""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from model import Model

from ..defaults import EXIT_FINDING, EXIT_OK
from ..diagnosis import diagnose
from ..fitting.identifiability import analyse_fit
from ..fitting.inference import sampled_units, write_chain_attributes, write_inference_data
from ..fitting.noise import estimate_noise
from ..fitting.parametrisation import normalised_model
from ..fitting.posterior import LogPosterior, default_n_walkers, initial_walkers, sample_posterior
from ..fitting.priors import apply_priors, prior_table
from ..fitting.terms import select_terms
from ..output.diagnosis_files import COMPARISON_FILE, earlier_study, next_step, write_diagnosis
from ..output.report import ResultsError, residual_above_noise, write_report
from ..output.results import (
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
    read_json,
    remove_run,
    write_data,
    write_fit,
    write_json,
    write_summary,
)
from .fit import LONG_RECORD_SAMPLES, fit_or_explain, format_fit_table, say

__all__ = [
    "StudyResult",
    "StudyRun",
    "RESUMABLE_SETTINGS",
    "api_settings",
    "chain_to_extend",
    "check_priors",
    "check_walkers",
    "default_model",
    "priors_settings",
    "sampled_dimension",
    "write_report_or_say",
]

#: Settings that may differ when a run is resumed (``max_steps`` is checked against the
#: stored chain instead, :func:`identify.output.results.check_resumable`).
RESUMABLE_SETTINGS = ("data", "no_report", "no_diagnose")  # data compared by sha256; the others change no number
#: The copy of a finished chain that a raised max_steps extends (renamed over chain.h5 when done).
_EXTENDING = ".chain.h5.extending"


@dataclass
class StudyResult:
    """What :func:`study` computed and where it is.

    Attributes
    ----------
    out : pathlib.Path
        The results folder.
    record : identify.data.records.Record
        The record studied.
    fit : identify.fitting.lsq.FitResult
        The least-squares fit (the stored one when the folder held it).
    summary : dict
        The contents of ``summary.json`` (model, noise, fit, identifiability, posterior).
    status : str
        ``"converged"``, ``"not converged"`` (the chain reached ``max_steps``) or
        ``"finished before"`` (the folder already held this finished study; nothing ran).
    posterior : identify.fitting.posterior.PosteriorResult or None
        The chain's samples and diagnostics; None when the study had finished before.
    identifiability : identify.fitting.identifiability.IdentifiabilityResult or None
        The weak directions at the fit; None when the study had finished before.
    paths : dict of str to pathlib.Path
        The files of the folder by role (:data:`identify.output.results.FILES`) that exist.

    A chain that did not converge is a complete result with a finding, not an error:
    :attr:`converged` is False and :attr:`exit_code` 1, the command line's exit code.
    """

    out: Path
    record: object
    fit: object
    summary: dict
    status: str
    posterior: object = None
    identifiability: object = None
    paths: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        """Whether the chain converged (for ``"finished before"``: the stored summary's verdict)."""
        if self.posterior is not None:
            return bool(self.posterior.converged)
        return bool((self.summary.get("posterior") or {}).get("converged"))

    @property
    def exit_code(self) -> int:
        """The command line's exit code for this result: 0 converged, 1
        (:data:`identify.defaults.EXIT_FINDING`) the chain did NOT CONVERGE (a finding:
        raise ``max_steps`` to extend it)."""
        return EXIT_OK if self.converged else EXIT_FINDING


def sampled_dimension(model, noise_sigma) -> int:
    """Coordinates the sampler moves: the free parameters, plus ``noise_log_sigma`` when sigma is free."""
    free = int(sum(bool(v) for v in model.parameters.vary))
    return free + (1 if str(noise_sigma or "").strip().lower() == "free" else 0)


def check_walkers(walkers, model, noise_sigma, flag="walkers") -> None:
    """Raise a ValueError naming ``flag`` unless ``walkers`` (None: the default) suits the model."""
    if walkers is None:
        return
    ndim = sampled_dimension(model, noise_sigma)
    if walkers < 2 * ndim or walkers % 2:
        raise ValueError(
            f"{flag} {walkers}: needs an even number >= {2 * ndim} (twice the {ndim} sampled parameters); "
            f"omit it for the default {default_n_walkers(ndim)}"
        )


def check_priors(priors, model):
    """Raise a :class:`identify.fitting.priors.PriorsError` unless the priors file ``priors``
    (None: none) suits ``model`` (names, distributions, bounds around the defaults)."""
    if priors is None:
        return

    apply_priors(model, priors)


def priors_settings(priors) -> dict:
    """The manifest's settings of a priors file: its path and the SHA-256 of its content (a
    file edited between runs is another study)."""
    if priors is None:
        return {"priors": None}

    settings = {"priors": str(priors)}
    try:
        settings["priors_sha256"] = hashlib.sha256(Path(priors).read_bytes()).hexdigest()
    except OSError:
        pass  # reported by the priors check with the file's name
    return settings


def default_model(model):
    """The study's model: the paper's GPI by default; alpha pinned (the normalisation) unless it is."""
    if model is None:
        return normalised_model(Model([], n_operators=12, reading="swapped"))
    alpha_free = dict(zip(model.names, model.parameters.vary)).get("alpha", False)
    return normalised_model(model) if alpha_free else model


def api_settings(
    record,
    model,
    *,
    seed,
    noise_sigma,
    n_starts,
    walkers,
    max_steps,
    check_every,
    moves,
    report,
    priors,
    select_terms=True,
    diagnose=True,
):
    """The manifest's settings for a call from Python, with the keys the command line records."""
    return {
        **({} if select_terms else {"all_terms": True}),  # recorded when set (runs before it had every term)
        **priors_settings(priors),
        "check_every": check_every,
        "effects": ",".join(model.effect_names),
        "every": 1,
        "input_column": record.input_name,
        "input_unit": record.input_unit,
        "max_steps": max_steps,
        "moves": moves,
        "n_operators": model.n_operators,
        "n_starts": n_starts,
        "no_report": not report,
        "no_diagnose": not diagnose,
        "noise_sigma": noise_sigma,
        "output_column": record.output_name,
        "output_unit": record.output_unit,
        "reading": model.reading,
        "seed": seed,
        "time_column": getattr(record, "time_name", "time"),
        "walkers": walkers,
        "data": str(record.source),
    }


def _holds_finished_result(state) -> bool:
    """The folder holds a complete result (a posterior summary of the stored chain) that a
    raised ``max_steps`` is about to extend."""
    post = state.posterior
    return bool(post is not None and state.chain_steps and post.get("n_steps") == state.chain_steps)


@contextlib.contextmanager
def chain_to_extend(chain: Path, state):
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


def write_report_or_say(out: Path, log=say) -> None:
    """Write ``out/report.html``; a report that cannot be drawn is one line, not a failure."""
    try:
        path = write_report(out)
    except ResultsError as exc:  # the results are complete; only the page could not be drawn
        log(f"report not written: {exc}")
        return
    log(f"report: {path}")


class StudyRun:
    """One call of :func:`study`: its inputs and the named steps of the run."""

    def __init__(self, out, record, model, settings, *, quiet, **options):
        self.out, self.record, self.model, self.settings = out, record, model, settings
        self.options = options
        self.log = (lambda message, level=logging.INFO: None) if quiet else say
        self.show = (lambda text: None) if quiet else print
        self.phases: dict[str, float] = {}
        self._clock = _time.perf_counter()

    def lap(self, name: str) -> None:
        now = _time.perf_counter()
        self.phases[name] = now - self._clock
        self._clock = now

    def execute(self) -> StudyResult:
        """Check everything that can be checked, then run or resume (the study's order of steps)."""
        self.t_start, self.started = _time.perf_counter(), now_iso()
        # everything that can be checked is checked before the first write
        self.noise = estimate_noise(self.record, noise_sigma=self.options["noise_sigma"])
        self.manifest = build_manifest(
            seed=self.options["seed"], record=self.record, settings=self.settings, started=self.started, task="study"
        )
        (self.out / _EXTENDING).unlink(missing_ok=True)  # an extension's copy left by a crash; chain.h5 is intact
        state = self.inspect_folder()
        if state is None:
            return self.finished_before()
        if state.manifest is not None:
            self.manifest["started"] = state.manifest.get("started", self.started)
            self.manifest["runs"] = state.manifest.get("runs", [])
            self.log(f"resuming the run in {self.out} (same data, seed and settings)")
        return self.compute(state)

    def inspect_folder(self):
        """The folder's :class:`~identify.output.results.RunState`, or None when it holds this study, finished."""
        out = self.out
        if self.options["force"]:
            removed = remove_run(out)
            if removed:
                self.log(f"--force: removed the run in {out} ({', '.join(removed)})")
            return RunState()
        state = inspect_run(out)
        if state.manifest is None and (state.has_fit or state.chain_steps is not None):
            raise RunMismatchError(
                f"{out} holds results ({FILES['fit'] if state.has_fit else FILES['chain']}) but no manifest.json, so "
                "they cannot be matched with this command. Nothing was changed. Use --force to discard them, or "
                "another --out folder"
            )
        try:
            check_resumable(out, self.manifest, ignore=RESUMABLE_SETTINGS, chain_steps=state.chain_steps)
        except RunMismatchError:
            if state.status != "failed" or state.chain_steps:
                raise
            # a run that failed before sampling holds nothing of value: replaced
            self.log(f"note: {out} held a run with other settings that failed before sampling; it is replaced")
            remove_run(out)
            state = RunState()
        if state.finished(self.options["max_steps"]):
            self.repair_finished(state)
            return None
        return state

    def repair_finished(self, state) -> None:
        """A finished study: rewrite a missing data file, say so, write a missing report."""
        out = self.out
        if not state.has_data:  # derived from the record, whose SHA-256 matched: repaired
            write_data(out, self.record)
            self.log(f"rewrote {out / FILES['data']} (it was missing or damaged) from {self.settings.get('data')}")
        post = state.posterior
        verdict = "converged" if post.get("converged") else "NOT converged, at the cap"
        self.log(
            f"{out} already holds this study, finished ({verdict}: {state.chain_steps} steps); "
            "nothing to do, no result rewritten (raise --max-steps to extend a chain that did not converge)"
        )
        if self.options["report"] and not (out / FILES["report"]).exists():
            write_report_or_say(out, self.log)

    def finished_before(self) -> StudyResult:
        summary_path = self.out / FILES["summary"]
        summary = read_json(summary_path) if summary_path.exists() else {}
        return StudyResult(self.out, self.record, load_fit(self.out), summary, "finished before", paths=self.paths())

    def paths(self) -> dict:
        return {role: self.out / name for role, name in FILES.items() if (self.out / name).exists()}

    def compute(self, state) -> StudyResult:
        """Least squares, identifiability, posterior and report, with the manifest kept current."""
        status, error, self.wrote_manifest = "interrupted", None, False
        extending = _holds_finished_result(state)
        try:
            rng = np.random.default_rng(self.options["seed"])
            lsq_rng, posterior_rng = rng.spawn(2)
            noise = self.noise
            self.log(f"noise: sigma = {noise.sigma:.4g} {self.record.output_unit}, {noise.kind}, source {noise.source}")
            self.lap("load_and_noise")
            fit = self.least_squares(state, lsq_rng, extending)
            ident = self.identifiability(state, fit)
            posterior, summary = self.posterior(state, fit, ident, posterior_rng)
            status = "converged" if posterior.converged else "not converged"
            self.lap("inference_data")
            self.diagnose(fit, summary)
            self.comparison()
            self.report()
        except KeyboardInterrupt:
            status = "interrupted"
            raise
        except BaseException as exc:
            if status == "interrupted":  # failed before the posterior was summarised
                status, error = "failed", f"{type(exc).__name__}: {exc}"
            raise
        finally:
            if self.wrote_manifest and not (
                extending and status == "failed"
            ):  # a failed extension leaves all as it was
                manifest = finish_manifest(
                    self.manifest,
                    started=self.started,
                    seconds=_time.perf_counter() - self.t_start,
                    status=status,
                    phases=self.phases,
                    error=error,
                )
                write_json(self.out / FILES["manifest"], manifest)
        self.log("times: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in self.phases.items()))
        self.log(f"study finished in {_time.perf_counter() - self.t_start:.1f} s: {self.out}")
        return StudyResult(self.out, self.record, fit, summary, status, posterior, ident, self.paths())

    def least_squares(self, state, lsq_rng, extending):
        """The fit (reused when the folder holds it), then the first writes: record, manifest, fit."""
        out, record, model = self.out, self.record, self.model
        fit_path = out / FILES["fit"]
        if state.has_fit:
            fit = load_fit(out)
            self.log(f"least squares: reusing {fit_path}")
        else:
            self.log(f"least squares: {model!r}, {self.options['n_starts']} starts ...")
            verbose = len(record) >= LONG_RECORD_SAMPLES
            fit = fit_or_explain(
                record, model, noise=self.noise, n_starts=self.options["n_starts"], rng=lsq_rng, verbose=verbose
            )
            if self.options["select_terms"]:
                fit = select_terms(record, fit, rng=lsq_rng, log=self.log)
        # the first writes: the record, the manifest (the run is in progress), the fit
        if not state.has_data:
            write_data(out, record)
        if not extending:  # a finished result's manifest changes only when its extension ends
            write_json(out / FILES["manifest"], self.manifest)
        self.wrote_manifest = True
        if not state.has_fit:
            write_fit(out, fit)
        self.show(format_fit_table(fit, record))
        self.lap("least_squares")
        return fit

    def identifiability(self, state, fit):
        ident = analyse_fit(fit, self.record)
        self.show(ident.describe())
        if state.posterior is None:  # never replace a finished posterior summary by an unfinished one
            write_summary(self.out, build_summary(self.record, fit, ident, None))
        self.lap("identifiability")
        return ident

    def posterior(self, state, fit, ident, posterior_rng):
        """The emcee chain from the fit's Laplace approximation, its summary and exports."""
        out, record, opts = self.out, self.record, self.options
        post_model, priors = fit.model, None
        if opts["priors"] is not None:
            post_model, priors = apply_priors(
                fit.model, opts["priors"], start=fit.theta, start_name="least-squares estimate"
            )
            self.log(f"priors: {', '.join(f'{n} {p.distribution}' for n, p in priors.items())} from {opts['priors']}")
        log_post = LogPosterior(record, post_model, fit.noise, priors=priors)
        free = log_post.free
        mean = fit.theta[free]
        cov = fit.covariance[np.ix_(free, free)]
        if log_post.free_sigma:
            dof = len(record.time) - free.size
            mean = np.append(mean, np.log(fit.noise.sigma))
            cov = np.pad(cov, ((0, 1), (0, 1)))
            cov[-1, -1] = 1.0 / (2.0 * dof)
        posterior = self.sample(log_post, mean, cov, state, posterior_rng, "posterior")
        summary = build_summary(record, fit, ident, posterior)
        summary["priors"] = prior_table(log_post)
        write_summary(out, summary)
        write_chain_attributes(out / FILES["chain"], log_post.names, sampled_units(log_post, record))
        self.lap("posterior")  # the sampling and its summary; the export is the phase "inference_data"
        write_inference_data(out, record, log_post, posterior, seed=opts["seed"])
        self.log(f"posterior: ArviZ InferenceData in {out / 'posterior.nc'}")
        self.show(f"posterior: {posterior.message}")
        self.show(
            f"acceptance fraction {posterior.acceptance_fraction:.3f}; tau_max {posterior.tau_max:.1f} steps; "
            f"{posterior.samples.shape[0]} samples after discarding {posterior.discard} and thinning by "
            f"{posterior.thin}"
        )
        return posterior, summary

    def sample(self, log_post, mean, cov, state, posterior_rng, what: str):
        """The emcee chain of ``log_post`` from walkers around ``mean``/``cov`` into chain.h5 (a
        raised max_steps extends a finished chain's copy); ``what`` heads the log line."""
        opts = self.options
        n_walkers = opts["walkers"] or default_n_walkers(log_post.ndim)
        self.log(
            f"{what}: {n_walkers} walkers x {log_post.ndim} parameters, up to {opts['max_steps']} steps "
            f"({opts['moves']} moves)"
        )
        with chain_to_extend(self.out / FILES["chain"], state) as chain_path:
            return sample_posterior(
                log_post,
                lambda n, r: initial_walkers(log_post, mean, cov, n, r),
                chain_path,
                posterior_rng,
                n_walkers=n_walkers,
                max_steps=opts["max_steps"],
                check_every=opts["check_every"],
                moves=opts["moves"],
                reference=mean,
                progress=opts["progress"],
                log=self.log,
            )

    def diagnose(self, fit, summary) -> None:
        """The diagnosis, when asked for and the residual is above the noise (not for a free sigma,
        which the residual itself sets); its verdict and the next command are printed."""
        if not self.options["diagnose"] or not residual_above_noise(summary):
            return
        self.log("the residual is above the noise: diagnosing which effect is missing (--no-diagnose skips it) ...")
        try:
            found = diagnose(
                self.record,
                fit.model,
                noise=fit.noise,
                fit=fit,
                rng=np.random.default_rng(self.options["seed"]),
                progress=lambda message: self.log(f"diagnosis: {message}"),
            )
        except ValueError as exc:  # e.g. a record the diagnosis cannot whiten: the study stands
            self.log(f"diagnosis skipped: {exc}")
            return
        write_diagnosis(found, self.record, out_dir=self.out)
        self.show(found.summary())
        sentence, command = next_step(
            found.to_dict(), data_file=self.settings.get("data"), effects=fit.model.effect_names, out_dir=self.out
        )
        self.show(sentence + (f"\nnext: {command}" if command else ""))
        self.lap("diagnosis")

    def comparison(self) -> None:
        """Name the earlier study this one is compared with (``compare``, else found by manifest)."""
        earlier, found = self.options["compare"], "given (--compare)"
        if earlier is None:
            earlier, found = earlier_study(self.out, self.record.sha256, self.model.effect_names), "found by manifest"
        if earlier is None:
            (self.out / COMPARISON_FILE).unlink(missing_ok=True)
            return
        write_json(self.out / COMPARISON_FILE, {"earlier": str(earlier), "found": found})
        self.log(f"compared with the earlier study {earlier} ({found})")

    def report(self) -> None:
        if not self.options["report"]:
            self.log(f"report skipped (--no-report); write it with: python -m identify report {self.out}")
            return
        write_report_or_say(self.out, self.log)
        self.lap("report")
