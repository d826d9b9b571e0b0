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
from identify.data.records import write_record
from identify.fitting.posterior import BACKEND_GROUP
from identify.workflows import study_run

FAST = ["--max-steps", "40", "--check-every", "20", "--n-starts", "2", "--progress", "off"]
#: Exit code of a FAST study: its 40-step chain stops at the cap, NOT CONVERGED (a finding, docs/reproducibility.md).
NOT_CONVERGED = 1


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    """Table 1 transducer, paper input at 5 Hz (351 samples, 51 of them quiet), noise 0.5 um."""
    path = tmp_path_factory.mktemp("data") / "small.csv"
    sim = simulate(fs=5.0, seed=4)
    write_record(path, sim.record)
    return path


@pytest.fixture(autouse=True)
def report_calls(request, monkeypatch):
    """Record study's call of write_report instead of drawing the report (its figures take most
    of a small study's time); the slow test draws it for real. Patched where the study calls it
    (:mod:`identify.workflows.study_run` imports it at its top)."""
    calls = []
    if request.node.name.startswith("test_report_is_written"):
        return calls

    def fake_write_report(result_dir):
        calls.append(result_dir)
        return result_dir / "report.html"

    monkeypatch.setattr(study_run, "write_report", fake_write_report)
    return calls


def chain_of(folder):
    backend = emcee.backends.HDFBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    return backend.get_chain()


def test_study_writes_the_contract_folder(small_csv, tmp_path, capsys, report_calls):
    out = tmp_path / "run"
    assert main(["study", str(small_csv), "--out", str(out), "--seed", "5", *FAST]) == NOT_CONVERGED
    printed = capsys.readouterr()
    assert "exit code 1: the chain did NOT CONVERGE" in printed.err
    if "identify.output.report" in sys.modules:
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
    assert len(ident["exact"]) == 1 and set(ident["exact"][0]["combination"]) == {
        "rho",
        "alpha",
        "tau",
        "a0",
        "a3",
        "b0",
        "b3",
    }
    post = summary["posterior"]
    assert set(post) >= {
        "converged",
        "n_walkers",
        "n_steps",
        "discard",
        "thin",
        "acceptance_fraction",
        "tau_max",
        "seconds",
    }
    # 40 steps cannot converge: said plainly in the summary and on screen
    assert post["converged"] is False and post["n_steps"] == 40 and post["n_walkers"] == 36
    assert "NOT CONVERGED" in post["message"] and "NOT CONVERGED" in printed.out
    params = summary["parameters"]
    assert [p["name"] for p in params][:3] == ["alpha", "rho", "tau"] and len(params) == 19
    for p in params:
        assert set(p) == {
            "name",
            "unit",
            "table1",
            "lsq",
            "lsq_stderr",
            "median",
            "lo95",
            "hi95",
            "tau",
            "ess",
            "vary",
            "rhat",
            "ess_bulk",
            "ess_tail",
            "mcse_mean",
            "mcse_sd",
            "mean",
            "sd",
        }
        assert p["lo95"] <= p["median"] <= p["hi95"]
    alpha = params[0]
    assert alpha["vary"] is False and alpha["lsq_stderr"] is None and alpha["median"] == -0.1993

    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 5
    assert manifest["data"]["sha256"] == hashlib.sha256(small_csv.read_bytes()).hexdigest()
    settings = manifest["settings"]
    for key in (
        "effects",
        "n_operators",
        "reading",
        "noise_sigma",
        "walkers",
        "max_steps",
        "check_every",
        "moves",
        "n_starts",
        "input_column",
        "output_unit",
        "data",
    ):
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
    assert main(args) == NOT_CONVERGED
    fit_bytes = (out / "fit.json").read_bytes()
    first = chain_of(out)
    # same command with a higher cap: the chain continues, the fit is reused
    longer = [a if a != "40" else "60" for a in args]
    assert main(longer) == NOT_CONVERGED
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
    assert main([*longer, "--seed", "9", "--force"]) == NOT_CONVERGED
    assert json.loads((out / "manifest.json").read_text())["seed"] == 9


def test_same_seed_same_chain_bit_for_bit(small_csv, tmp_path):
    for name in ("a", "b"):
        assert main(["study", str(small_csv), "--out", str(tmp_path / name), "--seed", "3", *FAST]) == NOT_CONVERGED
    assert np.array_equal(chain_of(tmp_path / "a"), chain_of(tmp_path / "b"))
    fit_a = json.loads((tmp_path / "a" / "fit.json").read_text())
    fit_b = json.loads((tmp_path / "b" / "fit.json").read_text())
    assert fit_a["theta"] == fit_b["theta"] and fit_a["covariance"] == fit_b["covariance"]


@pytest.mark.slow
def test_report_is_written_when_the_report_module_exists(small_csv, tmp_path):
    pytest.importorskip("identify.output.report")
    out = tmp_path / "run"
    assert main(["study", str(small_csv), "--out", str(out), *FAST]) == NOT_CONVERGED
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
    assert main(["study", str(path), "--out", str(out), "--noise-sigma", "free", *FAST]) == NOT_CONVERGED
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
    lines = ["t,voltage,position"] + [
        f"{float(t)!r},{float(20.0 * i)!r},{float(y)!r}" for t, i, y in zip(rec.time, rec.current, rec.displacement)
    ]
    path.write_text("\n".join(lines) + "\n")
    argv = [
        "fit",
        str(path),
        "--time-column",
        "t",
        "--input-column",
        "voltage",
        "--output-column",
        "position",
        "--input-unit",
        "V",
        "--n-starts",
        "3",
    ]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "1/V" in text
    # units by dimensional analysis: no parameter is labelled in A for a V-driven record
    units = {
        line.split()[0]: line.split()[3]
        for line in text.splitlines()
        if line.split() and line.split()[0] in ("alpha", "rho", "tau", "a0", "a1", "a3", "c0")
    }
    assert units == {"alpha": "V", "rho": "um/V", "tau": "1/V", "a0": "V", "a1": "1/V", "a3": "V", "c0": "um"}
    rms_ratio = float(text.split("residual RMS")[1].split("=")[2].split("x")[0])
    assert rms_ratio == pytest.approx(1.0, abs=0.15)


