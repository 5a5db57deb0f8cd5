"""The ``cape`` command: the entry points the Snakemake rules call.

Each subcommand does one job of the workflow and writes its outputs atomically. Problems the
user can fix are reported as one clear message (exit status 2), never as a traceback. The
commands live by group (``data``, ``models``, ``runs``, ``study``), each with its arguments
right above it; this module assembles them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from cape.cli import data, models, runs, study  # noqa: F401  (they register their commands)
from cape.cli.common import COMMANDS, STARTED
from cape.errors import CapeError

__all__ = ["STARTED", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from cape import __version__

    parser = argparse.ArgumentParser(
        prog="cape",
        description="CAPE: control algorithm performance evaluation under learned vehicle "
        "dynamics models. Subcommands are the steps of the Snakemake workflow.",
    )
    parser.add_argument("--version", action="version", version=f"cape {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (help_text, arguments, func) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text)
        arguments(p)
        p.set_defaults(func=func)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; a ``CapeError`` becomes a one-line message and exit status 2."""
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except CapeError as exc:
        print(f"cape {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0
