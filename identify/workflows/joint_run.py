"""The study of several records of one transducer: :func:`study_records` and its run, the
steps of :class:`identify.workflows.study_run.StudyRun` on the joint layout (the transducer shared,
each record's run and sensor zero its own; the method in docs/method.md). The summary's
joint parts are built by :mod:`identify.workflows.joint_study`."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..data.locks import FolderLock
from ..defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS, DEFAULT_N_STARTS
from ..diagnosis import diagnose
from ..fitting.identifiability import analyse_identifiability
from ..fitting.inference import write_chain_attributes
from ..fitting.joint import (
    JointModel,
    JointResiduals,
    check_records,
    joint_fit_from_json,
    joint_manifest_data,
    leave_one_record_out,
    record_noises,
)
from ..fitting.joint_posterior import JointLogPosterior, joint_sampled_units, write_joint_inference_data
from ..fitting.lsq import parameter_units
from ..fitting.priors import apply_priors, prior_table
from ..fitting.terms import optional_terms
from ..fitting.threads import single_threaded_blas
from ..output.diagnosis_files import write_diagnosis
from ..output.report import RMS_RATIO_LIMIT
from ..output.results import FILES, read_json, record_data_file, write_data, write_json, write_summary
from .fit import fit_records, format_joint_fit_table, select_terms_of_records, separate_fits_or_explain
from .joint_study import build_joint_summary
from .study_run import (
    StudyResult,
    StudyRun,
    api_settings,
    check_priors,
    check_walkers,
    default_model,
)

__all__ = ["study_records"]


class _JointRun(StudyRun):
    """One call of :func:`study_records`: the steps of :class:`identify.workflows.study_run.StudyRun` on
    several records."""

    def diagnose(self, fit, summary) -> None:
        """The joint diagnosis (each record alone, then the explanations on all together), when
        asked for and any record's residual is above its noise."""
        rows = summary.get("records") or []
        if not self.options["diagnose"] or not any(r["rms"] > RMS_RATIO_LIMIT * r["noise_sigma"] for r in rows):
            return
        self.log("a record's residual is above its noise: the joint diagnosis (--no-diagnose skips it) ...")
        try:
            found = diagnose(
                list(self.records),
                fit.model,
                rng=np.random.default_rng(self.options["seed"]),
                progress=lambda message: self.log(f"diagnosis: {message}"),
            )
        except ValueError as exc:  # a record the diagnosis cannot whiten: the study stands
            self.log(f"diagnosis skipped: {exc}")
            return
        write_diagnosis(found, list(self.records), out_dir=self.out)
        self.show(found.summary())
        self.lap("diagnosis")

    def comparison(self) -> None:
        """The before-and-after comparison is one record's (its report page); said when asked for."""
        if self.options["compare"] is not None:
            self.log("--compare: the comparison with an earlier study is drawn for one record; skipped here")

    def __init__(self, out, records, model, settings, *, quiet, **options):
        super().__init__(out, records, model, settings, quiet=quiet, **options)
        self.records = records

    def execute(self):
        if self.options["noise_sigma"] is not None:
            raise ValueError(
                "several records are each whitened with the noise of their own quiet start: noise_sigma "
                "(--noise-sigma) applies to one record"
            )
        self.noises = record_noises(self.records)
        for r, (record, noise) in enumerate(zip(self.records, self.noises), start=1):
            self.log(f"record {r}: {record.source}, {len(record.time)} samples, noise sigma {noise.sigma:.4g}")
        self.record = self.records[0]  # the base class's steps read record 1 (its units, its noise line)
        self.joint_data = joint_manifest_data(self.records)
        result = super().execute()
        result.record = self.records
        return result

    # the base class's execute estimates record 1's noise and builds its manifest: both replaced here
    def inspect_folder(self):
        self.noise = self.noises[0]
        self.manifest["data"] = self.joint_data
        return super().inspect_folder()

    def repair_finished(self, state) -> None:
        for r, record in enumerate(self.records, start=1):
            if not (self.out / record_data_file(r)).exists():
                write_data(self.out, record, record_data_file(r))
        state.has_data = True
        super().repair_finished(state)

    def finished_before(self):
        summary_path = self.out / FILES["summary"]
        summary = read_json(summary_path) if summary_path.exists() else {}
        return StudyResult(self.out, self.records, None, summary, "finished before", paths=self.paths())

    def least_squares(self, state, lsq_rng, extending):
        """The joint fit (reused when the folder holds it), then the first writes."""
        out = self.out
        if state.has_fit:
            fit = joint_fit_from_json(read_json(out / FILES["fit"]), self.records, self.noises)
            self.log(f"least squares: reusing {out / FILES['fit']}")
        else:
            self.log(f"least squares of {len(self.records)} records together: {self.model!r} ...")
            separate = None
            if self.options["select_terms"] and optional_terms(self.model):
                separate = separate_fits_or_explain(
                    self.records, self.model, self.noises, n_starts=self.options["n_starts"], rng=lsq_rng, log=self.log
                )
                separate = select_terms_of_records(self.records, separate, rng=lsq_rng, log=self.log)
            fit = fit_records(
                self.records,
                self.model,
                noises=self.noises,
                n_starts=self.options["n_starts"],
                rng=lsq_rng,
                progress=self.log,
                separate=separate,
            )
        for r, record in enumerate(self.records, start=1):
            if not (out / record_data_file(r)).exists():
                write_data(out, record, record_data_file(r))
        if not extending:
            write_json(out / FILES["manifest"], self.manifest)
        self.wrote_manifest = True
        if not state.has_fit:
            write_json(out / FILES["fit"], fit.to_json())
        self.show(format_joint_fit_table(fit))
        if not fit.consistency.get("consistent", True):
            self.log(f"warning: {fit.consistency['message']}", logging.WARNING)
        self.lap("least_squares")
        return fit

    def identifiability(self, state, fit):
        residuals = JointResiduals(fit.records, fit.joint, fit.noises)
        x = fit.theta[residuals.free]
        with single_threaded_blas():
            jac = residuals.central_jacobian(x)
        names = [fit.joint.names[i] for i in residuals.free]
        ident = analyse_identifiability(jac, x, names)
        self.show(ident.describe())
        if state.posterior is None:
            write_summary(self.out, build_joint_summary(fit, ident, None, self.units(fit)))
        self.lap("identifiability")
        return ident

    def units(self, fit) -> dict:
        record = self.records[0]
        by_name = dict(zip(fit.model.names, parameter_units(fit.model, record)))
        units = {}
        for name in fit.joint.names[fit.model.n_parameters :]:
            base = name.rsplit("_r", 1)[0]
            units[name] = record.output_unit if base == "zero" else by_name.get(base, "")
        return units

    def posterior(self, state, fit, ident, posterior_rng):
        """The emcee chain of the joint layout from the joint fit's Laplace approximation, leave one
        record out, the summary and the exports."""
        out, opts = self.out, self.options
        post_model, priors = fit.model, None
        if opts["priors"] is not None:
            post_model, priors = apply_priors(
                fit.model, opts["priors"], start=fit.fits[0].theta, start_name="least-squares estimate"
            )
        joint = JointModel(post_model, fit.joint.n_records, fit.joint.zero_bound)
        log_post = JointLogPosterior(fit.records, joint, fit.noises, priors=priors)
        free = log_post.free
        mean, cov = fit.theta[free], fit.covariance[np.ix_(free, free)]
        posterior = self.sample(log_post, mean, cov, state, posterior_rng, f"posterior of {len(fit.records)} records")
        self.lap("posterior")
        loro = leave_one_record_out(fit, rng=np.random.default_rng(opts["seed"]), progress=self.log)
        for row in loro:
            self.show(
                f"leave one record out: record {row['record']} predicted from the others: RMS {row['rms_sigma']:.2f} "
                f"noise sigmas, {100 * row['inside_95']:.1f} % inside the 95 % predictive band"
            )
        self.lap("leave_one_record_out")
        summary = build_joint_summary(fit, ident, posterior, self.units(fit), loro)
        summary["priors"] = prior_table(log_post)
        write_summary(out, summary)
        write_chain_attributes(out / FILES["chain"], log_post.names, joint_sampled_units(log_post, fit.records[0]))
        write_joint_inference_data(out, fit.records, log_post, posterior, seed=opts["seed"])
        self.log(f"posterior: ArviZ InferenceData in {out / 'posterior.nc'} (one variable per record)")
        self.show(f"posterior: {posterior.message}")
        return posterior, summary


