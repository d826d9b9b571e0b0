"""The posterior in the ecosystem's standard forms.

* :func:`write_inference_data` writes ``DIR/posterior.nc``, an ArviZ ``InferenceData``
  (netCDF, read with ``arviz.from_netcdf``):

  ``posterior``
      every draw after burn-in and thinning, dims ``(chain, draw)`` = (walker, draw),
      one variable per sampled parameter with ``unit`` and ``prior`` attributes (the
      draws ``summary.json`` is computed from, so ``az.summary`` gives its means).
  ``sample_stats``
      ``lp`` (log posterior).
  ``observed_data``
      ``displacement`` with the ``time`` coordinate, in the record's units.
  ``log_likelihood``
      ``displacement``: the pointwise log-likelihood, one value per draw and sample
      (the AR(1) noise model's conditional densities, summing to the likelihood), so
      ``az.loo`` and ``az.compare`` compare models, e.g. with and without an effect.
  ``posterior_predictive``
      ``displacement``: model output plus a draw of the fitted noise.

  Thinning: the pointwise groups hold the same ``K`` draws of every walker, every
  ``draw_step``-th (attribute) from the first, ``K = MAX_POINTWISE // (walkers x
  samples)`` (at least 1, at most all): draws x samples stays at most
  :data:`MAX_POINTWISE` values a variable (12 draws a walker, 432 draws, for 36 walkers
  and a 7001-sample record), which holds the file under 10 MB; the ``posterior`` group
  holds all draws. Both pointwise groups have the same ``chain`` and ``draw``
  coordinates, so ``az.loo_pit`` pairs them, and their ``draw`` values are the
  ``posterior`` group's (``idata.posterior.sel(draw=idata.log_likelihood.draw)``). Far
  fewer pointwise draws would worsen ``az.loo``'s Pareto-k diagnostics: ArviZ takes the
  relative efficiency from the ``posterior`` group's ESS over the pointwise draws, so its
  tail fits shrink with them; at 12 a walker the Pareto k's scatter between draws of
  the same chain is as large as at 15 or 16 (``benchmarks/pointwise_draws.py``;
  docs/benchmarks.md, "The results folder").

  Storage: the posterior, ``lp`` and the observed data in float64 (``az.summary`` gives
  ``summary.json``'s means exactly). The pointwise groups are rounded to a stated
  precision, since a value's digits below it are noise and cost most of the file (their
  entropy, not gzip, sets the size): the log-likelihood to the nearest multiple of
  :data:`LOG_LIKELIHOOD_QUANTUM` nats (2^-15, about 3.1e-5: ``az.loo``'s elpd and p_loo
  move by at most half of it per sample, and by 7e-4 on the bundled record; a Pareto k
  by less than 0.1, a fraction of its own Monte Carlo error), the posterior predictive to
  the nearest multiple of the largest power of two at most
  :data:`PREDICTIVE_SIGMA_FRACTION` of the smallest noise sigma (rounding error at most
  sigma/16, adding at most 1/768 of the noise variance, 0.07 % of its sd: far below the
  uncertainty of sigma itself, estimated from the quiet segment). Both are stored as float32 where
  float32 holds the rounded values exactly (float64 otherwise: a record with a large
  offset and little noise), so every reader gets plain floats. Every variable is
  gzip-compressed (level :data:`GZIP_LEVEL`) with byte shuffle (HDF5 filters any netCDF4
  or HDF5 reader decodes),
  the pointwise groups in chunks of all draws x :data:`POINTWISE_CHUNK_SAMPLES` samples.
  The file is written with h5netcdf in the layout ArviZ's ``to_netcdf`` writes, without
  importing ArviZ or xarray.
* :func:`write_chain_attributes` puts the parameter names and units on the emcee group of
  ``chain.h5`` (attributes ``parameter_names``, ``parameter_units``), where
  ``emcee.backends.HDFBackend(path, name="mcmc").open()`` finds them (fixed-length UTF-8
  bytes: ``[n.decode() for n in attrs["parameter_names"]]``).
"""

