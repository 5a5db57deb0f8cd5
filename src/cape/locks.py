"""Resuming after an interruption: locks left by a Snakemake process that no longer runs.

Snakemake locks its working directory while it runs and removes the locks when it ends; a run
killed with SIGKILL (or by a power loss, or a lost node) leaves them, and the next run refuses
to start until ``snakemake --unlock``. The README promises that the documented command picks up
where it stopped, so the workflow removes locks that no live Snakemake process holds: on Linux,
no other process whose command line is Snakemake's runs in this directory. Where that cannot be
told (no ``/proc``), the locks stay and Snakemake's own message says what to do.
"""

from __future__ import annotations

import os
from pathlib import Path


def other_snakemake_in(directory: Path) -> bool | None:
    """True if another Snakemake process runs in ``directory``, None if it cannot be told."""
    proc = Path("/proc")
    if not proc.is_dir():
        return None
    me = os.getpid()
    target = directory.resolve()
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            cwd = (entry / "cwd").resolve()
        except OSError:  # gone meanwhile, or not ours to read
            continue
        if cwd == target and any(part.endswith(b"snakemake") for part in cmdline[:2]):
            return True
    return False


def clear_stale_locks(directory: str | Path = ".") -> list[Path]:
    """Remove Snakemake's locks in ``directory`` when no other Snakemake process runs there;
    returns the lock files removed."""
    locks = Path(directory) / ".snakemake" / "locks"
    files = sorted(locks.glob("*.lock")) if locks.is_dir() else []
    if not files or other_snakemake_in(Path(directory)) is not False:
        return []
    for lock in files:
        lock.unlink(missing_ok=True)
    return files
