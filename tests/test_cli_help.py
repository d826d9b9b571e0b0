"""``python -m identify --help`` and every command's ``--help`` import no numerical library
(numba, scipy, matplotlib; not even numpy), so they answer at once."""

from __future__ import annotations

import subprocess
import sys

from identify.commands import COMMANDS

HEAVY = ("numba", "scipy", "matplotlib", "numpy")

SCRIPT = """
import contextlib, io, sys
from identify.cli import main
heavy = {heavy!r}
for command in {commands!r}:
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            main([*command.split(), "--help"])
        except SystemExit:
            pass
    loaded = [name for name in heavy if name in sys.modules]
    print(repr(command), loaded)
"""


def help_imports(commands) -> dict[str, str]:
    code = SCRIPT.format(heavy=HEAVY, commands=list(commands))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return dict(line.split(" ", 1) for line in result.stdout.splitlines())


def test_help_imports_no_numerical_library():
    found = help_imports(["", *COMMANDS])
    assert len(found) == len(COMMANDS) + 1
    assert all(loaded == "[]" for loaded in found.values()), found


def test_the_check_sees_a_heavy_import():
    """The same check fails when a command does import numpy (here: by running one that loads a record)."""
    code = (
        SCRIPT.format(heavy=HEAVY, commands=[])
        + "\nimport identify.data.records\nprint([n for n in heavy if n in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "numpy" in out


def test_python_m_identify_help_runs():
    result = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "identify", "study", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "usage: python -m identify study" in result.stdout
    imported = {line.split("|")[-1].strip() for line in result.stderr.splitlines() if line.startswith("import time:")}
    assert not imported & set(HEAVY), imported & set(HEAVY)
