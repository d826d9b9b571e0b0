"""The Python API (``from identify import load_record, Model, study, diagnose``): a study run
from Python without argparse is the command line's study, chain for chain."""

from __future__ import annotations

import json
import subprocess
import sys

import emcee
import numpy as np
import pytest

import identify
from identify import Model, load_record, study
from identify.bench import simulate
from identify.cli import main
from identify.data.records import write_record
from identify.fitting.posterior import BACKEND_GROUP

SHORT = {"max_steps": 40, "check_every": 20, "n_starts": 2, "progress": False}
SHORT_ARGS = ["--max-steps", "40", "--check-every", "20", "--n-starts", "2", "--progress", "off"]


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    """Table 1 transducer, paper input at 5 Hz (351 samples, 51 of them quiet), noise 0.5 um."""
    path = tmp_path_factory.mktemp("data") / "small.csv"
    write_record(path, simulate(fs=5.0, seed=4).record)
    return path


def chain_of(folder):
    return emcee.backends.HDFBackend(str(folder / "chain.h5"), name=BACKEND_GROUP, read_only=True).get_chain()


def test_the_api_names_are_there_and_import_lazily():
    for name in ("load_record", "Model", "study", "diagnose", "StudyResult", "fit_least_squares", "write_report"):
        assert name in identify.__all__ and callable(getattr(identify, name)), name
    with pytest.raises(AttributeError):
        _ = identify.no_such_name
    code = (
        "import sys, identify; print(sorted(m for m in ('numpy', 'numba', 'scipy', 'matplotlib') if m in sys.modules))"
    )
    assert (
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "[]"
    )


def test_study_from_python_is_the_command_lines_study(small_csv, tmp_path, capsys):
    """The same record, seed and settings from Python and from the command line: the same
    chain, bit for bit, the same summary; the result object holds fit, posterior, summary and paths."""
    result = study(load_record(small_csv), Model([]), out=tmp_path / "api", seed=3, report=False, **SHORT)
    assert result.status in ("converged", "not converged")
    assert result.out == tmp_path / "api"
    assert set(result.paths) >= {"data", "chain", "fit", "summary", "manifest"}
    assert all(path.is_file() for path in result.paths.values())
    assert result.fit.model.names == Model([]).names and not dict(zip(result.fit.model.names, result.fit.vary))["alpha"]
    assert result.posterior.samples.shape[1] == result.fit.vary.sum()
    assert result.summary == json.loads(result.paths["summary"].read_text())
    assert result.identifiability is not None

    # 40 steps: NOT CONVERGED, a result with a finding; the command line's exit code says so
    assert result.status == "not converged" and not result.converged and result.exit_code == 1
    assert (
        main(["study", str(small_csv), "--out", str(tmp_path / "cli"), "--seed", "3", "--no-report", *SHORT_ARGS]) == 1
    )
    assert np.array_equal(chain_of(tmp_path / "api"), chain_of(tmp_path / "cli"))
    cli_summary = json.loads((tmp_path / "cli" / "summary.json").read_text())

    def untimed(section):
        return {key: value for key, value in section.items() if key != "seconds"}

    assert untimed(cli_summary["posterior"]) == untimed(result.summary["posterior"])
    assert untimed(cli_summary["fit"]) == untimed(result.summary["fit"])

    # a path works as the record; a finished study is not run again
    capsys.readouterr()
    again = study(str(small_csv), out=tmp_path / "api", seed=3, report=False, quiet=True, **SHORT)
    assert again.status == "finished before" and again.posterior is None
    assert not again.converged and again.exit_code == 1  # the stored verdict
    assert again.summary == result.summary
    assert capsys.readouterr() == ("", "")


def test_study_refuses_bad_walkers_before_writing(small_csv, tmp_path):
    with pytest.raises(ValueError, match="walkers 5: needs an even number"):
        study(small_csv, out=tmp_path / "w", walkers=5, **SHORT)
    assert not (tmp_path / "w").exists() or not any((tmp_path / "w").iterdir())


def test_study_refuses_a_bad_priors_file_before_writing(small_csv, tmp_path):
    """study(priors=) is study --priors: a file that cannot be used raises PriorsError (exit code 2
    from the command line) before anything is written."""
    from identify.fitting.priors import PriorsError

    bad = tmp_path / "bad.toml"
    bad.write_text("[no_such_parameter]\ndistribution = 'uniform'\nlower = 0.0\nupper = 1.0\n")
    with pytest.raises(PriorsError, match="no_such_parameter"):
        study(small_csv, out=tmp_path / "p", priors=bad, **SHORT)
    assert not (tmp_path / "p").exists() or not any((tmp_path / "p").iterdir())
    assert main(["study", str(small_csv), "--out", str(tmp_path / "q"), "--priors", str(bad), *SHORT_ARGS]) == 2
