"""Resuming after an interruption: Snakemake locks that provably belong to no living run.

Every main Snakemake process of this workflow records itself (``.snakemake/cape-runs/*.json``:
host, boot, PID namespace, PID and start time) before Snakemake takes its locks, and removes the
record when it exits. Locks are removed only when every record is provably dead, at least one
exists, and no Snakemake process of this PID namespace works in this directory. Otherwise they
stay, with a message that says how to remove them by hand. Why, and what cannot be proven:
docs/modules.md.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import socket
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

RECORDS = Path(".snakemake") / "cape-runs"
LOCKS = Path(".snakemake") / "locks"
HAND_REMOVAL = (
    "if no snakemake works in this folder on any machine, remove them with "
    "`snakemake --unlock` and start again"
)


@dataclass(frozen=True)
class Process:
    """Who a process is, in terms that survive PID reuse and tell hosts and namespaces apart."""

    host: str
    boot: str
    pid_namespace: str
    pid: int
    started: int  # clock ticks after boot (/proc/<pid>/stat, field 22)

    @classmethod
    def me(cls) -> Process | None:
        """This process, or None where it cannot be told (no /proc)."""
        started = _start_time(os.getpid())
        try:
            boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
            namespace = os.readlink("/proc/self/ns/pid")
        except OSError:
            return None
        if started is None:
            return None
        return cls(socket.gethostname(), boot, namespace, os.getpid(), started)

    def alive(self, here: Process | None) -> bool | None:
        """True or False when ``here`` (this process) can tell; None when it cannot: another
        host, boot or PID namespace, or no /proc."""
        if here is None or (self.host, self.boot, self.pid_namespace) != (
            here.host,
            here.boot,
            here.pid_namespace,
        ):
            return None
        return _start_time(self.pid) == self.started

    def describe(self) -> str:
        return f"PID {self.pid} on {self.host}"


def _start_time(pid: int) -> int | None:
    """A process's start time in clock ticks after boot, or None if there is no such process."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may hold spaces: split after it
    return int(stat[stat.rindex(")") + 2 :].split()[19])


def record_this_run(directory: str | Path = ".") -> Path | None:
    """Leave a record of this process in ``directory`` (removed when the process exits), so a
    later run can prove whether the locks it finds were this one's. None where no record can
    be made (no /proc)."""
    me = Process.me()
    if me is None:
        return None
    folder = Path(directory) / RECORDS
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{me.host}-{me.pid}-{me.started}.json"
    body = {**asdict(me), "written": time.time(), "cwd": str(Path.cwd())}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(body, indent=2) + "\n")
    os.replace(tmp, path)
    atexit.register(lambda: path.unlink(missing_ok=True))
    return path


def _records(directory: Path) -> list[tuple[Path, Process | None]]:
    out = []
    for path in sorted((directory / RECORDS).glob("*.json")):
        try:
            body = json.loads(path.read_text())
            out.append((path, Process(**{k: body[k] for k in Process.__dataclass_fields__})))
        except (OSError, ValueError, KeyError, TypeError):
            out.append((path, None))  # unreadable: it proves nothing
    return out


def snakemake_working_in(directory: Path) -> list[int]:
    """PIDs of other processes of this PID namespace that run Snakemake (``snakemake …`` or
    ``python -m snakemake …``) with ``directory`` as their working directory."""
    me, target, found = os.getpid(), directory.resolve(), []
    with contextlib.suppress(OSError):
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit() or int(entry.name) == me:
                continue
            try:
                cmdline = (entry / "cmdline").read_bytes().split(b"\0")
                cwd = (entry / "cwd").resolve()
            except OSError:  # gone meanwhile, or not ours to read
                continue
            names = {Path(part.decode(errors="replace")).name for part in cmdline[:4]}
            if cwd == target and "snakemake" in names:
                found.append(int(entry.name))
    return found


def clear_stale_locks(
    directory: str | Path = ".", report: Callable[[str], None] = lambda _message: None
) -> list[Path]:
    """Remove Snakemake's locks in ``directory`` if they provably belong to no living run, then
    record this process (see the module's docstring); ``report`` receives what was done or
    why not. Returns the lock files removed."""
    directory = Path(directory)
    locks = sorted((directory / LOCKS).glob("*.lock")) if (directory / LOCKS).is_dir() else []
    here = Process.me()
    records = _records(directory)
    verdicts = [(path, proc, proc.alive(here) if proc is not None else None)
                for path, proc in records]  # fmt: skip
    removed: list[Path] = []
    if locks:
        living = [proc.describe() for _, proc, alive in verdicts if alive and proc is not None]
        unknown = [path.name for path, _, alive in verdicts if alive is None]
        others = snakemake_working_in(directory) if here is not None else []
        if living or others:
            who = ", ".join(living + [f"PID {pid}" for pid in others if f"PID {pid}" not in
                                      " ".join(living)])  # fmt: skip
            report(f"Snakemake's locks in {directory / LOCKS} are left in place: a snakemake run "
                   f"works in this folder ({who}); {HAND_REMOVAL}")  # fmt: skip
        elif unknown:
            report(f"Snakemake's locks in {directory / LOCKS} are left in place: they may belong "
                   f"to a run this machine cannot see (another host or PID namespace: "
                   f"{', '.join(unknown)} in {directory / RECORDS}); {HAND_REMOVAL}")  # fmt: skip
        elif not records:
            report(f"Snakemake's locks in {directory / LOCKS} are left in place: no record says "
                   f"which run wrote them; {HAND_REMOVAL}")  # fmt: skip
        else:  # every record is of a run on this machine that has ended
            for lock in locks:
                lock.unlink(missing_ok=True)
                removed.append(lock)
            report(f"removed Snakemake's locks ({', '.join(p.name for p in locks)}), left by an "
                   "interrupted run that has ended; resuming")  # fmt: skip
    if removed or not locks:  # records of ended runs: evidence while their locks may stand
        for path, _, alive in verdicts:
            if alive is False:
                path.unlink(missing_ok=True)
    record_this_run(directory)
    return removed
