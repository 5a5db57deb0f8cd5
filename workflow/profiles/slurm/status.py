#!/usr/bin/env python3
"""Say whether one SLURM job is running, succeeded or failed: the SLURM profile's status command.

Snakemake's cluster-generic executor calls ``status.py JOBID`` for every job in flight, once
a round (``seconds-between-status-checks``), and reads one word: ``running``, ``success`` or
``failed``. So that a study with many jobs in flight costs the scheduler one query per round,
not one per job, the user's queue (``squeue``) is read by the round's first call into
``.snakemake/slurm-status.json`` and shared by the calls that follow it within ``ROUND_GAP``
seconds of each other. A job no longer queued is looked up once in ``sacct`` (the accounting
database), or, on a cluster that keeps none, in ``scontrol``. A job that SLURM answers it does
not know is reported failed, with the reason on stderr: it cannot be waited for. A job SLURM
gave no answer about (a busy controller, a timeout) is reported running and asked about again
next round, never given up on.
"""

from __future__ import annotations

import getpass
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from submit import LOG_ROOT  # this folder's submit.py: where SLURM's logs of the jobs go

CACHE = Path(".snakemake") / "slurm-status.json"
JOB_ID = re.compile(r"[0-9]+(_[0-9]+)?")
ROUND_GAP = 1.0  # s: a call later than this after the one before starts a new round
MAX_AGE = 30.0  # s: a snapshot is read again after this long, even within one round
SUCCESS = {"COMPLETED"}
RUNNING = {
    "PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "REQUEUED", "REQUEUE_FED",
    "REQUEUE_HOLD", "RESIZING", "SUSPENDED", "STAGE_OUT", "SIGNALING", "RESV_DEL_HOLD",
    "STOPPED", "POWER_UP_NODE",
}  # fmt: skip
# everything else is failed: FAILED, TIMEOUT, OUT_OF_MEMORY, CANCELLED, NODE_FAIL, PREEMPTED,
# BOOT_FAIL, DEADLINE, REVOKED, SPECIAL_EXIT


def verdict(state: str) -> str:
    """``success``, ``running`` or ``failed`` for a SLURM job state ("CANCELLED by 0" too)."""
    word = state.split()[0].rstrip("+") if state.strip() else ""
    if word in SUCCESS:
        return "success"
    return "running" if word in RUNNING else "failed"


def _run(*command: str) -> subprocess.CompletedProcess[str] | None:
    """The finished command, or None when it could not run (not installed, hung 60 s)."""
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None


def queued(now: float) -> dict[str, str] | None:
    """Job id → state of the user's queued jobs, read once per round of calls; None when
    ``squeue`` gave no answer this round (a busy controller: asked again next round)."""
    gap = float(os.environ.get("CAPE_SLURM_ROUND_GAP", ROUND_GAP))
    try:
        cached = json.loads(CACHE.read_text())
        fresh = now - float(cached["called"]) < gap and now - float(cached["read"]) < MAX_AGE
        jobs, read = cached["jobs"], float(cached["read"])
    except (OSError, ValueError, KeyError, TypeError):
        fresh = False
    if not fresh:
        done = _run("squeue", "-h", "-u", getpass.getuser(), "-o", "%i|%T")
        jobs, read = None, now
        if done is not None and done.returncode == 0:
            jobs = dict(line.split("|", 1) for line in done.stdout.split() if "|" in line)
        elif done is not None:
            print(f"status.py: squeue: {done.stderr.strip()}", file=sys.stderr)
    part = CACHE.with_name(f"{CACHE.name}.{os.getpid()}.part")
    try:  # the cache only saves queries: a folder that will not hold it costs one per call
        CACHE.parent.mkdir(parents=True, exist_ok=True)
        part.write_text(json.dumps({"called": now, "read": read, "jobs": jobs}))
        part.replace(CACHE)  # atomic: a reader never sees half a file
    except OSError:
        part.unlink(missing_ok=True)
    return None if jobs is None else dict(jobs)


def final_state(jobid: str) -> tuple[str | None, bool]:
    """A job's state from the accounting database, else from the controller's memory; and
    whether SLURM answered that it knows no such job (rather than not answering)."""
    done = _run("sacct", "-X", "-n", "-P", "-j", jobid, "-o", "State")
    if done is not None and done.returncode == 0 and done.stdout.strip():
        return done.stdout.strip().splitlines()[0], False
    done = _run("scontrol", "show", "job", "-o", jobid)
    if done is None:
        return None, False
    for field in done.stdout.split():
        if field.startswith("JobState="):
            return field.removeprefix("JobState="), False
    return None, "invalid job id" in done.stderr.lower()


def main(argv: list[str]) -> int:
    jobid = argv[1].strip() if len(argv) == 2 else ""
    if not JOB_ID.fullmatch(jobid):  # an empty id would make scontrol list every job
        print("usage: status.py JOBID (a SLURM job id, as submit.py printed it)", file=sys.stderr)
        return 2
    jobs = queued(time.time())
    state, unknown = (jobs[jobid], False) if jobs and jobid in jobs else final_state(jobid)
    if state is None:
        if jobs is not None and unknown:  # the queue answered without it, and so did scontrol
            print(f"status.py: SLURM knows no job {jobid} (squeue, sacct, scontrol)",
                  file=sys.stderr)  # fmt: skip
            print("failed")
        else:  # no answer: the job is not given up on a busy controller's word
            print(f"status.py: SLURM did not say how job {jobid} is; asking again next round",
                  file=sys.stderr)  # fmt: skip
            print("running")
        return 0
    said = verdict(state)
    if said == "failed":  # why, and where SLURM's own log of the job is
        logs = sorted(str(p) for p in LOG_ROOT.glob(f"*/{jobid}.log"))
        where = f"; its log: {logs[0]}" if logs else ""
        print(f"status.py: SLURM job {jobid} ended {state.strip()}{where}", file=sys.stderr)
    print(said)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