from __future__ import annotations

import math
import os
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import h5netcdf
import numpy as np

from ..data.fileio import require_space, write_via_temporary
from ..data.hdf5 import open_hdf5
from .chain_file import BACKEND_GROUP, CHAIN_METADATA_BYTES
from .lsq import parameter_units
from .noise import ar1_noise, whiten

__all__ = [
    "MAX_POINTWISE",
    "GZIP_LEVEL",
    "pointwise_draws",
    "FILE",
    "write_inference_data",
    "write_netcdf",
    "write_chain_attributes",
    "sampled_units",
    "pointwise_log_likelihood",
]

#: Largest number of draws x record samples in the pointwise groups (float32: 12.4 MB each
#: before compression, 4-5 MB after).
MAX_POINTWISE = 3_100_000
#: gzip level of posterior.nc's variables (6: 3 % smaller than 4 for 0.3 s more on a 7001-sample
#: record's pointwise groups; 9 saves 1.5 % more for ten times the time).
GZIP_LEVEL = 6
#: Record samples per HDF5 chunk of the pointwise groups (every walker and draw in a chunk:
#: a sample's values over the draws lie 64 values apart, which gzip finds).
POINTWISE_CHUNK_SAMPLES = 64
#: The pointwise log-likelihood is stored rounded to a multiple of this [nats] (2^-15).
LOG_LIKELIHOOD_QUANTUM = 2.0**-15
#: The posterior predictive is stored rounded to a multiple of the largest power of two at
#: most this fraction of the smallest noise sigma.
PREDICTIVE_SIGMA_FRACTION = 1.0 / 8.0
#: File name in the results folder.
FILE = "posterior.nc"


def sampled_units(log_post, record) -> list[str]:
    """Units of the sampled coordinates (``noise_log_sigma``: log of the output unit)."""
    units = parameter_units(log_post.model, record)
    by_name = dict(zip(log_post.model.names, units))
    return [by_name.get(n, f"log({record.output_unit})") for n in log_post.names]


def write_chain_attributes(path, names, units) -> None:
    """Parameter names and units as attributes of ``chain.h5``'s emcee group."""
    require_space(path, CHAIN_METADATA_BYTES)  # HDF5 does not survive a full disk: checked first
    with open_hdf5(os.fspath(path), "a") as f:  # waits for a reader's lock instead of failing
        g = f[BACKEND_GROUP]
        # fixed-length UTF-8 bytes (decode when reading): plain arrays, compared bit for bit by reproduce
        g.attrs["parameter_names"] = np.array([str(n).encode() for n in names], dtype=bytes)
        g.attrs["parameter_units"] = np.array([str(u).encode() for u in units], dtype=bytes)


def pointwise_log_likelihood(residual, noise, sigma=None, *, time=None) -> np.ndarray:
    """``(S, T)`` log-likelihood per sample: the AR(1) conditional Gaussian densities of the
    whitened residuals (:func:`identify.fitting.noise.whiten`, each step's own correlation
    on an uneven ``time`` grid); their sum over T is :func:`identify.fitting.noise.log_likelihood`."""
    e = np.atleast_2d(np.asarray(residual, dtype=float))
    w = whiten(e, noise, sigma, time=time)
    sig = np.asarray(noise.sigma if sigma is None else sigma, dtype=float)
    log_sig = np.log(sig)[:, None] if sig.ndim == 1 else math.log(float(sig))
    out = -0.5 * w * w - log_sig - 0.5 * math.log(2.0 * math.pi)
    if noise.rho != 0.0:
        correlations = noise.step_correlations(time)
        if correlations is None:
            out[:, 1:] -= 0.5 * math.log(1.0 - noise.rho**2)
        else:
            out[:, 1:] -= 0.5 * np.log1p(-correlations * correlations)
    return out


def predictive_quantum(sigma) -> float:
    """The posterior predictive's rounding step [output unit]: the largest power of two at
    most :data:`PREDICTIVE_SIGMA_FRACTION` of the smallest noise sigma ``sigma`` (scalar or
    ``(S, 1)``)."""
    return float(2.0 ** math.floor(math.log2(PREDICTIVE_SIGMA_FRACTION * float(np.min(sigma)))))


