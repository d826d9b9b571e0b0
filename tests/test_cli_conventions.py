"""Command-line conventions on real subprocesses (issue 18): --version."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _env():
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + (os.pathsep + e["PYTHONPATH"] if e.get("PYTHONPATH") else "")
    return e


def test_version(tmp_path):
    import importlib.metadata as md

    done = subprocess.run([sys.executable, "-m", "identify", "--version"], cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"python -m identify {md.version('msma-gpi')}"
