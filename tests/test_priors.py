"""Priors from a TOML file (issue 18): checks with clear errors, the densities, and a tight
prior that moves a bench record's posterior, recorded in summary.json and the report."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.integrate import quad

from identify.bench import simulate
from identify.cli import main
from identify.cli.common import model_from_args
from identify.data.records import write_record
from identify.fitting.priors import Prior, PriorsError, apply_priors

STUDY = [
    "--max-steps",
    "400",
    "--check-every",
    "200",
    "--n-starts",
    "2",
    "--seed",
    "5",
    "--progress",
    "off",
    "--no-report",
]


class _Args:
    effects, n_operators, reading = "thermal", 12, "swapped"


@pytest.fixture(scope="module")
def model():
    return model_from_args(_Args())


@pytest.mark.parametrize(
    "text, message",
    [
        (
            "[warp]\ndistribution = 'uniform'\nlower = 0\nupper = 1\n",
            r"'warp' is not a parameter of .*; its parameters: alpha, rho",
        ),
        (
            "[rho]\ndistribution = 'cauchy'\n",
            r"parameter 'rho': unknown distribution 'cauchy'; known: uniform, log_uniform, normal",
        ),
        (
            "[rho]\ndistribution = 'uniform'\nlower = 10\nupper = 20\n",
            r"parameter 'rho': bounds \[10, 20\] exclude its starting value 5\.6438",
        ),
        ("[rho]\ndistribution = 'normal'\nmu = 5\nsigma = 0\n", r"parameter 'rho': sigma must be > 0"),
        ("[rho]\ndistribution = 'normal'\nmu = 5\n", r"parameter 'rho': a normal prior needs sigma"),
        (
            "[rho]\ndistribution = 'uniform'\nlower = 3\nupper = 1\n",
            r"parameter 'rho': lower 3\.0 must be below upper 1\.0",
        ),
        (
            "[rho]\ndistribution = 'log_uniform'\nlower = 0\nupper = 10\n",
            r"parameter 'rho': a log_uniform prior needs lower > 0",
        ),
        (
            "[rho]\ndistribution = 'uniform'\nlower = 1\nupper = 10\nwidth = 3\n",
            r"parameter 'rho': unknown key\(s\) width",
        ),
        ("[alpha]\ndistribution = 'uniform'\nlower = -1\nupper = 1\n", r"parameter 'alpha' is pinned"),
        ("[rho\ndistribution = 'uniform'\n", r"not valid TOML: .*line 1"),
        (
            "[rho]\ndistribution = 'uniform'\nlower = 'one'\nupper = 10\n",
            r"parameter 'rho': lower must be a finite number, got 'one'",
        ),
    ],
    ids=[
        "unknown-name",
        "distribution",
        "excludes-start",
        "sigma",
        "missing",
        "order",
        "log-lower",
        "key",
        "pinned",
        "toml",
        "text",
    ],
)
def test_a_bad_priors_file_is_one_clear_error(tmp_path, model, text, message):
    path = tmp_path / "priors.toml"
    path.write_text(text)
    with pytest.raises(PriorsError, match=r"priors\.toml: " + message):
        apply_priors(model, path)


def test_a_good_file_sets_bounds_and_distributions(tmp_path, model):
    path = tmp_path / "priors.toml"
    path.write_text(
        "[thermal_tau]\ndistribution = 'truncated_normal'\nmu = 100.0\nsigma = 20.0\nlower = 20.0\nupper = 400.0\n"
        "[rho]\ndistribution = 'log_uniform'\nlower = 0.5\nupper = 50.0\n[c0]\ndistribution = 'normal'\nmu = "
        "1.5\nsigma = 0.2\n"
    )
    changed, priors = apply_priors(model, path)
    p = changed.parameters
    assert (p["thermal_tau"].lower, p["thermal_tau"].upper) == (20.0, 400.0) and (p["rho"].lower, p["rho"].upper) == (
        0.5,
        50.0,
    )
    assert (p["c0"].lower, p["c0"].upper) == (
        model.parameters["c0"].lower,
        model.parameters["c0"].upper,
    )  # normal: model's bounds
    assert model.parameters["rho"].lower == 1e-3  # the model passed in is unchanged
    assert priors["c0"] == Prior("normal", 1.5, 0.2, source=str(path))


@pytest.mark.parametrize(
    "prior, lower, upper",
    [
        (Prior("truncated_normal", 100.0, 20.0), 50.0, 400.0),
        (Prior("normal", 1.5, 0.2), -1e3, 1e3),
        (Prior("truncated_normal", 0.0, 1.0), 2.0, 3.0),
        (Prior("log_uniform"), 0.5, 50.0),
        (Prior("uniform"), -2.0, 5.0),
    ],
)
def test_densities_integrate_to_one_on_their_bounds(prior, lower, upper):
    def density(x):
        return math.exp(float(prior(np.array([x]), lower, upper)[0]))

    edges = {lower, upper}  # a narrow normal in wide bounds: integrate its +-10 sigma core on its own
    if prior.mu is not None:
        edges |= {min(upper, max(lower, prior.mu + k * prior.sigma)) for k in (-10, 10)}
    edges = sorted(edges)
    total = sum(quad(density, a, b, limit=200)[0] for a, b in zip(edges, edges[1:]))
    assert total == pytest.approx(1.0, rel=1e-6)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """A bench record (Table 1 transducer, 5 Hz, noise 0.5 um) and its study without a priors file."""
    base = tmp_path_factory.mktemp("priors")
    csv = base / "bench.csv"
    write_record(csv, simulate(fs=5.0, seed=4).record)
    assert main(["study", str(csv), "--out", str(base / "free"), *STUDY]) == 1  # 400 steps: NOT CONVERGED
    return csv, base


def _c0(folder):
    summary = json.loads((folder / "summary.json").read_text())
    return next(p for p in summary["parameters"] if p["name"] == "c0"), summary


def test_a_tight_normal_prior_pulls_the_posterior_and_is_reported(bench, tmp_path):
    csv, base = bench
    free, free_summary = _c0(base / "free")
    mu, sigma = free["lsq"] + free["lsq_stderr"], 0.1 * free["lsq_stderr"]  # one std. error off, 10x tighter
    priors = tmp_path / "c0.toml"
    priors.write_text(f"[c0]\ndistribution = 'normal'\nmu = {mu!r}\nsigma = {sigma!r}\n")
    out = tmp_path / "tight"
    assert main(["study", str(csv), "--out", str(out), "--priors", str(priors), *STUDY]) == 1
    tight, summary = _c0(out)
    assert tight["lsq"] == free["lsq"]  # the least squares is not changed by the prior
    assert abs(tight["median"] - mu) < 0.5 * sigma + 0.1 * abs(free["median"] - mu)
    assert abs(tight["median"] - mu) < abs(free["median"] - mu)
    assert (tight["hi95"] - tight["lo95"]) < 0.3 * (free["hi95"] - free["lo95"])
    # the priors used are in summary.json: the file's for c0, the defaults for the others
    rows = {row["name"]: row for row in summary["priors"]}
    assert rows["c0"] == {
        "name": "c0",
        "distribution": "normal",
        "mu": mu,
        "sigma": sigma,
        "source": str(priors),
        "lower": -1e3,
        "upper": 1e3,
    }
    assert rows["rho"]["distribution"] == "log_uniform" and rows["rho"]["source"] == "default"
    assert {row["source"] for row in free_summary["priors"]} == {"default"} and "alpha" not in rows
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["priors"] == str(priors) and len(manifest["settings"]["priors_sha256"]) == 64
    # and in the report
    from identify.output.report import write_report

    page = write_report(out).read_text()
    table = page.split('<table id="priors">')[1].split("</table>")[0]
    assert '<tr class="given-prior"><td>c0</td>' in table and "normal" in table and str(priors) in table


def test_study_with_a_bad_priors_file_exits_2_before_writing(bench, tmp_path, capsys):
    csv, _base = bench
    priors = tmp_path / "bad.toml"
    priors.write_text("[c0]\ndistribution = 'normal'\nmu = 1.0\nsigma = 0.1\nlower = 5.0\nupper = 9.0\n")
    out = tmp_path / "run"
    assert main(["study", str(csv), "--out", str(out), "--priors", str(priors), *STUDY]) == 2
    err = capsys.readouterr().err
    assert (
        f"error: {priors}: parameter 'c0': bounds [5, 9] exclude its starting value" in err and "Traceback" not in err
    )
    assert not (out / "manifest.json").exists()
    with pytest.raises(SystemExit) as exited:  # an option error: argparse's exit, code 2
        main(["study", str(csv), "--out", str(out), "--priors", str(tmp_path / "none.toml"), *STUDY])
    assert exited.value.code == 2 and "argument --priors:" in capsys.readouterr().err


def test_default_bounds_follow_the_record_unit_prefixes_and_a_priors_file_wins(tmp_path, model):
    """docs/method.md, 'Units and default bounds': a record in V (within a factor 30 of the
    paper's 5 A) keeps the input-side bounds; one in mm instead of um gets the output-side
    bounds widened 1000-fold downwards; a priors file's bounds are kept as given."""
    from identify.data.records import Record
    from identify.fitting.noise import estimate_noise
    from identify.fitting.posterior import LogPosterior

    rec = simulate(fs=5.0, seed=4).record
    amps = Record(rec.time, rec.current, rec.displacement, source="a", sha256="")
    volts = Record(
        rec.time, 20.0 * rec.current, 1e-3 * rec.displacement, source="v", sha256="", input_unit="V", output_unit="mm"
    )
    noise = estimate_noise(amps)
    a, v = LogPosterior(amps, model, noise), LogPosterior(volts, model, noise)
    for name in ("a1", "b1", "c1", "d1", "a0", "tau"):  # input side: V within a factor 30 of A
        j = a.names.index(name)
        assert (a.lower[j], a.upper[j]) == (v.lower[j], v.upper[j])
    j = a.names.index("c0")  # output side: mm is 1/1000 of um
    assert v.lower[j] == a.lower[j] and v.upper[j] == a.upper[j]  # +-1e3 already holds the mm-scaled +-1
    j = a.names.index("rho")
    assert v.lower[j] == pytest.approx(a.lower[j] * 1e-3) and v.upper[j] == a.upper[j]  # widened downwards
    path = tmp_path / "mm.toml"
    path.write_text("[c0]\ndistribution = 'uniform'\nlower = -1.0\nupper = 5.0\n")  # mm-sized bounds
    changed, priors = apply_priors(model, path)
    post = LogPosterior(volts, changed, noise, priors=priors)
    j = post.names.index("c0")
    assert (post.lower[j], post.upper[j]) == (-1.0, 5.0) and post.prior_names["c0"] == "uniform"
