"""One verbosity scheme for every command: ``-v``/``-q`` on top of Python :mod:`logging`.

Every message the package writes for a person (progress, notes, what was reused or
skipped) goes through the logger ``"identify"`` (or a child, ``"identify.posterior"``,
...): numerical code never prints to stderr. Results stay on stdout (tables, paths) and
errors are one ``error:`` line from the command line (:mod:`identify.cli`).

Levels (:func:`level_for`), counted from the default ``INFO``:

=========  ========  =====================================================================
flags      level     what is shown on stderr
=========  ========  =====================================================================
``-q -q``  ERROR     nothing but errors
``-q``     WARNING   warnings only: no progress, no notes (the old ``--quiet``)
(none)     INFO      progress lines and notes, as the commands always wrote them
``-v``     DEBUG     also one line per least-squares start and per skipped check
                     (the old ``fit --verbose``)
=========  ========  =====================================================================

The command line calls :func:`configure` once per command. From Python (a script, a
terminal, a notebook), :func:`identify.study` and :func:`identify.diagnose` show their
progress by default, as emcee and lmfit do: :func:`show_progress` routes the package logger
to stderr at INFO unless logging was configured already (a handler on the ``identify``
logger or on the root logger: then that configuration decides); ``progress=False``
silences them.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

__all__ = [
    "LOGGER_NAME",
    "get_logger",
    "level_for",
    "configure",
    "add_verbosity_arguments",
    "say",
    "show_progress",
    "progress_function",
    "ordinal",
]

#: Name of the package's logger; modules log to children of it.
LOGGER_NAME = "identify"


def get_logger(name: str = "") -> logging.Logger:
    """The package logger, or its child ``identify.<name>``."""
    return logging.getLogger(LOGGER_NAME + ("." + name if name else ""))


def level_for(verbose: int = 0, quiet: int = 0) -> int:
    """The logging level for ``verbose`` ``-v`` and ``quiet`` ``-q`` flags (table in the module docstring).

    Parameters
    ----------
    verbose, quiet : int or bool, default 0
        How often each flag was given (``True`` counts as 1).

    Returns
    -------
    int
        ``logging.INFO + 10 (quiet - verbose)``, clipped to ``[DEBUG, ERROR]``.
    """
    step = int(quiet or 0) - int(verbose or 0)
    return min(logging.ERROR, max(logging.DEBUG, logging.INFO + 10 * step))


class _StderrHandler(logging.Handler):
    """Writes the bare message to the *current* ``sys.stderr`` (looked up at each record, so
    a redirected or captured stderr gets it) and flushes at once."""

    def emit(self, record):
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:  # pragma: no cover - a closed stream must not end the run
            self.handleError(record)


def configure(verbose: int = 0, quiet: int = 0) -> logging.Logger:
    """Route the package logger to stderr at the level of the flags (idempotent).

    Messages are written bare (no level or time prefix: a ``note:`` or ``error:`` says
    what it is). The logger does not propagate to the root logger, so a program that
    also configured the root logger does not get every line twice.

    Returns
    -------
    logging.Logger
        The ``"identify"`` logger.
    """
    logger = get_logger()
    for handler in [h for h in logger.handlers if isinstance(h, _StderrHandler)]:
        logger.removeHandler(handler)
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    logger.setLevel(level_for(verbose, quiet))
    logger.propagate = False
    return logger


def add_verbosity_arguments(parser: argparse.ArgumentParser) -> None:
    """``-v/--verbose`` and ``-q/--quiet`` (counted) on ``parser``; every command has them."""
    group = parser.add_argument_group("messages on stderr")
    group.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="more detail (one line per least-squares start, per convergence check); -v adds DEBUG",
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="count",
        default=0,
        help="less: -q shows only warnings and errors (no progress), -qq only errors",
    )


def say(message: str, level: int = logging.INFO) -> None:
    """Log one progress or note line through the package logger (INFO by default)."""
    get_logger().log(level, message)


def show_progress() -> None:
    """Show the package's progress lines on stderr from Python, unless logging is configured.

    A program that configured :mod:`logging` (a handler on the ``identify`` logger, e.g. the
    command line's :func:`configure`, or on the root logger, e.g. ``logging.basicConfig``)
    keeps its configuration; otherwise the lines would go nowhere (Python's last-resort
    handler shows warnings only), so the ``identify`` logger gets the stderr handler at INFO,
    once per process. In a notebook stderr is the cell's output.
    """
    logger = get_logger()
    if logger.handlers or logging.getLogger().handlers:
        return
    configure()


def progress_function(progress, prefix: str = ""):
    """The ``progress(message)`` callable of a ``progress`` argument of the Python API.

    Parameters
    ----------
    progress : callable or bool or None
        A callable is returned as it is; False gives a function that shows nothing; None or
        True give lines on stderr through the package logger (:func:`show_progress`), with
        the seconds since this call and ``prefix``.
    prefix : str, optional
        Put before each message (e.g. ``"diagnosis: "``).
    """
    if callable(progress):
        return progress
    if progress is False:
        return lambda message: None

    show_progress()
    started = time.perf_counter()
    return lambda message: say(f"[{time.perf_counter() - started:6.1f} s] {prefix}{message}")


def ordinal(n: int) -> str:
    """``n`` as an English ordinal: 1st, 2nd, 3rd, 4th, 11th, 12th, 13th, 21st, ..."""
    n = int(n)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"
