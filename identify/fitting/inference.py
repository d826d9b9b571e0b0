"""The posterior in the ecosystem's standard forms.

* :func:`write_inference_data` writes ``DIR/posterior.nc``, an ArviZ ``InferenceData``
  (netCDF, read with ``arviz.from_netcdf``):

  ``posterior``
      every draw after burn-in and thinning, dims ``(chain, draw)`` = (walker, draw),
      one variable per sampled parameter with ``unit`` and ``prior`` attributes (the
      draws ``summary.json`` is computed from, so ``az.summary`` gives its means).
  ``sample_stats``
      ``lp`` (log posterior) and ``log_likelihood`` (its sum over the record).
  ``observed_data``
      ``displacement`` with the ``time`` coordinate, in the record's units.
  ``log_likelihood``
      ``displacement``: the pointwise log-likelihood, one value per draw and sample
      (the AR(1) noise model's conditional densities, summing to the likelihood), so
      ``az.loo`` and ``az.compare`` compare models, e.g. with and without an effect.
  ``posterior_predictive``
      ``displacement``: model output plus a draw of the fitted noise.

  The pointwise groups hold every ``k``-th draw of every walker, ``k`` chosen so that
  draws x samples stays at most :data:`MAX_POINTWISE` (attribute ``draw_step``); the
  ``posterior`` group holds all draws.
* :func:`write_chain_attributes` puts the parameter names and units on the emcee group of
  ``chain.h5`` (attributes ``parameter_names``, ``parameter_units``), where
  ``emcee.backends.HDFBackend(path, name="mcmc").open()`` finds them (fixed-length UTF-8
  bytes: ``[n.decode() for n in attrs["parameter_names"]]``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

__all__ = [
    "MAX_POINTWISE",
    "FILE",
    "write_inference_data",
    "write_netcdf",
    "write_chain_attributes",
    "sampled_units",
    "pointwise_log_likelihood",
]

#: Largest number of draws x record samples in the pointwise groups (float64: 32 MB each).
MAX_POINTWISE = 4_000_000
#: File name in the results folder.
FILE = "posterior.nc"


def sampled_units(log_post, record) -> list[str]:
    """Units of the sampled coordinates (``noise_log_sigma``: log of the output unit)."""
    from .lsq import parameter_units

    units = parameter_units(log_post.model, record)
    by_name = dict(zip(log_post.model.names, units))
    return [by_name.get(n, f"log({record.output_unit})") for n in log_post.names]


def write_chain_attributes(path, names, units) -> None:
    """Parameter names and units as attributes of ``chain.h5``'s emcee group."""
    from ..data.fileio import require_space
    from ..data.hdf5 import open_hdf5
    from .posterior import BACKEND_GROUP, CHAIN_METADATA_BYTES

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
    from .noise import whiten

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


def write_inference_data(out_dir, record, log_post, posterior, *, seed=0) -> Path:
    """Write ``DIR/posterior.nc`` (module docstring) and return its path."""
    from .posterior import BACKEND_GROUP, ChainBackend, import_arviz

    az = import_arviz()
    out_dir = Path(out_dir)
    backend = ChainBackend(str(out_dir / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    chain = backend.get_chain()[posterior.discard :: posterior.thin]  # (draw, walker, D)
    lp = backend.get_log_prob()[posterior.discard :: posterior.thin]
    draws = np.moveaxis(chain, 1, 0)  # (walker, draw, D)
    n_chain, n_draw, _ = draws.shape
    names = list(log_post.names)
    units = sampled_units(log_post, record)
    time = np.asarray(record.time, dtype=float)
    data = np.asarray(record.displacement, dtype=float)
    step = max(1, math.ceil(n_chain * n_draw * time.size / MAX_POINTWISE))
    sub = draws[:, ::step]  # (walker, draw', D)
    flat = sub.reshape(-1, sub.shape[2])
    y, valid = log_post.model.evaluate(log_post.full_theta(flat), log_post.time, log_post.current)
    sigma = np.exp(flat[:, -1]) if log_post.free_sigma else None
    pointwise = pointwise_log_likelihood(data[None, :] - y, log_post.noise, sigma, time=time)
    pointwise[~np.asarray(valid, dtype=bool)] = -np.inf
    rng = np.random.default_rng(seed)
    noise_sigma = sigma[:, None] if sigma is not None else log_post.noise.sigma
    white = rng.standard_normal(y.shape)
    correlations = log_post.noise.step_correlations(time)
    if correlations is None:
        correlations = np.full(max(time.size - 1, 0), log_post.noise.rho)
    eps = np.empty_like(white)
    eps[:, 0] = white[:, 0]
    for t in range(1, time.size):  # AR(1) with unit marginal variance, each step's own correlation
        rho = correlations[t - 1]
        eps[:, t] = rho * eps[:, t - 1] + math.sqrt(1.0 - rho * rho) * white[:, t]
    predictive = y + noise_sigma * eps
    shape = (n_chain, sub.shape[1], time.size)
    draw_index = np.arange(0, n_draw, step)
    unit_out = record.output_unit
    import warnings

    warnings.filterwarnings("ignore", message="More chains", category=UserWarning)  # a short chain: fine here
    idata = az.from_dict(
        posterior={n: draws[:, :, j] for j, n in enumerate(names)},
        sample_stats={"lp": np.moveaxis(lp, 1, 0)},
        observed_data={"displacement": data},
        coords={"time": time},
        dims={"displacement": ["time"]},
        attrs={
            "source": "msma-gpi study",
            "input_unit": record.input_unit,
            "output_unit": unit_out,
            "discard": int(posterior.discard),
            "thin": int(posterior.thin),
        },
    )
    pointwise_groups = az.from_dict(
        log_likelihood={"displacement": pointwise.reshape(shape)},
        posterior_predictive={"displacement": predictive.reshape(shape)},
        coords={"time": time, "draw": draw_index},
        dims={"displacement": ["time"]},
    )
    idata.extend(pointwise_groups)
    for j, n in enumerate(names):
        idata.posterior[n].attrs.update(unit=units[j], prior=str(getattr(log_post, "prior_names", {}).get(n, "")))
    for group in (idata.log_likelihood, idata.posterior_predictive):
        group.attrs["draw_step"] = int(step)
    idata.observed_data["displacement"].attrs["unit"] = unit_out
    idata.observed_data["time"].attrs["unit"] = "s"
    path = out_dir / FILE
    write_netcdf(path, idata)
    return path


def write_netcdf(path, idata) -> None:
    """``idata.to_netcdf`` through :func:`identify.data.fileio.write_via_temporary`: a fresh
    ``mkstemp`` name in the folder (a link planted there is never written through), removed
    on any error; the space the groups may take (their raw size and 1 MB of netCDF/HDF5
    bookkeeping; compression only shrinks them) is checked free first, so HDF5 never meets
    a full disk, which it does not survive."""
    from ..data.fileio import write_via_temporary

    need = sum(int(getattr(idata, group).nbytes) for group in idata.groups()) + 2**20
    write_via_temporary(path, lambda tmp: idata.to_netcdf(tmp), need_bytes=need)
