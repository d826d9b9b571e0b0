"""The posterior in the ecosystem's standard forms: ArviZ's diagnostics in summary.json and
the report, ``posterior.nc`` (InferenceData), names and units in ``chain.h5``."""

from __future__ import annotations

import contextlib
import json
import warnings

import emcee
import numpy as np
import pytest

from identify.bench import simulate
from identify.cli import main
from identify.data.records import write_record
from identify.fitting.posterior import BACKEND_GROUP, chain_diagnostics, import_arviz

az = import_arviz()  # two test workers may import arviz at the same moment (see import_arviz)

STEPS = ["--max-steps", "120", "--check-every", "60", "--n-starts", "2", "--progress", "off"]


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """A small finished study (Table 1 transducer at 5 Hz, 120 steps: not converged), no report."""
    base = tmp_path_factory.mktemp("eco")
    csv = base / "small.csv"
    write_record(csv, simulate(fs=5.0, seed=4).record)
    out = base / "run"
    code = main(["study", str(csv), "--out", str(out), "--seed", "5", "--no-report", *STEPS])
    assert code == 1  # 120 steps: the chain is NOT CONVERGED (exit code 1)
    return out


def _stored_draws(folder, summary):
    backend = emcee.backends.HDFBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    post = summary["posterior"]
    # (steps, walkers, D); stored in float32, computed on in float64 as the package's reader gives them
    return backend.get_chain()[post["discard"] :: post["thin"]].astype(np.float64)


