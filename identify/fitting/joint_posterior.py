r"""The posterior of several records of one transducer, and its ``posterior.nc``.

:class:`JointLogPosterior` is :class:`identify.fitting.posterior.LogPosterior` over the joint
layout (:class:`identify.fitting.joint.JointModel`: the transducer shared, each further record's
run parameters and sensor zero its own): the same priors (the defaults of every parameter, a
record's own copy with the same prior as the original), the same support and labelling, and
the log-likelihood summed over the records, each record's residual scored with its own noise
model (its own quiet start, its own AR(1) correlation and time grid). The records are
independent given the parameters: their sensors' noise does not carry over from one run to
the next.

:func:`write_joint_inference_data` writes ``posterior.nc`` in the layout of
:func:`identify.fitting.inference.write_inference_data`, with one variable per record in the
record-wise groups: ``displacement_record<k>`` with its own time dimension
``time_record<k>`` in ``observed_data``, ``log_likelihood`` and ``posterior_predictive``, so
``az.loo(idata, var_name="displacement_record1")`` scores each record. The pointwise groups
share one draw thinning (a group has one ``draw`` dimension),
:func:`identify.fitting.inference.pointwise_draws` of the records' samples together, so that
draws x samples of all records stays at most :data:`identify.fitting.inference.MAX_POINTWISE`.
"""

from __future__ import annotations

from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import numpy as np

from .inference import (
    FILE,
    LOG_LIKELIHOOD_QUANTUM,
    POINTWISE_CHUNK_SAMPLES,
    pointwise_draws,
    pointwise_log_likelihood,
    predictive_quantum,
    quantised,
    write_netcdf,
)
from .joint import JointModel
from .lsq import parameter_units
from .noise import RowLikelihood, ar1_noise
from .parametrisation import in_record_units
from .posterior import LogPosterior

__all__ = ["JointLogPosterior", "write_joint_inference_data", "joint_sampled_units", "record_variable"]


def record_variable(r: int, name: str = "displacement") -> str:
    """The variable (or time dimension, ``name="time"``) of record ``r`` (from 1) in ``posterior.nc``."""
    return f"{name}_record{r}"


class JointLogPosterior(LogPosterior):
    """Vectorised log-posterior of a joint layout's free parameters on several records.

    Parameters
    ----------
    records : sequence of Record
        Two or more records of one transducer, in the same units.
    joint : JointModel
        The layout (pinned parameters stay at their values).
    noises : sequence of NoiseModel
        Each record's noise; a free sigma is not supported (each record's sigma comes from
        its own quiet start).
    priors : dict, optional
        As for :class:`~identify.fitting.posterior.LogPosterior`.

    Attributes
    ----------
    records, noises : list
    time, current : ndarray
        The longest record's times and every record's input, concatenated: what the sampler's
        coordinates read (input range, duration).
    """

    def __init__(self, records, joint: JointModel, noises, *, priors=None):
        if any(noise.is_free for noise in noises):
            raise ValueError("a free noise sigma is not supported for several records: each has its own quiet start")
        converted = in_record_units(joint.model, records[0])
        if converted is not joint.model:
            joint = JointModel(converted, joint.n_records, joint.zero_bound)
        super().__init__(records[0], joint, noises[0], priors=priors)
        self.joint = joint
        self.records = list(records)
        self.noises = list(noises)
        self.parts = []
        for record, noise in zip(self.records, self.noises):
            time = np.asarray(record.time, dtype=float)
            correlations = noise.step_correlations(time)  # each step's r_k on an uneven grid, else None
            data = np.asarray(record.displacement, dtype=float)
            self.parts.append((time, np.asarray(record.current, dtype=float), data, correlations))
        self._likelihoods = [  # each record's, its checks and constants once
            RowLikelihood(part[2], noise, correlations=part[3]) for part, noise in zip(self.parts, self.noises)
        ]
        longest = max(self.records, key=lambda r: float(np.ptp(r.time)))
        self.time = np.asarray(longest.time, dtype=float)
        self.current = np.concatenate([part[1] for part in self.parts])

    def record_outputs(self, theta, r: int):
        """Record ``r``'s (from 1) model output ``(W, T_r)`` with its zero, and validity ``(W,)``,
        of full joint vectors ``theta`` ``(W, P_joint)``."""
        time, current, *_ = self.parts[r - 1]
        rows, zero = self.joint.record_rows(theta, r)
        try:
            y, valid = self.joint.model.evaluate(rows, time, current)
        except Exception:  # never raise for a walker: one row at a time
            y, valid = np.zeros((rows.shape[0], time.size)), np.zeros(rows.shape[0], dtype=bool)
            for k in range(rows.shape[0]):
                try:
                    yk, vk = self.joint.model.evaluate(rows[k], time, current)
                    y[k], valid[k] = yk[0], vk[0]
                except Exception:
                    self.n_errors += 1
        return y + zero[:, None], np.asarray(valid, dtype=bool)

    def record_log_likelihoods(self, theta) -> np.ndarray:
        """``(K, W)`` each record's log-likelihood of full joint vectors ``(W, P_joint)`` (``-inf``
        where the model is invalid)."""
        theta = np.atleast_2d(theta)
        out = np.full((len(self.parts), theta.shape[0]), -np.inf)
        for r, likelihood in enumerate(self._likelihoods, start=1):
            y, valid = self.record_outputs(theta, r)
            if valid.any():
                rows = np.flatnonzero(valid)
                out[r - 1, rows] = likelihood(y, rows)
        return out

    def __call__(self, x) -> np.ndarray:
        """Log-posterior of ``(W, D)`` coordinates -> ``(W,)``: the prior plus the sum of the
        records' log-likelihoods; 1-D in -> float."""
        x_in = np.asarray(x, dtype=float)
        x2 = np.atleast_2d(x_in)
        out = self.log_prior(x2)
        ok = np.flatnonzero(np.isfinite(out))
        if ok.size:
            out[ok] += self.record_log_likelihoods(self.full_theta(x2[ok])).sum(axis=0)
        out[~np.isfinite(out)] = -np.inf
        return float(out[0]) if x_in.ndim == 1 else out


