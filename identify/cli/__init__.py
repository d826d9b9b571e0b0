"""The command line, ``python -m identify COMMAND``: one thin module per command.

Each command module (``identify.cli.<name>``, listed in :data:`identify.commands.COMMANDS`)
defines ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``: it parses its options
(:mod:`identify.cli.options` checks every value) and calls into a workflow
(:mod:`identify.workflows`) or a lower stage. :mod:`identify.cli.app` dispatches, turns
errors into exit codes and keeps ``--help`` fast: nothing here imports numpy, scipy,
numba or matplotlib at module level.
"""

from ..commands import COMMANDS, PARENT_VARIABLE
from .app import DEBUG_VARIABLE, EXIT_CODES, build_parser, input_errors, main, version

__all__ = [
    "COMMANDS",
    "PARENT_VARIABLE",
    "DEBUG_VARIABLE",
    "EXIT_CODES",
    "build_parser",
    "input_errors",
    "main",
    "version",
]
