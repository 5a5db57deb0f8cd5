"""The ``cape`` command: the entry points the Snakemake rules call.

Each subcommand does one job of the workflow and writes its outputs atomically. Problems the
user can fix are reported as one clear message (exit status 2), never as a traceback. The
commands live by group (``data``, ``models``, ``runs``, ``study``), each with its arguments
right above it; this module assembles them.
"""

from __future__ import annotations

import argparse
import errno
import signal
import sys
import threading
from collections.abc import Sequence
from typing import NoReturn

from cape.cli import data, models, question, runs, study  # noqa: F401  (they register their commands)
from cape.cli.common import COMMANDS, STARTED
from cape.errors import CapeError, limit_text, one_line
from cape.numerics import interrupt

__all__ = ["STARTED", "build_parser", "main"]


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a bad argument is one line (what is wrong and where the help is) and
    exit status 2, as every other error of ``cape``; the usage is one ``--help`` away."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    from cape import __version__

    parser = OneLineParser(
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


class Interrupted(BaseException):
    """SIGTERM (what a scheduler or Snakemake sends to stop a job), raised where the process
    is, so that its temporary files are cleaned up as for Ctrl-C."""


def _terminated(signum: int, _frame: object) -> None:
    interrupt.requested.append(Interrupted(signum))
    if not interrupt.deferring():  # within a lap the loop raises it (cape.numerics.interrupt)
        raise interrupt.requested[-1]


def _interrupted(signum: int, _frame: object) -> None:
    interrupt.requested.append(KeyboardInterrupt())
    if not interrupt.deferring():
        raise interrupt.requested[-1]


def describe_os_error(exc: OSError) -> str:
    """One line for a failed read or write: the file, what the system said, and the fix."""
    where = f"{exc.filename}: " if exc.filename else ""
    what = exc.strerror or str(exc)
    fixes = {
        errno.ENOSPC: "the disk is full; free some space and run the command again",
        errno.EDQUOT: "the disk quota is exhausted; free some space and run the command again",
        errno.EACCES: "permission denied; choose a location you can write to",
        errno.EPERM: "an immutable folder, or another user's; choose a location you can write to",
        errno.EROFS: "the file system is read-only; choose another location",
    }
    fix = fixes.get(exc.errno or 0, "check the path and the file system, then run it again")
    return f"{where}{what} ({fix}; no file was left half-written)"


def shortage(exc: BaseException) -> str | None:
    """One line for a machine that ran short (no thread, process or memory to be had), naming
    the resource and this process's limit; None for any other error."""
    import resource

    text = str(exc)
    threads = isinstance(exc, RuntimeError) and "can't start new thread" in text
    if threads or (isinstance(exc, OSError) and exc.errno == errno.EAGAIN):
        return (f"the machine would not start another thread or process (ulimit -u: "
                f"{limit_text(resource.RLIMIT_NPROC)} for this user); end other programs or ask "
                "for a higher limit, then run it again")  # fmt: skip
    memory = isinstance(exc, MemoryError) or (
        isinstance(exc, OSError) and exc.errno == errno.ENOMEM
    )
    if memory or (isinstance(exc, RuntimeError) and "can't allocate memory" in text):
        return (f"out of memory (ulimit -v: {limit_text(resource.RLIMIT_AS)} kB; a job's mem_mb "
                "or the machine's memory); free memory or give the job more, then run it "
                "again")  # fmt: skip
    return None


def told(exc: BaseException) -> tuple[int, str]:
    """How a command ends on ``exc``: its exit status and its one line. A ``CapeError``, a
    failed read or write (a full disk) or a machine that ran short of threads or memory is 2
    and the message; Ctrl-C 130, SIGTERM 143."""
    if isinstance(exc, CapeError):
        return 2, f"error: {one_line(str(exc))}"
    short = shortage(exc)
    if short is not None:
        return 2, f"error: {short}; no output was left half-written"
    if isinstance(exc, OSError):
        return 2, f"error: {one_line(describe_os_error(exc))}"
    if isinstance(exc, Interrupted):
        return 143, "terminated; no output was left half-written"
    return 130, "interrupted; no output was left half-written"


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand. A ``CapeError`` or a failed read or write (a full disk) becomes a
    one-line message and exit status 2; Ctrl-C and SIGTERM a one-line message and 130 or 143.
    Every output is written atomically, so none of these leaves a half-written file."""
    from cape.storage import ownership

    args = build_parser().parse_args(argv)
    succeeded = False
    main_thread = threading.current_thread() is threading.main_thread()
    previous = {}
    if main_thread:  # raise, and remember for the loop (cape.numerics.interrupt: IPOPT swallows it)
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _terminated)
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupted)
    try:
        args.func(args)
        succeeded = True
    except (CapeError, OSError, KeyboardInterrupt, Interrupted, MemoryError, RuntimeError) as exc:
        if isinstance(exc, (MemoryError, RuntimeError)) and shortage(exc) is None:
            raise  # a bug: its traceback
        status, message = told(exc)
        print(f"cape {args.command}: {message}", file=sys.stderr)
        return status
    finally:
        ownership.release(succeeded)  # the outputs' locks; a failure's empty claims removed
        for number, handler in previous.items():
            signal.signal(number, handler)
        interrupt.requested.clear()
    return 0
