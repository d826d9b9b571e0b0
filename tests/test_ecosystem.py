"""The posterior in the ecosystem's standard forms: ArviZ's diagnostics in summary.json and
the report, ``posterior.nc`` (InferenceData), names and units in ``chain.h5``."""

from __future__ import annotations

import json
import warnings

import emcee
import numpy as np
import pytest

from identify.bench import simulate
from identify.cli import main
from identify.posterior import BACKEND_GROUP, chain_diagnostics
from identify.records import write_record

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    import arviz as az

STEPS = ["--max-steps", "120", "--check-every", "60", "--n-starts", "2", "--progress", "off"]


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """A small finished study (Table 1 transducer at 5 Hz, 120 steps: not converged), no report."""
    base = tmp_path_factory.mktemp("eco")
    csv = base / "small.csv"
    write_record(csv, simulate(fs=5.0, seed=4).record)
    out = base / "run"
    code = main(["study", str(csv), "--out", str(out), "--seed", "5", "--no-report", *STEPS])
    assert code in (0, 1)
    return out


def _stored_draws(folder, summary):
    backend = emcee.backends.HDFBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    post = summary["posterior"]
    return backend.get_chain()[post["discard"] :: post["thin"]]  # (steps, walkers, D)


def test_diagnostics_equal_arviz_on_the_stored_chain(study_dir):
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
    assert post["rule"] == {"rhat_max": 1.01, "ess_bulk_min": 400.0}


def test_verdict_needs_rhat_and_bulk_ess(tmp_path):
    """tau alone passes on a short Gaussian chain; the verdict also needs bulk ESS >= 400."""
    from identify import posterior as P

    good = np.random.default_rng(0).standard_normal((400, 40, 2))
    diag = chain_diagnostics(good)
    ok, words = P._diagnostics_verdict(diag)
    assert ok and "R-hat max" in words
    few = good[:8, :4]  # 32 draws: bulk ESS far below 400
    ok, words = P._diagnostics_verdict(chain_diagnostics(few))
    assert not ok and "need >= 400" in words
    shifted = good.copy()
    shifted[:, :20] += 1.0  # half the walkers elsewhere: R-hat >> 1.01
    ok, _ = P._diagnostics_verdict(chain_diagnostics(shifted))
    assert not ok and np.max(chain_diagnostics(shifted)["rhat"]) > 1.01
