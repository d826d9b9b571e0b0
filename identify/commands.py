"""The commands of ``python -m identify``: one table for the command line, the batch and reproduce.

Importing this module is cheap (no numerical library), so ``--help`` stays fast. Each
command's module (:mod:`identify.cli`) defines ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; :mod:`identify.workflows.batch` and :mod:`identify.workflows.reproduce`
look a command's options up here at run time, as the shell would run it.
"""

import os
from pathlib import Path

from .logs import add_verbosity_arguments

#: command name -> module, in the order ``--help`` lists them.
COMMANDS = {
    "paper": "identify.cli.paper",
    "simulate": "identify.cli.simulate",
    "fit": "identify.cli.fit",
    "study": "identify.cli.study",
    "report": "identify.cli.report",
    "batch": "identify.cli.batch",
    "reproduce": "identify.cli.reproduce",
    "diagnose": "identify.cli.diagnose",
    "predict": "identify.cli.predict",
    "compensate": "identify.cli.compensate",
    "export": "identify.cli.export",
    "design": "identify.cli.design",
}

#: Set by a batch for the commands it runs: their PID is to end (SIGTERM) when the batch does.
PARENT_VARIABLE = "IDENTIFY_PARENT_PID"


def package_root():
    """The folder that holds this package (``identify/`` and ``model/``: a checkout's root), a
    :class:`pathlib.Path`."""
    return Path(__file__).resolve().parents[1]


def package_environment(env=None) -> dict:
    """A copy of ``env`` (default :data:`os.environ`) whose ``PYTHONPATH`` starts with
    :func:`package_root`, so that a subprocess ``python -m identify ...`` runs this very code,
    installed or not, wherever it is started."""
    env = dict(os.environ if env is None else env)
    root = str(package_root())
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def add_command_arguments(parser, module) -> None:
    """The options of command ``module`` (its ``add_arguments``) and the shared ``-v/-q``
    (:func:`identify.logs.add_verbosity_arguments`): the command line's parser of a command,
    also used by :mod:`identify.workflows.batch` and :mod:`identify.workflows.reproduce` to
    check a command line."""
    module.add_arguments(parser)
    add_verbosity_arguments(parser)
