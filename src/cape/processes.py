"""Operating-system processes, through Linux's /proc: running a command with its output logged
(``run_logged``, how `cape question` runs Snakemake), stopping a process and every job it started
(``stop``, for that Snakemake and the benchmarks'), and what the tests and benchmarks measure
from outside a process (``threads_of``)."""

from __future__ import annotations

import contextlib
import os
import shlex
import signal
import subprocess
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path


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


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (its children, theirs, …), from /proc; [] where there is
    no /proc."""
    parents: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()  # the name may hold ")"
            parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, ended and not yet reaped, does not)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


def _send(pids: Iterable[int], group: int, sig: int) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, sig)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(group, sig)


def stop(proc: subprocess.Popen, grace: float) -> None:
    """Stop ``proc`` (started in a session of its own: ``start_new_session=True``) and every
    process below it: SIGTERM, then SIGKILL to whatever still runs after ``grace`` seconds;
    returns once ``proc`` has ended. A job writes atomically, so what it had not finished is
    simply missing, and the next run redoes it."""
    jobs = set(descendants(proc.pid))  # before proc ends and they are reparented
    _send(jobs, proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=grace)
    while any(_alive(pid) for pid in jobs) and time.monotonic() < deadline:
        time.sleep(0.1)
    if proc.poll() is None or any(_alive(pid) for pid in jobs):
        jobs |= set(descendants(proc.pid))
        _send([pid for pid in jobs if _alive(pid)], proc.pid, signal.SIGKILL)
        proc.wait()


def run_logged(cmd: Sequence[str], log: Path, seen: Callable[[str], None], grace: float) -> int:
    """Run ``cmd`` in a session of its own, its output appended to ``log`` line by line (after
    a line with the time and the command, so that a rerun keeps the earlier attempts and
    ``tail -f`` follows it) and each line handed to ``seen``; its exit status. Stopped
    (SIGTERM, Ctrl-C), it stops ``cmd`` and every job it started (``stop``) and raises on."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a", buffering=1) as out:
        out.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')}\n$ " + shlex.join(cmd) + "\n")
        out.flush()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # its progress as it happens, not at exit
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            env=env,
            start_new_session=True,
        )
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                out.write(line)
                seen(line)
            return proc.wait()
        except BaseException:  # stopped: the command and its jobs with it; a rerun resumes
            stop(proc, grace=grace)
            raise
