"""The ``fit`` and ``study`` commands end to end on small simulated records: the results
folder per docs/CONTRACTS.md, the manifest, resuming, refusing a different run,
reproducibility, bad input and other rigs' records."""

from __future__ import annotations

import hashlib
import json
import sys

import emcee
import numpy as np
import pytest

from identify.bench import simulate
from identify.cli import main
from identify.posterior import BACKEND_GROUP
from identify.records import write_record

FAST = ["--max-steps", "40", "--check-every", "20", "--n-starts", "2", "--progress", "off"]


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    """Table 1 transducer, paper input at 5 Hz (351 samples, 51 of them quiet), noise 0.5 um."""
    path = tmp_path_factory.mktemp("data") / "small.csv"
    sim = simulate(fs=5.0, seed=4)
    write_record(path, sim.record)
    return path


@pytest.fixture(autouse=True)
def report_calls(request, monkeypatch):
    """Record study's call of identify.report.write_report instead of drawing the report
    (its figures take most of a small study's time); the slow test draws it for real."""
    calls = []
    if request.node.name.startswith("test_report_is_written"):
        return calls
    try:
        import identify.report as report
    except ImportError:
        return calls

    def fake_write_report(result_dir):
        calls.append(result_dir)
        return result_dir / "report.html"

    monkeypatch.setattr(report, "write_report", fake_write_report)
    return calls


def chain_of(folder):
    backend = emcee.backends.HDFBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    return backend.get_chain()


def test_study_writes_the_contract_folder(small_csv, tmp_path, capsys, report_calls):
    out = tmp_path / "run"
    assert main(["study", str(small_csv), "--out", str(out), "--seed", "5", *FAST]) == 0
    printed = capsys.readouterr()
    if "identify.report" in sys.modules:
        assert [str(p) for p in report_calls] == [str(out)]  # the report is written from this folder
    for name in ("data.npz", "chain.h5", "fit.json", "summary.json", "manifest.json"):
        assert (out / name).is_file(), name

    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) >= {"model", "units", "noise", "fit", "identifiability", "posterior", "parameters"}
    assert summary["model"] == {"effects": [], "n_operators": 12, "reading": "swapped"}
    assert summary["units"] == {"input": "A", "output": "um"}
    assert set(summary["noise"]) >= {"sigma", "rho", "kind", "source", "n_quiet"} and summary["noise"]["n_quiet"] == 51
    assert set(summary["fit"]) >= {"rms", "max_error_pct", "reduced_chi2", "seconds"}
    ident = summary["identifiability"]
    assert ident["normalisation"] == {"alpha": -0.1993}
    assert len(ident["exact"]) == 1 and set(ident["exact"][0]["combination"]) == {"rho", "alpha", "tau", "a0", "a3", "b0", "b3"}
    post = summary["posterior"]
    assert set(post) >= {"converged", "n_walkers", "n_steps", "discard", "thin", "acceptance_fraction", "tau_max", "seconds"}
    # 40 steps cannot converge: said plainly in the summary and on screen
    assert post["converged"] is False and post["n_steps"] == 40 and post["n_walkers"] == 36
    assert "NOT CONVERGED" in post["message"] and "NOT CONVERGED" in printed.out
    params = summary["parameters"]
    assert [p["name"] for p in params][:3] == ["alpha", "rho", "tau"] and len(params) == 19
    for p in params:
        assert set(p) == {"name", "unit", "table1", "lsq", "lsq_stderr", "median", "lo95", "hi95", "tau", "ess", "vary"}
        assert p["lo95"] <= p["median"] <= p["hi95"]
    alpha = params[0]
    assert alpha["vary"] is False and alpha["lsq_stderr"] is None and alpha["median"] == -0.1993

    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 5
    assert manifest["data"]["sha256"] == hashlib.sha256(small_csv.read_bytes()).hexdigest()
    settings = manifest["settings"]
    for key in ("effects", "n_operators", "reading", "noise_sigma", "walkers", "max_steps", "check_every", "moves",
                "n_starts", "input_column", "output_unit", "data"):  # fmt: skip
        assert key in settings, key
    assert settings["max_steps"] == 40
    for package in ("numpy", "scipy", "emcee", "numba", "h5py", "python"):
        assert manifest["versions"][package], package
    assert set(manifest["git"]) == {"commit", "dirty"}
    assert manifest["started"] and manifest["finished"]
    assert [run["status"] for run in manifest["runs"]] == ["not converged"]

    with np.load(out / "data.npz") as data:
        assert str(data["input_unit"]) == "A" and str(data["output_unit"]) == "um"
        assert data["time"].shape == (351,)


