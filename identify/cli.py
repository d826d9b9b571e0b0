"""Command line: ``python -m identify COMMAND ...``.

Each command lives in its own module ``identify.cmd_<name>`` that defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
imported only when their command runs, so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: command name -> module, in the order ``--help`` lists them.
COMMANDS = {
    "paper": "identify.cmd_paper",
    "simulate": "identify.cmd_simulate",
    "fit": "identify.cmd_fit",
    "study": "identify.cmd_study",
    "report": "identify.cmd_report",
    "batch": "identify.cmd_batch",
    "reproduce": "identify.cmd_reproduce",
    "diagnose": "identify.cmd_diagnose",
    "predict": "identify.cmd_predict",
    "compensate": "identify.cmd_compensate",
}

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m identify",
        description="Bayesian identification of GPI hysteresis in MSMA transducers.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        p.set_defaults(_module=module)
        mod.add_arguments(p)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted; completed work is kept (rerun the same command to resume)", file=sys.stderr)
        return 130