@contextlib.contextmanager
def _more_walkers_than_draws():
    """ArviZ warns "More chains (36) than draws (31)" (its guess that an array came transposed) on
    a short chain of many walkers; here the arrays are (chain, draw) as it asks, so only that
    warning is silenced, at the calls, and any other still shows."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"More chains \(\d+\) than draws \(\d+\)", category=UserWarning)
        yield


def test_diagnostics_equal_arviz_on_the_stored_chain(study_dir):
    with _more_walkers_than_draws():
        _diagnostics_equal_arviz(study_dir)


def _diagnostics_equal_arviz(study_dir):
    summary = json.loads((study_dir / "summary.json").read_text())
    draws = _stored_draws(study_dir, summary)
    varying = [p for p in summary["parameters"] if p["vary"]]
    assert len(varying) == draws.shape[2]
    for j, p in enumerate(varying):
        x = draws[:, :, j].T  # ArviZ: (chain, draw), walkers as chains
        assert p["rhat"] == pytest.approx(float(az.rhat(x)), rel=1e-12)
        assert p["ess_bulk"] == pytest.approx(float(az.ess(x, method="bulk")), rel=1e-12)
        assert p["ess_tail"] == pytest.approx(float(az.ess(x, method="tail")), rel=1e-12)
        assert p["mcse_mean"] == pytest.approx(float(np.ravel(az.mcse(x, method="mean"))[0]), rel=1e-12)
    # az.mcse(method="sd") on an array fails with numpy 2 in arviz 0.23.4; az.summary's works
    data = az.convert_to_dataset({p["name"]: draws[:, :, j].T for j, p in enumerate(varying)})
    table = az.summary(data, kind="diagnostics", round_to="none")
    for p in varying:
        assert p["mcse_sd"] == pytest.approx(float(table.loc[p["name"], "mcse_sd"]), rel=1e-12)
        assert p["rhat"] == pytest.approx(float(table.loc[p["name"], "r_hat"]), rel=1e-12)
    pinned = [p for p in summary["parameters"] if not p["vary"]]
    assert pinned and all(p["rhat"] is None for p in pinned)
    post = summary["posterior"]
    assert post["rhat_max"] == pytest.approx(max(p["rhat"] for p in varying))
    assert post["rule"] == {"rhat_max": 1.05, "ess_bulk_min": 400.0}


def test_diagnostics_equal_az_summary_without_importing_arviz():
    """chain_diagnostics gives az.summary's figures (ArviZ's arithmetic, relative 1e-14) on a
    chain whose means dwarf its spread (the variance of the walker means then cancels to
    1e-10 when summed in another order), on ties and on a parameter that never moves; and it
    runs without importing ArviZ (2-6 s of the sampling phase)."""
    import subprocess
    import sys

    rng = np.random.default_rng(3)
    draws = rng.standard_normal((150, 36, 4)).cumsum(axis=0) * 1e-3 + np.array([100.0, -5.0, 0.0, 2.0])
    draws[:, :, 2] = np.round(draws[:, :, 2] * 1e3) / 1e3  # ties
    draws[:, :, 3] = 2.0  # never moves
    ours = chain_diagnostics(draws)
    data = az.convert_to_dataset({f"p{d}": np.ascontiguousarray(draws[:, :, d].T) for d in range(4)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the parameter that never moves: ArviZ divides 0 by 0
        table = az.summary(data, kind="diagnostics", round_to="none")
    columns = {"rhat": "r_hat", "ess_bulk": "ess_bulk", "ess_tail": "ess_tail", "mcse_mean": "mcse_mean"}
    columns["mcse_sd"] = "mcse_sd"
    for key, column in columns.items():
        theirs = np.array([float(table.loc[f"p{d}", column]) for d in range(4)])
        assert np.allclose(ours[key], theirs, rtol=1e-14, atol=0, equal_nan=True), key
    code = (
        "import sys, numpy as np; from identify.fitting.posterior import chain_diagnostics; "
        "chain_diagnostics(np.random.default_rng(0).standard_normal((40, 8, 2))); "
        "assert 'arviz' not in sys.modules and 'xarray' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_verdict_needs_rhat_and_bulk_ess(tmp_path):
    """tau alone passes on a short Gaussian chain; the verdict also needs bulk ESS >= 400."""
    from identify.fitting.convergence import diagnostics_verdict

    good = np.random.default_rng(0).standard_normal((400, 40, 2))
    diag = chain_diagnostics(good)
    ok, words = diagnostics_verdict(diag)
    assert ok and "R-hat max" in words
    few = good[:8, :4]  # 32 draws: bulk ESS far below 400
    ok, words = diagnostics_verdict(chain_diagnostics(few))
    assert not ok and "need >= 400" in words
    shifted = good.copy()
    shifted[:, :20] += 1.0  # half the walkers elsewhere: R-hat >> 1.05
    ok, _ = diagnostics_verdict(chain_diagnostics(shifted))
    assert not ok and np.max(chain_diagnostics(shifted)["rhat"]) > 1.05


def test_posterior_nc_opens_in_arviz(study_dir):
    """posterior.nc: az.summary's means are summary.json's; names, units; az.loo runs."""
    summary = json.loads((study_dir / "summary.json").read_text())
    idata = az.from_netcdf(study_dir / "posterior.nc")
    assert {"posterior", "sample_stats", "observed_data", "log_likelihood", "posterior_predictive"} <= set(
        idata.groups()
    )
    table = az.summary(idata, kind="stats", round_to="none")
    varying = [p for p in summary["parameters"] if p["vary"]]
    assert list(idata.posterior.data_vars) == [p["name"] for p in varying]
    for p in varying:
        assert float(table.loc[p["name"], "mean"]) == pytest.approx(p["mean"], rel=1e-12, abs=1e-300)
        assert idata.posterior[p["name"]].attrs["unit"] == p["unit"]
        assert idata.posterior[p["name"]].attrs["prior"] in ("uniform", "log_uniform")
    n = summary["posterior"]["n_samples"]
    assert idata.posterior.sizes["chain"] * idata.posterior.sizes["draw"] == n
    assert idata.observed_data["displacement"].size == idata.log_likelihood["displacement"].sizes["time"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loo = az.loo(idata, pointwise=True)
    assert np.isfinite(loo.elpd_loo)
    # the pointwise log-likelihood sums to the likelihood of each draw
    total = idata.log_likelihood["displacement"].sum("time")
    assert np.isfinite(total).all()


def test_posterior_nc_pointwise_groups_are_rounded_to_their_stated_precision(study_dir, tmp_path):
    """The pointwise groups are float32, gzip + shuffle, rounded to their stated quanta: the
    log-likelihood within half of :data:`LOG_LIKELIHOOD_QUANTUM` of the float64 values
    recomputed from the stored draws, so az.loo's elpd and p_loo within T times that and
    every Pareto k within 0.1 (a fraction of k's own Monte Carlo error, about (1 + k) /
    sqrt(M) >= 0.15 for the M <= 40 tail draws of this file); the predictive on its grid of
    a power of two <= sigma / 16; az.loo_pit pairs the two groups; writing the file imports
    neither ArviZ nor xarray."""
    import subprocess
    import sys

    import h5py

    from identify.fitting.inference import LOG_LIKELIHOOD_QUANTUM, pointwise_log_likelihood, predictive_quantum
    from identify.fitting.posterior import LogPosterior
    from identify.output.results import load_data, load_fit

    path = study_dir / "posterior.nc"
    with h5py.File(path, "r") as f:
        for group in ("log_likelihood", "posterior_predictive"):
            stored = f[group]["displacement"]
            assert stored.dtype == np.float32 and stored.compression == "gzip" and stored.shuffle
        assert f["posterior"]["rho"].dtype == np.float64 and f["posterior"]["rho"].compression == "gzip"
    idata = az.from_netcdf(path)
    fit = load_fit(study_dir)
    record = load_data(study_dir)
    log_post = LogPosterior(record, fit.model, fit.noise)
    ll = idata.log_likelihood["displacement"]
    assert ll.attrs["rounded_to"] == LOG_LIKELIHOOD_QUANTUM
    draws = np.stack([idata.posterior[n].sel(draw=ll["draw"]).values for n in log_post.names], axis=-1)
    flat = draws.reshape(-1, draws.shape[-1])
    y, _ = log_post.model.evaluate(log_post.full_theta(flat), log_post.time, log_post.current)
    exact = pointwise_log_likelihood(log_post.data[None, :] - y, log_post.noise).reshape(ll.shape)
    assert np.max(np.abs(ll.values - exact)) <= 0.5 * LOG_LIKELIHOOD_QUANTUM * (1 + 1e-6)
    assert np.array_equal(np.round(ll.values / LOG_LIKELIHOOD_QUANTUM), ll.values / LOG_LIKELIHOOD_QUANTUM)
    step = predictive_quantum(fit.noise.sigma)
    predictive = idata.posterior_predictive["displacement"]
    assert step <= fit.noise.sigma / 8 < 2 * step and predictive.attrs["rounded_to"] == step
    assert np.array_equal(np.round(predictive.values / step), predictive.values / step)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stored_loo = az.loo(idata, pointwise=True)
        idata.log_likelihood["displacement"] = (ll.dims, exact)
        exact_loo = az.loo(idata, pointwise=True)
        pit = az.loo_pit(idata, y="displacement")
    bound = 0.5 * LOG_LIKELIHOOD_QUANTUM * ll.sizes["time"]
    assert stored_loo.elpd_loo == pytest.approx(exact_loo.elpd_loo, abs=bound)
    assert stored_loo.p_loo == pytest.approx(exact_loo.p_loo, abs=2 * bound)
    assert np.max(np.abs(stored_loo.pareto_k.values - exact_loo.pareto_k.values)) < 0.1
    assert np.isfinite(pit).all() and pit.shape == (ll.sizes["time"],)
    copy = tmp_path / "run"
    copy.mkdir()
    for name in ("data.npz", "chain.h5", "fit.json", "summary.json", "manifest.json"):
        (copy / name).write_bytes((study_dir / name).read_bytes())
    code = (
        "import sys; from identify.output.results import load_data, load_fit; "
        "from identify.fitting.posterior import LogPosterior, posterior_from_backend; "
        "from identify.fitting.inference import write_inference_data; "
        f"d = {str(copy)!r}; fit = load_fit(d); record = load_data(d); "
        "lp = LogPosterior(record, fit.model, fit.noise); "
        "post = posterior_from_backend(d + '/chain.h5', lp.names, check_every=60); "
        "write_inference_data(d, record, lp, post, seed=5); "
        "assert 'arviz' not in sys.modules and 'xarray' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    again = az.from_netcdf(copy / "posterior.nc")
    assert np.array_equal(again.log_likelihood["displacement"].values, ll.values)


def test_posterior_nc_keeps_the_stated_draws_compressed_and_loads_in_arviz(study_dir):
    """posterior.nc's storage as stated (identify.fitting.inference): every variable gzip +
    shuffle at GZIP_LEVEL; the posterior, lp and the observed data float64, every draw of the
    chain after burn-in and thinning (quantiles equal to the chain's); the pointwise groups
    float32, K = MAX_POINTWISE // (walkers x samples) draws a walker, every draw_step-th, the
    same chain/draw coordinates in both, drawn from the posterior group's draws (their
    quantiles within Monte Carlo error of the whole posterior's); ArviZ opens the file and
    az.loo, az.loo_pit run on it."""
    import h5py

    from identify.fitting.inference import GZIP_LEVEL, MAX_POINTWISE, pointwise_draws

    summary = json.loads((study_dir / "summary.json").read_text())
    path = study_dir / "posterior.nc"
    with h5py.File(path, "r") as f:
        for group in ("posterior", "sample_stats", "observed_data", "log_likelihood", "posterior_predictive"):
            for name, stored in f[group].items():
                if stored.ndim and stored.size > 64 and name not in ("chain", "draw"):
                    assert stored.compression == "gzip" and stored.compression_opts == GZIP_LEVEL and stored.shuffle
                    pointwise = group in ("log_likelihood", "posterior_predictive") and name == "displacement"
                    assert stored.dtype == (np.float32 if pointwise else np.float64), (group, name)
    idata = az.from_netcdf(path)
    walkers, draws = idata.posterior.sizes["chain"], idata.posterior.sizes["draw"]
    samples = idata.observed_data.sizes["time"]
    kept, step = pointwise_draws(walkers, draws, samples)
    ll, pp = idata.log_likelihood, idata.posterior_predictive
    assert np.array_equal(ll["draw"].values, kept) and np.array_equal(pp["draw"].values, kept)
    assert np.array_equal(ll["chain"].values, pp["chain"].values) and ll.attrs["draw_step"] == step
    assert (
        kept.size == min(draws, MAX_POINTWISE // (walkers * samples)) and walkers * kept.size * samples <= MAX_POINTWISE
    )
    chain = _stored_draws(study_dir, summary)  # (steps, walkers, D) from chain.h5
    names = list(idata.posterior.data_vars)
    whole = np.stack([idata.posterior[n].values for n in names], axis=-1)  # (walker, draw, D)
    assert np.array_equal(whole, np.moveaxis(chain, 1, 0))
    q = np.array([0.025, 0.5, 0.975])
    assert np.array_equal(
        np.quantile(whole.reshape(-1, len(names)), q, axis=0), np.quantile(chain.reshape(-1, len(names)), q, axis=0)
    )
    # the pointwise draws: where their quantiles fall in the whole posterior, within 4 binomial errors
    sub = whole[:, kept].reshape(-1, len(names))
    ranks = np.mean(whole.reshape(-1, len(names))[:, None, :] <= np.quantile(sub, q, axis=0)[None], axis=0)
    assert np.all(np.abs(ranks - q[:, None]) <= 4 * np.sqrt(q * (1 - q) / sub.shape[0])[:, None] + 1 / sub.shape[0]), (
        ranks
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loo = az.loo(idata, pointwise=True)
        pit = az.loo_pit(idata, y="displacement")
    assert np.isfinite(loo.elpd_loo) and loo.pareto_k.size == samples and np.isfinite(pit).all()


def test_chain_h5_carries_names_and_units(study_dir):
    summary = json.loads((study_dir / "summary.json").read_text())
    backend = emcee.backends.HDFBackend(str(study_dir / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    with backend.open() as f:
        names = [n.decode() if isinstance(n, bytes) else n for n in f[BACKEND_GROUP].attrs["parameter_names"]]
        units = [u.decode() if isinstance(u, bytes) else u for u in f[BACKEND_GROUP].attrs["parameter_units"]]
    varying = [p for p in summary["parameters"] if p["vary"]]
    assert names == [p["name"] for p in varying] and units == [p["unit"] for p in varying]
    assert backend.get_chain().shape[2] == len(names)


def test_pointwise_log_likelihood_sums_to_the_likelihood():
    from identify.fitting.inference import pointwise_log_likelihood
    from identify.fitting.noise import NoiseModel, log_likelihood

    rng = np.random.default_rng(1)
    residual = rng.standard_normal((3, 50))
    for rho in (0.0, 0.6):
        noise = NoiseModel(sigma=0.7, rho=rho, kind="ar1" if rho else "white", source="user")
        assert np.allclose(pointwise_log_likelihood(residual, noise).sum(axis=1), log_likelihood(residual, noise))


def test_arviz_imports_although_another_process_won_its_stamp_file_race(monkeypatch):
    """ArviZ's import writes a daily stamp file through a temporary file of a fixed name; the
    loser of two processes importing it at once gets FileNotFoundError. import_arviz tries
    once more (the stamp is there by then) and returns the module."""
    import importlib.abc
    import sys

    class LosesTheRaceOnce(importlib.abc.MetaPathFinder):
        raised = 0

        def find_spec(self, name, path=None, target=None):
            if name == "arviz" and not self.raised:
                self.raised += 1
                raise FileNotFoundError(2, "No such file or directory", "daily_warning.tmp")
            return None

    finder = LosesTheRaceOnce()
    for name in [m for m in sys.modules if m == "arviz" or m.startswith("arviz.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(sys, "meta_path", [finder, *sys.meta_path])
    module = import_arviz()
    assert finder.raised == 1
    assert callable(module.rhat) and callable(module.ess)
