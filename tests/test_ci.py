"""The CI script runs exactly the README's test command, and that command installs what the tests exercise."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _readme_commands():
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.*?)\n```", text, re.S)


def test_ci_runs_the_readme_test_command():
    commands = _readme_commands()
    test_cmds = [c for c in commands if "pytest" in c]
    assert len(test_cmds) == 1, test_cmds
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci == test_cmds[0]


def test_test_command_installs_the_dask_extra():
    """tests/test_batch.py's LocalCluster test needs dask.distributed: the test command installs it."""
    (cmd,) = [c for c in _readme_commands() if "pytest" in c]
    extras = re.search(r'-e "\.\[([^\]]*)\]"', cmd).group(1).split(",")
    assert {"test", "dask"} <= set(extras)
    # the study command installs the package itself
    (study,) = [c for c in _readme_commands() if " study " in c]
    assert study.startswith("python -m pip install -e . &&")


def test_api_and_cli_share_the_sampler_defaults():
    """sample_posterior's step cap and check interval are study's (issue 18)."""
    import inspect

    from identify.cli import build_parser
    from identify.defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS
    from identify.fitting.posterior import sample_posterior

    params = inspect.signature(sample_posterior).parameters
    args = build_parser().parse_args(["study", "x.csv", "--out", "o"])
    assert params["max_steps"].default == args.max_steps == DEFAULT_MAX_STEPS == 60000
    assert params["check_every"].default == args.check_every == DEFAULT_CHECK_EVERY


def test_the_test_extra_installs_what_the_default_options_use():
    """pytest's default options run the suite in worker processes (``-n``): the test extra
    installs pytest-xdist, which provides that option."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    addopts = project["tool"]["pytest"]["ini_options"]["addopts"]
    assert re.search(r"(^|\s)-n\s+\d+", addopts)
    extra = project["project"]["optional-dependencies"]["test"]
    assert any(re.match(r"pytest-xdist\b", requirement) for requirement in extra)