def test_rerun_resumes_and_a_different_run_is_refused(small_csv, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["study", str(small_csv), "--out", str(out), *FAST]
    assert main(args) == 0
    fit_bytes = (out / "fit.json").read_bytes()
    first = chain_of(out)
    # same command with a higher cap: the chain continues, the fit is reused
    longer = [a if a != "40" else "60" for a in args]
    assert main(longer) == 0
    assert "resuming" in capsys.readouterr().err
    second = chain_of(out)
    assert second.shape[0] == 60 and np.array_equal(second[:40], first)
    assert (out / "fit.json").read_bytes() == fit_bytes
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["runs"]) == 2
    # another seed in the same folder is refused, naming the difference and --force
    assert main([*longer, "--seed", "9"]) == 2
    err = capsys.readouterr().err
    assert "different" in err and "seed 0 -> 9" in err and "--force" in err
    assert main([*longer, "--seed", "9", "--force"]) == 0
    assert json.loads((out / "manifest.json").read_text())["seed"] == 9


def test_same_seed_same_chain_bit_for_bit(small_csv, tmp_path):
    for name in ("a", "b"):
        assert main(["study", str(small_csv), "--out", str(tmp_path / name), "--seed", "3", *FAST]) == 0
    assert np.array_equal(chain_of(tmp_path / "a"), chain_of(tmp_path / "b"))
    fit_a = json.loads((tmp_path / "a" / "fit.json").read_text())
    fit_b = json.loads((tmp_path / "b" / "fit.json").read_text())
    assert fit_a["theta"] == fit_b["theta"] and fit_a["covariance"] == fit_b["covariance"]


@pytest.mark.slow
def test_report_is_written_when_the_report_module_exists(small_csv, tmp_path):
    pytest.importorskip("identify.report")
    out = tmp_path / "run"
    assert main(["study", str(small_csv), "--out", str(out), *FAST]) == 0
    assert (out / "report.html").is_file()


def test_no_quiet_segment_names_the_fallbacks_and_free_sigma_works(tmp_path, capsys):
    sim = simulate(fs=5.0, seed=6)
    rec = sim.record
    keep = rec.time >= 12.0  # drop the unenergised start
    path = tmp_path / "busy.csv"
    write_record(path, (rec.time[keep] - 12.0, rec.current[keep], rec.displacement[keep]))
    assert main(["fit", str(path)]) == 2
    err = capsys.readouterr().err
    assert "--noise-sigma VALUE" in err and "--noise-sigma free" in err
    out = tmp_path / "free"
    assert main(["study", str(path), "--out", str(out), "--noise-sigma", "free", *FAST]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["noise"]["source"] == "free"
    assert summary["noise"]["sigma"] == pytest.approx(0.5, rel=0.15)  # 291 samples
    assert "posterior" in summary["noise"] and summary["noise"]["posterior"]["median"] > 0


def test_fit_prints_a_table_and_writes_json(small_csv, tmp_path, capsys):
    out_json = tmp_path / "fit.json"
    assert main(["fit", str(small_csv), "--n-starts", "2", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "parameter" in text and "stderr" in text and "pinned" in text
    assert "x noise sigma" in text and "% of the displacement range" in text
    data = json.loads(out_json.read_text())
    assert len(data["theta"]) == 19 and data["vary"][0] is False


def test_unknown_effect_lists_the_known_ones(small_csv, capsys):
    from model import EFFECTS

    assert main(["fit", str(small_csv), "--effects", "thermal,warp"]) == 2
    err = capsys.readouterr().err
    assert "'warp'" in err and all(name in err for name in EFFECTS)


def test_piezo_record_with_other_columns_and_units(tmp_path, capsys):
    """A record in V and um with other column names: loaded through the column options,
    fitted from the data-driven start (Table 1 rescaled to a 0-100 V drive)."""
    sim = simulate(fs=5.0, seed=8)
    rec = sim.record
    path = tmp_path / "piezo.csv"
    lines = ["t,voltage,position"] + [f"{float(t)!r},{float(20.0 * i)!r},{float(y)!r}" for t, i, y in zip(rec.time, rec.current, rec.displacement)]
    path.write_text("\n".join(lines) + "\n")
    argv = ["fit", str(path), "--time-column", "t", "--input-column", "voltage", "--output-column", "position",
            "--input-unit", "V", "--n-starts", "3"]  # fmt: skip
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "1/V" in text
    rms_ratio = float(text.split("residual RMS")[1].split("=")[2].split("x")[0])
    assert rms_ratio == pytest.approx(1.0, abs=0.15)
