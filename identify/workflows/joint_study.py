"""The study of several records of one transducer: its summary (:func:`build_joint_summary`); the
run itself is :func:`identify.workflows.joint_run.study_records`.

:func:`identify.workflows.study.study` given a list of two or more records runs this; one record
(or a list of one) is the study of one record, unchanged. The steps and the folder's rules are
the same (lock, checks before the first write, resume, ``force``, the manifest kept current):

* each record's noise from its own quiet start (a record without one is refused, naming it);
* the joint least squares (:func:`identify.fitting.joint.fit_joint`: the transducer shared,
  each further record's run parameters and sensor zero its own) and the consistency test of
  the records (a warning naming the record that disagrees);
* identifiability of the joint parameters (the Jacobian of every record's whitened residual);
* the emcee posterior of the joint layout (:class:`identify.fitting.joint_posterior.JointLogPosterior`:
  the log-likelihood summed over the records), with the same convergence rule, cap and resume;
* leave one record out (:func:`identify.fitting.joint.leave_one_record_out`);
* ``summary.json`` (the summary of one record for record 1's vector, the per-record parameters
  appended, and ``records``, ``consistency``, ``leave_one_record_out``), ``posterior.nc`` with one
  variable per record, ``chain.h5``, ``fit.json`` (:meth:`identify.fitting.joint.JointFit.to_json`),
  every record's data (``data.npz``, ``data_record<k>.npz``) and the report
  (:mod:`identify.output.joint_report`).
"""

from __future__ import annotations

import numpy as np

from ..fitting.posterior import DIAGNOSTICS
from ..output.results import build_summary, jsonable

__all__ = ["build_joint_summary"]


def _extra_parameters(fit, posterior, units) -> list[dict]:
    """``summary.json`` entries of the joint parameters beyond the model's (each further record's
    own run parameters and zero), with the keys of the model's entries."""
    joint = fit.joint
    index = {n: j for j, n in enumerate(posterior.names)} if posterior is not None else {}
    quantiles = posterior.quantiles((0.025, 0.5, 0.975)) if posterior is not None else None
    out = []
    for i in range(joint.model.n_parameters, joint.n_parameters):
        name = joint.names[i]
        entry = {
            "name": name,
            "unit": units.get(name, ""),
            "table1": None,
            "lsq": float(fit.theta[i]),
            "lsq_stderr": float(fit.stderr[i]),
            **{k: None for k in ("mean", "sd", "median", "lo95", "hi95", "tau", "ess")},
            **{k: None for k in DIAGNOSTICS},
            "vary": bool(joint.parameters.vary[i]),
        }
        if name in index:
            j = index[name]
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
        out.append(entry)
    return out


def build_joint_summary(fit, identifiability=None, posterior=None, units=None, loro=None) -> dict:
    """``summary.json`` of a study of several records: :func:`identify.output.results.build_summary`
    of record 1 (the shared parameters and record 1's run), its ``parameters`` extended by the
    further records' own, with ``records`` (file, samples, noise sigma, rms, max error, rms alone,
    per record), ``consistency``, ``alone`` (each record's separate least squares: value and
    stderr of every model parameter) and ``leave_one_record_out`` when given."""
    summary = build_summary(fit.records[0], fit.fits[0], identifiability, posterior)
    summary["parameters"] += _extra_parameters(fit, posterior, units or {})
    summary["records"] = [
        {
            "file": str(rec.source),
            "samples": len(rec.time),
            "noise_sigma": float(f.noise.sigma),
            "noise": f.noise.to_dict(),
            "rms": float(f.rms),
            "max_error_pct": float(f.max_error_pct),
            "rms_alone": float(alone.rms),
        }
        for rec, f, alone in zip(fit.records, fit.fits, fit.separate)
    ]
    summary["consistency"] = dict(fit.consistency)
    summary["alone"] = [
        {"file": str(rec.source), "theta": alone.theta_dict(), "stderr": dict(zip(alone.model.names, alone.stderr))}
        for rec, alone in zip(fit.records, fit.separate)
    ]
    summary["fit"]["rms"] = float(fit.rms)
    if loro is not None:
        summary["leave_one_record_out"] = list(loro)
    return jsonable(summary)
