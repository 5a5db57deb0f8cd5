"""Helpers about operating-system processes, read through Linux's /proc: what the tests and
benchmarks measure from outside a process."""

from __future__ import annotations


def threads_of(pid: int) -> int | None:
    """The thread count of process ``pid`` (Linux's /proc), None when it cannot be read: how
    the bound on Snakemake's wake-up timers is measured from outside
    (benchmarks/scheduler_threads.py, the slow tests; cape/workflow/scheduler.py)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None
