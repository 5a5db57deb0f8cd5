"""One pending wake-up timer in Snakemake's scheduler, not one per pass of its loop.

Snakemake 9.27's ``JobScheduler`` starts a ``threading.Timer`` at the end of every pass while a
job rate limit is set (the default ``100/1s``); each timer's wake-up is another pass, so the
timers never drop and every finished job adds one: 600 to 1 200 threads in one ``snakemake``.
``bound_wakeup_timers`` keeps one timer pending at a time. Why and the measurements:
docs/cluster.md ("What the snakemake process needs"); the reproduction: docs/upstream.md.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

_PATCHED = "_cape_one_wakeup_timer"


def _short_of_threads() -> None:
    """Say once, in one line, that the machine refused a thread."""
    global _SAID
    if not _SAID:
        import resource

        from cape.errors import limit_text

        limit = limit_text(resource.RLIMIT_NPROC)
        print(f"CAPE: the machine refused snakemake a thread (ulimit -u: {limit}); it goes on "
              "without its wake-up timer", file=sys.stderr)  # fmt: skip
        _SAID = True


_SAID = False


def bound_wakeup_timers() -> bool:
    """Make ``JobScheduler._schedule_reevalutation`` start a timer only when none is pending
    (a wake-up within ``delay`` is all it promises). False when this Snakemake has no such
    method (a later version: nothing to bound)."""
    try:
        from snakemake.scheduling.job_scheduler import JobScheduler
    except ImportError:
        return False
    original = getattr(JobScheduler, "_schedule_reevalutation", None)
    if original is None:
        return False
    if getattr(original, _PATCHED, False):
        return True

    def schedule_one(self: Any, delay: float) -> None:
        lock = self.__dict__.setdefault("_cape_timer_lock", threading.Lock())
        with lock:
            if self.__dict__.get("_cape_timer_pending"):
                return  # the pending timer wakes the loop within its own delay
            self._cape_timer_pending = True

        def wake() -> None:
            with lock:
                self._cape_timer_pending = False  # before the wake-up: its pass may set one
            self._open_jobs.release()

        timer = threading.Timer(delay, wake)
        timer.daemon = True
        try:
            timer.start()
        except RuntimeError:  # no thread to be had (ulimit -u): wake at once, never crash
            with lock:
                self._cape_timer_pending = False
            _short_of_threads()
            time.sleep(min(delay, 1.0))  # what the timer would have waited
            self._open_jobs.release()

    setattr(schedule_one, _PATCHED, True)
    JobScheduler._schedule_reevalutation = schedule_one  # type: ignore[method-assign]
    return True
