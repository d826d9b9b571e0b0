"""The commands of ``python -m identify``: one table for the command line, the batch and reproduce.

Importing this module is cheap (no numerical library), so ``--help`` stays fast. Each
command's module (:mod:`identify.cli`) defines ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; :mod:`identify.workflows.batch` and :mod:`identify.workflows.reproduce`
look a command's options up here at run time, as the shell would run it.
"""

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
}

#: Set by a batch for the commands it runs: their PID is to end (SIGTERM) when the batch does.
PARENT_VARIABLE = "IDENTIFY_PARENT_PID"


def add_command_arguments(parser, module) -> None:
    """The options of command ``module`` (its ``add_arguments``) and the shared ``-v/-q``
    (:func:`identify.logs.add_verbosity_arguments`): the command line's parser of a command,
    also used by :mod:`identify.workflows.batch` and :mod:`identify.workflows.reproduce` to
    check a command line."""
    from .logs import add_verbosity_arguments

    module.add_arguments(parser)
    add_verbosity_arguments(parser)
