"""Checked command-line values: every option is validated when it is parsed, before a
command reads or writes anything, and a bad value is one line naming the option.

The functions here are ``argparse`` ``type=`` callables: they return the parsed value or
raise :class:`argparse.ArgumentTypeError`, which the command line turns into
``error: argument --seed: expected an integer >= 0, got -1`` (exit code 2). The batch
runs the same parsers on every job's options before any job starts.

:class:`OptionError` is for checks that need more than one option or the record (e.g.
``--walkers`` against the model's dimension); its message names the option too.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

__all__ = [
    "OptionError",
    "integer",
    "positive_int",
    "seed",
    "n_operators",
    "positive_float",
    "non_negative_float",
    "open_interval",
    "noise_sigma",
    "folder_path",
    "existing_folder",
    "file_path",
    "existing_file",
    "number_pair",
    "unit",
    "MAX_OPERATORS",
]

#: Largest ``--n-operators`` accepted (the paper uses 12; memory and time grow with N).
MAX_OPERATORS = 1000


class OptionError(ValueError):
    """An option value that cannot work with the others or with the record; names the option."""


def _fail(message):
    raise argparse.ArgumentTypeError(message)


def integer(low=None, high=None, what="an integer"):
    """A ``type=`` callable for an integer in ``[low, high]`` (either bound may be None)."""

    def parse(text):
        try:
            value = int(str(text).strip())
        except ValueError:
            _fail(f"expected {what}, got {text!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            _fail(f"expected {what}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


positive_int = integer(1, None, "an integer >= 1")
seed = integer(0, 2**63 - 1, "an integer >= 0 (the seed of the random generator)")
n_operators = integer(1, MAX_OPERATORS, f"a number of operators between 1 and {MAX_OPERATORS}")


def _finite(text):
    try:
        value = float(str(text).strip())
    except ValueError:
        _fail(f"expected a number, got {text!r}")
    if not math.isfinite(value):
        _fail(f"expected a finite number, got {text!r}")
    return value


def positive_float(text) -> float:
    """A finite number > 0."""
    value = _finite(text)
    if not value > 0:
        _fail(f"expected a number > 0, got {text!r}")
    return value


def non_negative_float(text) -> float:
    """A finite number >= 0."""
    value = _finite(text)
    if value < 0:
        _fail(f"expected a number >= 0, got {text!r}")
    return value


def open_interval(low, high):
    """A ``type=`` callable for a number strictly between ``low`` and ``high``."""

    def parse(text):
        value = _finite(text)
        if not low < value < high:
            _fail(f"expected a number strictly between {low:g} and {high:g}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


def noise_sigma(text) -> str:
    """``free`` or a finite number > 0 (returned as given, so the manifest records the text)."""
    if str(text).strip().lower() == "free":
        return str(text).strip()
    positive_float(text)
    return str(text)


def _nearest_parent_is_a_folder(text, path: Path) -> None:
    """The nearest existing parent of ``path`` must be a folder (the rest is created)."""
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                _fail(f"{text}: {parent} is a file, not a folder")
            break


def _path_for_writing(text, *, kind: str) -> Path:
    """``text`` as a path a ``kind`` (``"folder"`` or ``"file"``) can be written at; fails naming the problem."""
    path = Path(text)
    if not str(text).strip():
        _fail(f"expected a {kind} path, got ''")
    if kind == "folder" and path.exists() and not path.is_dir():
        _fail(f"{text} exists and is not a folder")
    if kind == "file" and (path.is_dir() or str(text).endswith(("/", "\\"))):
        _fail(f"{text} is a folder; give a file name")
    _nearest_parent_is_a_folder(text, path)
    return path


def _existing(text, *, kind: str) -> Path:
    """``text`` as the path of an existing ``kind`` (``"folder"`` or ``"file"``); fails naming the problem."""
    path = Path(text)
    if not path.exists():
        _fail(f"{text}: no such {kind}")
    if kind == "folder" and not path.is_dir():
        _fail(f"{text} is not a folder")
    if kind == "file" and path.is_dir():
        _fail(f"{text} is a folder, not a file")
    return path


def folder_path(text) -> str:
    """A folder to write into: it may exist, but not as a file."""
    _path_for_writing(text, kind="folder")
    return text


def existing_folder(text) -> str:
    """A folder that exists."""
    _existing(text, kind="folder")
    return text


def file_path(text) -> str:
    """A file to write: it may exist, but not as a folder (its folder is created)."""
    _path_for_writing(text, kind="file")
    return text


def existing_file(text) -> str:
    """A file that exists."""
    _existing(text, kind="file")
    return text


def number_pair(text, option: str, *, form: str = "A:B with two numbers", example: str = "0:5") -> tuple[float, float]:
    """``"A:B"`` -> ``(A, B)`` floats, for options checked at run time.

    Raises
    ------
    ValueError
        Naming ``option``, the ``form`` it takes and an ``example`` when ``text`` is not two numbers.
    """
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"{option} must be {form} (e.g. {example}), got {text!r}") from None
    return a, b


def unit(text) -> str:
    """A unit (``--input-unit``, ``--output-unit``): a short printable string
    (:func:`identify.data.records.unit_problem`), e.g. ``um``, ``V``, ``mm/s``."""
    # deferred (--help imports every command's module): data.records: numpy, +110 ms
    from ..data.records import unit_problem

    problem = unit_problem(text)
    if problem:
        _fail(problem)
    return text
