"""Ctrl-C and SIGTERM during a lap, where a native solver would swallow them.

IPOPT (the NMPC's rescue) catches the ``KeyboardInterrupt`` that Ctrl-C raises while it runs,
reports a failed solve instead (the run would go on as if nothing had been asked), and CasADi
prints a warning of its own to the terminal. So the ``cape`` command's handlers record each
signal here, and raise it at once only outside a lap: within one (``deferred()``), the closed
loop calls ``check()`` after every controller step and the interrupt stops the run there, a few
milliseconds later, with the command's one-line message and nothing else.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

requested: list[BaseException] = []
"""The interrupt each signal asked for (the command's handlers append it)."""

_deferring = 0


def check() -> None:
    """Raise the first interrupt asked for, if any."""
    if requested:
        raise requested[0]


def deferring() -> bool:
    """True within ``deferred()``: a handler should record the signal and not raise it."""
    return _deferring > 0


@contextmanager
def deferred() -> Iterator[None]:
    """A stretch (the lap's loop) that calls ``check()`` often enough to stop promptly: signals
    that arrive in it are raised by that check, never inside a native solver. One already
    asked for is raised on entry and on exit."""
    global _deferring
    check()
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
    check()