def study_records(records, model=None, *, out, settings=None, lock: bool = True, quiet: bool = False, **options):
    """The study of two or more records of one transducer (:func:`study` given a list: the module
    :mod:`identify.workflows.joint_study` says what is computed and written); the options are
    :func:`study`'s, and so are the result (its ``record`` the list) and the errors. A record that
    cannot join the others (other units, the same data twice, no quiet start) is a ValueError naming
    it, raised before anything is written; ``select_terms`` does not apply (every term is fitted)."""
    records = check_records(records)
    model = default_model(model)
    if options.get("noise_sigma") is not None:
        raise ValueError(
            "several records are each whitened with the noise of their own quiet start: noise_sigma "
            "(--noise-sigma) applies to one record"
        )
    check_priors(options.get("priors"), model)
    if settings is None:
        keys = ("seed", "noise_sigma", "n_starts", "walkers", "max_steps", "check_every", "moves", "priors")
        defaults = {"seed": 0, "n_starts": DEFAULT_N_STARTS, "max_steps": DEFAULT_MAX_STEPS, "moves": "de"}
        given = {k: options.get(k, defaults.get(k)) for k in keys}
        given["check_every"] = options.get("check_every", DEFAULT_CHECK_EVERY)
        settings = api_settings(records[0], model, report=options.get("report", True), **given)
        settings["data"] = [str(r.source) for r in records]
    options = {
        "seed": 0,
        "noise_sigma": None,
        "n_starts": DEFAULT_N_STARTS,
        "walkers": None,
        "max_steps": DEFAULT_MAX_STEPS,
        "check_every": DEFAULT_CHECK_EVERY,
        "moves": "de",
        "priors": None,
        "select_terms": True,
        "force": False,
        "report": True,
        "diagnose": True,
        "compare": None,
        "progress": False if quiet else None,
        **options,
    }
    check_walkers(options["walkers"], _joint_layout(model, len(records)), None)
    run = _JointRun(Path(out), records, model, settings, quiet=quiet, **options)
    if not lock:
        return run.execute()
    sources = ", ".join(repr(str(r.source)) for r in records)
    with FolderLock(run.out, command=f"identify.study([{sources}], out={str(out)!r})") as held:
        if held.stale_note():
            run.log(f"note: {held.stale_note()}")
        return run.execute()


def _joint_layout(model, n_records):
    """The joint layout of ``model`` for ``n_records`` records (what the sampler moves)."""
    return JointModel(model, n_records)
