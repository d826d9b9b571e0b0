"""Command line: ``python -m identify COMMAND ...``.

Each command lives in its own module ``identify.cli.<name>`` that defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
imported only when their command runs, so ``--help`` stays fast.

Every command ends with one of the exit codes in :data:`EXIT_CODES` and never with a
traceback: a bad option or input is one ``error:`` line (exit 2), Ctrl-C and SIGTERM
stop it where completed work is kept (exit 130), and an unexpected failure is one line
too (exit 1; ``IDENTIFY_DEBUG=1`` shows the traceback). See docs/reliability.md.
"""

from __future__ import annotations

import argparse
import ctypes
import importlib
import importlib.metadata as md
import os
import signal
import sys
import threading

from ..commands import COMMANDS, PARENT_VARIABLE, add_command_arguments
from ..data.fileio import DiskFullError, LinkedFileError, is_disk_full
from ..data.hdf5 import ChainFileError
from ..data.locks import FolderBusyError
from ..logs import configure
from .interrupts import interrupts_redelivered
from .options import OptionError

#: Exit code -> meaning (printed by ``--help``; docs/reproducibility.md). The numbers are
#: :mod:`identify.defaults`' ``EXIT_*``.
EXIT_CODES = {
    0: "done (a study: its chain converged; a fit: its solver converged; a batch: every run did)",
    1: "done with a finding to look at: study's chain NOT CONVERGED (raise --max-steps), fit's solver did not "
    "converge, batch: a run failed or did not converge, reproduce: the rerun differs; also a full disk (one "
    "line naming the file) or an unexpected failure (one error line; IDENTIFY_DEBUG=1 shows the traceback)",
    2: "bad input or usage: an invalid option (named), an unreadable or invalid record (file, line, column) or "
    "priors file (file, parameter), a damaged results file, a link planted in a results folder, a folder in use "
    "by another process, a folder holding a run with other settings, a batch folder of another configuration",
    130: "interrupted by Ctrl-C or SIGTERM: completed work is kept; rerun the same command to resume",
}

#: Set to 1 to see the traceback of an unexpected failure.
DEBUG_VARIABLE = "IDENTIFY_DEBUG"


def _exit_code_text() -> str:
    return "exit codes:\n" + "\n".join(f"  {code:<4} {text}" for code, text in EXIT_CODES.items())


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line naming the option (exit code 2), and
    that takes options only as spelt in full (``allow_abbrev=False``: ``--jso`` is not
    ``--json``; a batch config or a manifest can only name an option exactly)."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"error: {self.prog}: {message} (see '{self.prog} --help')\n")


def version() -> str:
    """The installed package's version (``msma-gpi``), or pyproject's when run from a checkout."""
    try:
        return md.version("msma-gpi")
    except md.PackageNotFoundError:  # pragma: no cover - not installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="python -m identify",
        description="Bayesian identification of GPI hysteresis in MSMA transducers.",
        epilog=_exit_code_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(
            name,
            help=mod.HELP,
            description=mod.HELP,
            epilog=_exit_code_text(),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        p.set_defaults(_module=module)
        add_command_arguments(p, mod)
    return parser


def input_errors() -> tuple:
    """Exception types that mean bad input or usage (exit code 2)."""
    # deferred (--help imports every command's module): fitting.priors: numpy, scipy, numba, +550 ms
    from ..data.records import RecordError
    from ..fitting.priors import PriorsError
    from ..output.results import DamagedResultsError, RunMismatchError

    return (
        FolderBusyError,
        OptionError,
        PriorsError,
        RecordError,
        DamagedResultsError,
        RunMismatchError,
        ChainFileError,
        LinkedFileError,
    )


def _die_with_parent() -> None:
    """When started by a batch: end (SIGTERM, i.e. stop between steps) if the batch ends."""
    value = os.environ.pop(PARENT_VARIABLE, None)
    if not value or not value.isdigit():
        return
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != int(value):  # the batch ended before the prctl took effect
        raise KeyboardInterrupt("the batch that started this run has ended")


def _sigterm_as_interrupt() -> None:
    """SIGTERM (``kill PID``) stops a command exactly like Ctrl-C (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)

    if signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None):
        signal.signal(signal.SIGTERM, interrupt)


def main(argv=None, *, when_finished=None) -> int:
    """Run one command (``argv``: the command line after ``python -m identify``); its exit code.

    ``when_finished``, if given, is called with the exit code as soon as the command has
    finished, before this function's own clean-up (:func:`program` installs the late-signal
    handlers with it, and they then stay). A Ctrl-C or SIGTERM that lands after the command has
    finished, in that clean-up, changes nothing: the command's code is returned."""
    previous = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    finished = []
    try:
        _sigterm_as_interrupt()
        with interrupts_redelivered():
            finished.append(_main(argv))
        if when_finished is not None:
            when_finished(finished[0])
            previous = None  # the process's handlers are when_finished's from now on
        return finished[0]
    except KeyboardInterrupt:
        if not finished:
            raise
        if when_finished is not None:  # it landed before when_finished had put its handlers in
            when_finished(finished[0])
            previous = None
        return finished[0]
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def program() -> None:
    """``python -m identify``: :func:`main`, then exit with its code. A Ctrl-C or SIGTERM that
    arrives once the command has finished (while Python shuts down its threads) ends the
    process with that code and a note, never by the signal with no word."""
    code = 2
    try:
        code = main(when_finished=_late_signals_exit)
    except SystemExit as exc:  # --help, --version, a usage error
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    finally:
        _late_signals_exit(code)
    raise SystemExit(code)


def _late_signals_exit(code: int) -> None:
    """From now on SIGINT and SIGTERM end the process at once with ``code`` (the command's own:
    its work is complete), saying so, instead of interrupting Python's shutdown."""
    if threading.current_thread() is not threading.main_thread():  # pragma: no cover - always main here
        return

    def late(signum, frame):
        try:
            print(
                f"note: {signal.Signals(signum).name} after the command had finished; its work is complete "
                f"(exit code {code})",
                file=sys.stderr,
            )
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)

    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, late)


def _main(argv) -> int:
    try:
        _die_with_parent()
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 2
        configure(getattr(args, "verbose", 0), getattr(args, "quiet", 0))
        module = importlib.import_module(args._module)
        return int(module.run(args) or 0)
    except SystemExit:  # --help, --version and usage errors: before the clauses below import anything
        raise
    except KeyboardInterrupt:
        print("interrupted; completed work is kept (rerun the same command to resume)", file=sys.stderr)
        return 130
    except input_errors() as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. output piped into `head`
        return 0
    except MemoryError:
        print(
            "error: out of memory. For a long, densely sampled record pass --every N (keeps every N-th sample "
            "and every input reversal; the GPI's output there is unchanged)",
            file=sys.stderr,
        )
        return 1
    except OSError as exc:
        if os.environ.get(DEBUG_VARIABLE):
            raise
        if is_disk_full(exc):  # one line naming the file and what to do
            full = exc if isinstance(exc, DiskFullError) else DiskFullError(exc.filename)
            print(f"error: {full}", file=sys.stderr)
            return 1
        where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2 if isinstance(exc, (PermissionError, FileNotFoundError, NotADirectoryError, IsADirectoryError)) else 1
    except Exception as exc:  # never a traceback for the user
        if os.environ.get(DEBUG_VARIABLE):
            raise
        print(
            f"error: unexpected {type(exc).__name__}: {exc} (rerun with {DEBUG_VARIABLE}=1 for the traceback)",
            file=sys.stderr,
        )
        return 1