def quantised(values, quantum) -> np.ndarray:
    """``values`` rounded to the nearest multiple of ``quantum`` (a power of two), as float32
    when float32 holds every rounded value exactly (at most 2^24 steps from zero), else
    float64; non-finite values kept."""
    rounded = np.round(np.asarray(values, dtype=float) / quantum) * quantum
    largest = float(np.max(np.abs(rounded), where=np.isfinite(rounded), initial=0.0))
    return rounded.astype(np.float32 if largest / quantum <= 2.0**24 else np.float64)


def pointwise_draws(n_chain, n_draw, n_samples) -> tuple[np.ndarray, int]:
    """``(indices, step)``: the draws of every walker the pointwise groups hold, ``K =
    MAX_POINTWISE // (n_chain n_samples)`` of the ``n_draw`` (at least 1, at most all), every
    ``step = n_draw // K``-th from the first (module docstring, "Thinning")."""
    keep = max(1, min(int(n_draw), MAX_POINTWISE // max(1, int(n_chain) * int(n_samples))))
    step = max(1, int(n_draw) // keep)
    return np.arange(keep) * step, step


def _group(n_chain, n_draw, draw_index):
    return {"chain": np.arange(n_chain), "draw": np.asarray(draw_index)}


def _write_netcdf(path, groups) -> None:
    """Write ``groups`` (``{name: (coords, variables, attrs)}``; a coordinate ``values`` or
    ``(values, attrs)``, a variable ``(dims, values, attrs, chunks)``) as the netCDF4 groups
    of an InferenceData file: the layout ``InferenceData.to_netcdf`` writes through
    xarray's h5netcdf engine (dimension scales, coordinate variables), written here with
    h5netcdf alone, so writing it imports neither ArviZ nor xarray (2-3 s); every variable
    gzip-compressed with byte shuffle."""
    packed = dict(compression="gzip", compression_opts=GZIP_LEVEL, shuffle=True)
    with h5netcdf.File(path, "w") as f:
        for name, (coords, variables, attrs) in groups.items():
            g = f.create_group(name)
            g.dimensions = {d: len(v[0] if isinstance(v, tuple) else v) for d, v in coords.items()}
            for d, values in coords.items():
                values, coord_attrs = values if isinstance(values, tuple) else (values, {})
                # long coordinates (time: three copies of the record's grid) compressed too
                coord_packed = packed if np.size(values) > POINTWISE_CHUNK_SAMPLES else {}
                g.create_variable(d, (d,), data=values, **coord_packed).attrs.update(coord_attrs)
            for var, (dims, values, var_attrs, chunks) in variables.items():
                v = g.create_variable(var, dims, data=values, chunks=chunks, **packed)
                v.attrs.update(var_attrs)
            g.attrs.update(attrs)


def write_inference_data(out_dir, record, log_post, posterior, *, seed=0) -> Path:
    """Write ``DIR/posterior.nc`` (module docstring) and return its path.

    The draws are ``posterior.samples`` (the chain after burn-in and thinning, read from
    ``chain.h5`` by :func:`identify.fitting.posterior.posterior_from_backend`), walkers as
    ArviZ's chains."""
    out_dir = Path(out_dir)
    n_chain = int(posterior.n_walkers)
    draws = np.asarray(posterior.samples, dtype=float).reshape(-1, n_chain, posterior.samples.shape[1])
    draws = np.moveaxis(draws, 1, 0)  # (walker, draw, D)
    lp = np.asarray(posterior.log_prob, dtype=float).reshape(-1, n_chain).T  # (walker, draw)
    n_draw = draws.shape[1]
    names = list(log_post.names)
    units = sampled_units(log_post, record)
    time = np.asarray(record.time, dtype=float)
    data = np.asarray(record.displacement, dtype=float)
    kept, step = pointwise_draws(n_chain, n_draw, time.size)
    sub = draws[:, kept]  # (walker, draw', D)
    flat = sub.reshape(-1, sub.shape[2])
    y, valid = log_post.model.evaluate(log_post.full_theta(flat), log_post.time, log_post.current)
    sigma = np.exp(flat[:, -1]) if log_post.free_sigma else None
    pointwise = pointwise_log_likelihood(data[None, :] - y, log_post.noise, sigma, time=time)
    pointwise[~np.asarray(valid, dtype=bool)] = -np.inf
    rng = np.random.default_rng(seed)
    noise_sigma = sigma[:, None] if sigma is not None else log_post.noise.sigma
    white = rng.standard_normal(y.shape)
    predictive = y + noise_sigma * ar1_noise(white, log_post.noise.correlations_on(time))
    shape = (n_chain, sub.shape[1], time.size)
    pointwise_chunks = (n_chain, sub.shape[1], min(POINTWISE_CHUNK_SAMPLES, time.size))
    unit_out = record.output_unit
    try:
        version = {"arviz_version": metadata.version("arviz")}  # the schema's version, as from_dict writes it
    except metadata.PackageNotFoundError:  # pragma: no cover - arviz is a dependency
        version = {}
    stamp = {"created_at": datetime.now(timezone.utc).isoformat(), **version}
    run = {
        "source": "msma-gpi study",
        "input_unit": record.input_unit,
        "output_unit": unit_out,
        "discard": int(posterior.discard),
        "thin": int(posterior.thin),
    }
    draws_coords = _group(n_chain, n_draw, np.arange(n_draw))
    pointwise_coords = {**_group(n_chain, sub.shape[1], kept), "time": time}
    prior_names = getattr(log_post, "prior_names", {})
    whole = (n_chain, n_draw)
    dims3 = ("chain", "draw", "time")
    pointwise_attrs = {**stamp, "draw_step": int(step)}
    groups = {
        "posterior": (
            draws_coords,
            {
                n: (("chain", "draw"), draws[:, :, j], {"unit": units[j], "prior": str(prior_names.get(n, ""))}, whole)
                for j, n in enumerate(names)
            },
            stamp,
        ),
        "sample_stats": (draws_coords, {"lp": (("chain", "draw"), lp, {}, whole)}, stamp),
        "observed_data": (
            {"time": (time, {"unit": "s"})},
            {"displacement": (("time",), data, {"unit": unit_out}, None)},
            {**stamp, **run},
        ),
        "log_likelihood": (
            pointwise_coords,
            {
                "displacement": (
                    dims3,
                    quantised(pointwise, LOG_LIKELIHOOD_QUANTUM).reshape(shape),
                    {"rounded_to": LOG_LIKELIHOOD_QUANTUM},
                    pointwise_chunks,
                )
            },
            pointwise_attrs,
        ),
        "posterior_predictive": (
            pointwise_coords,
            {
                "displacement": (
                    dims3,
                    quantised(predictive, predictive_quantum(noise_sigma)).reshape(shape),
                    {"rounded_to": predictive_quantum(noise_sigma), "unit": unit_out},
                    pointwise_chunks,
                )
            },
            pointwise_attrs,
        ),
    }
    path = out_dir / FILE
    write_netcdf(path, groups)
    return path


def write_netcdf(path, groups) -> None:
    """:func:`_write_netcdf` through :func:`identify.data.fileio.write_via_temporary`: a fresh
    ``mkstemp`` name in the folder (a link planted there is never written through), removed
    on any error; the space the groups may take (their raw size and 1 MB of netCDF/HDF5
    bookkeeping; compression only shrinks them) is checked free first, so HDF5 never meets
    a full disk, which it does not survive."""
    need = 2**20
    for coords, variables, _attrs in groups.values():
        need += sum(np.asarray(v[0] if isinstance(v, tuple) else v).nbytes for v in coords.values())
        need += sum(np.asarray(v[1]).nbytes for v in variables.values())
    write_via_temporary(path, lambda tmp: _write_netcdf(tmp, groups), need_bytes=need)
