"""The local C compiler: find it, build a shared library from the export's C.

The compiler is ``$CC`` when set, else the first of ``cc``, ``gcc``, ``clang`` on the
``PATH``; :func:`find_compiler` says what it tried when there is none.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
from pathlib import Path

from .sources import COMPILE_FLAGS
from .spec import ExportError

__all__ = ["CANDIDATES", "CompilerError", "find_compiler", "shared_library", "executable"]

#: Compilers tried in order after ``$CC``.
CANDIDATES = ("cc", "gcc", "clang")
#: Seconds one compilation may take.
TIMEOUT = 120


class CompilerError(ExportError):
    """No C compiler, or one that failed (one line: what was tried, or its first error)."""


def find_compiler(compiler=None) -> list[str]:
    """The compiler command (a list: ``$CC`` may hold options) or :class:`CompilerError` naming what was tried.

    ``compiler``: a command (str, e.g. ``"gcc -m64"``, or an already found list); default ``$CC``, then
    :data:`CANDIDATES`."""
    if isinstance(compiler, (list, tuple)):
        compiler = shlex.join(compiler)
    tried = []
    choices = [compiler] if compiler else ([os.environ["CC"]] if os.environ.get("CC") else []) + list(CANDIDATES)
    for choice in choices:
        command = shlex.split(choice)
        if command and shutil.which(command[0]):
            return command
        tried.append(choice)
    raise CompilerError(f"no C compiler found (tried {', '.join(tried)} on the PATH); set CC to one")


def _run(command, what: str) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CompilerError(f"{what}: {shlex.join(command)} failed ({exc})") from None
    if done.returncode != 0:
        first = next((line for line in done.stderr.splitlines() if "error" in line), done.stderr.strip()[:300])
        raise CompilerError(f"{what}: {command[0]} exited with {done.returncode}: {first.strip()}")


def shared_library(sources, output, *, compiler=None, defines=(), extra_flags=()) -> Path:
    """Build ``output`` (a ``.so``) from the C ``sources`` with ``cc -shared -fPIC -O2 ... -lm``."""
    command = [
        *find_compiler(compiler),
        *COMPILE_FLAGS,
        "-shared",
        "-fPIC",
        *extra_flags,
        *(f"-D{d}" for d in defines),
        "-o",
        str(output),
        *(str(s) for s in sources),
        "-lm",
    ]
    _run(command, f"building {Path(output).name}")
    return Path(output)


def executable(sources, output, *, compiler=None) -> Path:
    """Build the program ``output`` from the C ``sources`` (the README's example, a benchmark)."""
    command = [*find_compiler(compiler), *COMPILE_FLAGS, "-o", str(output), *(str(s) for s in sources), "-lm"]
    _run(command, f"building {Path(output).name}")
    return Path(output)