# -- fit --out, notes, failures, --no-report ---------------------------------------------------


def test_fit_out_writes_a_reproducible_folder_with_notes_and_threads(small_csv, tmp_path, capsys):
    """``fit --out DIR``: data.npz, fit.json and a manifest as study writes them (task, seed,
    data hash, the record's notes, thread counts); a rerun with other settings is refused."""
    from identify.workflows.reproduce import rerun_arguments

    no_time = tmp_path / "no_time.csv"  # the same record without its time column: a note
    lines = small_csv.read_text().splitlines()
    no_time.write_text("\n".join(",".join(line.split(",")[1:]) for line in lines) + "\n")
    out = tmp_path / "fit_run"
    argv = ["fit", str(no_time), "--time-column", "none", "--n-starts", "2", "--seed", "4", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "note: the file has no time column" in err
    assert {p.name for p in out.iterdir()} == {"data.npz", "fit.json", "manifest.json"}
    fit = json.loads((out / "fit.json").read_text())
    assert len(fit["theta"]) == 19 and fit["rms"] > 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["task"] == "fit" and manifest["seed"] == 4
    assert manifest["data"]["sha256"] == hashlib.sha256(no_time.read_bytes()).hexdigest()
    assert any("no time column" in note for note in manifest["data"]["notes"])
    threads = manifest["threads"]
    assert threads["numba"] >= 1 and threads["numba_max"] >= threads["numba"] and threads["least_squares_blas"] == 1
    assert isinstance(threads["blas"], list)
    assert manifest["settings"]["n_starts"] == 2 and "json" not in manifest["settings"]
    assert [run["status"] for run in manifest["runs"]] == ["done"]
    # reproduce reruns it as a fit with the same options
    again = rerun_arguments(manifest, no_time, tmp_path / "again")
    assert again[0] == "fit" and "--n-starts" in again and again[again.index("--seed") + 1] == "4"
    # a different run in the same folder is refused (nothing overwritten), unless --force
    before = (out / "fit.json").read_bytes()
    assert main([*argv[:-2], "--n-starts", "3", "--out", str(out)]) == 2
    assert "n_starts: 2 -> 3" in capsys.readouterr().err
    assert (out / "fit.json").read_bytes() == before
    assert main([*argv[:-2], "--n-starts", "3", "--out", str(out), "--force"]) == 0
    assert json.loads((out / "manifest.json").read_text())["settings"]["n_starts"] == 3


def test_fit_failure_is_one_clean_error_line(small_csv, tmp_path, monkeypatch, capsys):
    """A least squares that cannot run (e.g. no start inside the domain) exits 2 with one
    line saying what failed and what to try, for fit and study alike, never a traceback."""
    import identify.fitting.lsq as lsq

    def no_start(*args, **kwargs):
        raise ValueError("no valid least-squares start: Table 1 lies outside the model's domain on this input")

    monkeypatch.setattr(lsq, "fit_least_squares", no_start)
    assert main(["fit", str(small_csv), "--n-operators", "21"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len([line for line in err if line.startswith("error:")]) == 1 and "Traceback" not in "\n".join(err)
    message = next(line for line in err if line.startswith("error:"))
    assert "least squares of" in message and "no valid least-squares start" in message
    assert "--n-operators" in message and "--n-starts" in message
    out = tmp_path / "study_run"
    assert main(["study", str(small_csv), "--out", str(out), "--n-operators", "21", *FAST]) == 2
    err = capsys.readouterr().err
    assert "error: least squares of" in err and "Traceback" not in err
    assert not (out / "fit.json").exists()  # nothing half-done is left as if it were a fit


def test_fit_with_21_operators_runs(small_csv, tmp_path):
    """More operators than Table 1's 12: the Table-1-shaped starts are rescaled, so the paper's
    sign of the thresholds gets a valid start (before: 'no valid least-squares start')."""
    out_json = tmp_path / "fit21.json"
    assert main(["fit", str(small_csv), "--n-operators", "21", "--n-starts", "2", "--json", str(out_json)]) == 0
    fit = json.loads(out_json.read_text())
    assert fit["model"]["n_operators"] == 21
    assert "alpha < 0 reached" in fit["message"] and "no valid least-squares start" not in fit["message"]
    assert fit["rms"] < 1.5 * fit["noise"]["sigma"]  # Table 1 data: 21 operators fit it about as well as 12


def test_study_no_report_skips_the_report(small_csv, tmp_path, capsys, report_calls):
    out = tmp_path / "run"
    assert main(["study", str(small_csv), "--out", str(out), "--no-report", *FAST]) == NOT_CONVERGED
    assert report_calls == [] and not (out / "report.html").exists()
    assert "report skipped (--no-report)" in capsys.readouterr().err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["task"] == "study" and manifest["settings"]["no_report"] is True
    assert "report" not in manifest["runs"][-1]["phases"]
    # resuming without --no-report is allowed (no number depends on it) and writes the report
    assert main(["study", str(small_csv), "--out", str(out), *FAST]) == NOT_CONVERGED
    if "identify.output.report" in sys.modules:
        assert [str(p) for p in report_calls] == [str(out)]
