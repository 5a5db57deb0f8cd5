"""Ctrl-C and SIGTERM that a native solver swallows.

IPOPT (the NMPC's rescue) catches the ``KeyboardInterrupt`` that Ctrl-C raises while it runs and
reports a failed solve instead, so the run would go on as if nothing had been asked. The
``cape`` command's handlers therefore also record the signal here, and the closed loop calls
``check()`` after every controller step: the interrupt then stops the run at the next step,
whatever the solver did with it.
"""

from __future__ import annotations

requested: list[BaseException] = []
"""The interrupt each signal raised (the command's handlers append it)."""


def check() -> None:
    """Raise the first interrupt asked for, if any."""
    if requested:
        raise requested[0]