def _group(n_chain, draw_index):
    return {"chain": np.arange(n_chain), "draw": np.asarray(draw_index)}


def joint_sampled_units(log_post: JointLogPosterior, record) -> list[str]:
    """Units of the sampled coordinates of a joint log-posterior (a record's own copy in its
    original's unit; a zero in the output unit)."""
    model = log_post.joint.model
    by_name = dict(zip(model.names, parameter_units(model, record)))
    units = []
    for name in log_post.names:
        base = name.rsplit("_r", 1)[0] if name not in by_name else name
        units.append(record.output_unit if base == "zero" else by_name.get(base, ""))
    return units


def _record_groups(r, record, log_post, flat, noise, step_draws, shape_head, rng):
    """Record ``r``'s observed data, pointwise log-likelihood and posterior predictive variables."""
    time, _current, data, correlations = log_post.parts[r - 1]
    uneven = None if correlations is None else time
    y, valid = log_post.record_outputs(log_post.full_theta(flat), r)
    pointwise = pointwise_log_likelihood(data[None, :] - y, noise, None, time=uneven)
    pointwise[~valid] = -np.inf
    predictive = y + noise.sigma * ar1_noise(rng.standard_normal(y.shape), noise.correlations_on(time))
    dims = ("chain", "draw", record_variable(r, "time"))
    shape = (*shape_head, time.size)
    chunks = (*shape_head, min(POINTWISE_CHUNK_SAMPLES, time.size))
    name = record_variable(r)
    return (
        (name, ((record_variable(r, "time"),), data, {"unit": record.output_unit, "source": str(record.source)}, None)),
        (
            name,
            (
                dims,
                quantised(pointwise, LOG_LIKELIHOOD_QUANTUM).reshape(shape),
                {"rounded_to": LOG_LIKELIHOOD_QUANTUM},
                chunks,
            ),
        ),
        (
            name,
            (
                dims,
                quantised(predictive, predictive_quantum(noise.sigma)).reshape(shape),
                {"rounded_to": predictive_quantum(noise.sigma), "unit": record.output_unit},
                chunks,
            ),
        ),
    )


def write_joint_inference_data(out_dir, records, log_post: JointLogPosterior, posterior, *, seed=0) -> Path:
    """Write ``DIR/posterior.nc`` of a study of several records (module docstring); returns its path."""
    n_chain = int(posterior.n_walkers)
    draws = np.moveaxis(
        np.asarray(posterior.samples, dtype=float).reshape(-1, n_chain, posterior.samples.shape[1]), 1, 0
    )
    lp = np.asarray(posterior.log_prob, dtype=float).reshape(-1, n_chain).T
    n_draw = draws.shape[1]
    total = sum(len(r.time) for r in records)
    kept, step = pointwise_draws(n_chain, n_draw, total)
    sub = draws[:, kept]
    flat = sub.reshape(-1, sub.shape[2])
    try:
        version = {"arviz_version": metadata.version("arviz")}
    except metadata.PackageNotFoundError:  # pragma: no cover - arviz is a dependency
        version = {}
    stamp = {"created_at": datetime.now(timezone.utc).isoformat(), **version}
    units = joint_sampled_units(log_post, records[0])
    prior_names = getattr(log_post, "prior_names", {})
    whole = (n_chain, n_draw)
    draws_coords = _group(n_chain, np.arange(n_draw))
    pointwise_coords = _group(n_chain, kept)
    observed_coords, observed, loglik, predictive = {}, {}, {}, {}
    rng = np.random.default_rng(seed)
    for r, (record, noise) in enumerate(zip(records, log_post.noises), start=1):
        time_dim = record_variable(r, "time")
        observed_coords[time_dim] = (np.asarray(record.time, dtype=float), {"unit": "s"})
        pointwise_coords[time_dim] = np.asarray(record.time, dtype=float)
        obs, ll, pp = _record_groups(r, record, log_post, flat, noise, step, (n_chain, sub.shape[1]), rng)
        observed[obs[0]], loglik[ll[0]], predictive[pp[0]] = obs[1], ll[1], pp[1]
    run = {
        "source": "msma-gpi study",
        "n_records": len(records),
        "input_unit": records[0].input_unit,
        "output_unit": records[0].output_unit,
        "discard": int(posterior.discard),
        "thin": int(posterior.thin),
    }
    pointwise_attrs = {**stamp, "draw_step": int(step)}
    groups = {
        "posterior": (
            draws_coords,
            {
                n: (("chain", "draw"), draws[:, :, j], {"unit": units[j], "prior": str(prior_names.get(n, ""))}, whole)
                for j, n in enumerate(log_post.names)
            },
            stamp,
        ),
        "sample_stats": (draws_coords, {"lp": (("chain", "draw"), lp, {}, whole)}, stamp),
        "observed_data": (observed_coords, observed, {**stamp, **run}),
        "log_likelihood": (pointwise_coords, loglik, pointwise_attrs),
        "posterior_predictive": (pointwise_coords, predictive, pointwise_attrs),
    }
    path = Path(out_dir) / FILE
    write_netcdf(path, groups)
    return path
