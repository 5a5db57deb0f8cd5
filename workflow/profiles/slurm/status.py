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
next round, for at most ``GIVE_UP_AFTER`` seconds from the first call without an answer (kept
in the cache); then it is reported failed, with the reason, as it is at once when SLURM's
commands are not installed. Whatever goes wrong, stderr gets at most one line.
"""

from __future__ import annotations

import contextlib
import getpass
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

# this folder's submit.py: where SLURM's logs of the jobs go, and its helpers
from submit import LOG_ROOT, ON_PATH, guarded, one_line

CACHE = Path(".snakemake") / "slurm-status.json"
JOB_ID = re.compile(r"[0-9]+(_[0-9]+)?")
ROUND_GAP = 1.0  # s: a call later than this after the one before starts a new round
MAX_AGE = 30.0  # s: a snapshot is read again after this long, even within one round
GIVE_UP_AFTER = 600.0  # s: a job SLURM says nothing about for this long is failed
TIMEOUT = 60  # s: a SLURM command that has not answered by then has not answered
SETTINGS = {"CAPE_SLURM_ROUND_GAP": ROUND_GAP, "CAPE_SLURM_GIVE_UP_AFTER": GIVE_UP_AFTER}
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


def setting(name: str) -> float:
    """Seconds from the environment variable ``name`` (one of SETTINGS), else its default."""
    raw = os.environ.get(name, "").strip()
    if not raw:
        return SETTINGS[name]
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name}={raw!r} is not a number of seconds >= 0: unset it or give one")
    return value


def _run(*command: str) -> subprocess.CompletedProcess[str] | str:
    """The finished command, or why it did not finish (not installed, hung TIMEOUT s)."""
    if shutil.which(command[0]) is None:
        return f"no {command[0]} on PATH"
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return f"{command[0]}: no answer in {TIMEOUT} s"
    except OSError as exc:
        return f"{command[0]}: {exc}"


def _time(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _states(jobs: object) -> bool:
    return isinstance(jobs, dict) and all(isinstance(state, str) for state in jobs.values())


def _valid(cache: Any) -> bool:
    """Whether ``cache`` is one as ``main`` writes it (a hand-edited one may not be)."""
    if not isinstance(cache, dict) or not all(_time(cache.get(k)) for k in ("called", "read")):
        return False
    jobs, unanswered = cache.get("jobs", 0), cache.get("unanswered", {})
    return (
        (jobs is None or _states(jobs))
        and isinstance(cache.get("why", ""), str)
        and isinstance(unanswered, dict)
        and all(_time(v) for v in unanswered.values())
    )


def load() -> tuple[dict[str, Any], str]:
    """The cache ({} when there is none), and a warning when a corrupt one was ignored."""
    try:
        cache = json.loads(CACHE.read_text())
    except OSError:  # none yet, or unreadable (then writing it fails too, and says so)
        return {}, ""
    except ValueError:  # not JSON, not text
        cache = None
    if _valid(cache):
        return cache, ""
    return {}, f"ignored a corrupt {CACHE} (written anew)"


def save(cache: dict[str, Any]) -> str:
    """Write the cache atomically; a warning when it cannot be kept."""
    part = CACHE.with_name(f"{CACHE.name}.{os.getpid()}.part")
    try:
        CACHE.parent.mkdir(parents=True, exist_ok=True)
        part.write_text(json.dumps(cache))
        part.replace(CACHE)  # atomic: a reader never sees half a file
    except OSError as exc:
        # The cache only saves queries: without it (say `.snakemake` is a file) every call
        # asks squeue itself and the study goes on; only SLURM's silence about a job is not
        # timed across calls then (each call waits for it anew, within GIVE_UP_AFTER).
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)
        why = f"{exc.strerror}: {exc.filename}" if exc.strerror and exc.filename else exc
        return f"cannot keep {CACHE} ({why}): squeue is asked every call"
    return ""


def queued() -> tuple[dict[str, str] | None, str]:
    """Job id → state of the user's queued jobs; None, and why, when squeue gave no answer."""
    try:
        user = getpass.getuser()
    except (OSError, KeyError):  # no name for this uid: squeue takes the number
        user = str(os.getuid())
    done = _run("squeue", "-h", "-u", user, "-o", "%i|%T")
    if isinstance(done, str):
        return None, done
    if done.returncode != 0:
        return None, f"squeue: {one_line(done.stderr) or f'exit {done.returncode}'}"
    return dict(line.split("|", 1) for line in done.stdout.split() if "|" in line), ""


def final_state(jobid: str) -> tuple[str | None, bool, list[str]]:
    """A job's state from the accounting database, else from the controller's memory; whether
    SLURM answered that it knows no such job (rather than not answering); and, without a
    state, why each command gave none."""
    why = []
    done = _run("sacct", "-X", "-n", "-P", "-j", jobid, "-o", "State")
    if isinstance(done, str):
        why.append(done)
    elif done.returncode == 0 and done.stdout.strip():
        return done.stdout.strip().splitlines()[0], False, []
    else:
        why.append(f"sacct: {one_line(done.stderr) or 'no record of the job'}")
    done = _run("scontrol", "show", "job", "-o", jobid)
    if isinstance(done, str):
        return None, False, [*why, done]
    for field in done.stdout.split():
        if field.startswith("JobState="):
            return field.removeprefix("JobState="), False, []
    said = one_line(done.stderr) or "no JobState"
    return None, "invalid job id" in done.stderr.lower(), [*why, f"scontrol: {said}"]


def judge(
    jobid: str,
    jobs: dict[str, str] | None,
    squeue_why: str,
    unanswered: dict[str, float],
    now: float,
    limit: float,
) -> tuple[str, str]:
    """The verdict on one job and the line of stderr that explains it ("" for none); updates
    ``unanswered`` (job id → the first call that got no answer about it)."""
    if jobs is not None and jobid in jobs:
        state, unknown, why = jobs[jobid], False, []
    else:
        state, unknown, why = final_state(jobid)
    if state is not None:
        unanswered.pop(jobid, None)
        said = verdict(state)
        if said != "failed":
            return said, ""
        try:  # why, and where SLURM's own log of the job is
            logs = sorted(str(p) for p in LOG_ROOT.glob(f"*/{jobid}.log"))
        except OSError:
            logs = []
        where = f"; its log: {logs[0]}" if logs else ""
        return "failed", f"SLURM job {jobid} ended {state.strip()}{where}"
    if jobs is not None and unknown:  # the queue answered without it, and so did scontrol
        unanswered.pop(jobid, None)
        return "failed", f"SLURM knows no job {jobid} (squeue, sacct, scontrol)"
    asked = ["sacct", "scontrol"] if jobs is not None else ["squeue", "sacct", "scontrol"]
    reasons = "; ".join(why if jobs is not None else [squeue_why, *why])
    if all(shutil.which(name) is None for name in asked):
        # Nothing could be asked: a command that is not installed does not appear by itself
        # during the run, so waiting GIVE_UP_AFTER for it would only delay the verdict.
        unanswered.pop(jobid, None)
        missing = f"{', '.join(asked[:-1])} or {asked[-1]}"
        return "failed", f"cannot tell how SLURM job {jobid} is: no {missing} on PATH; {ON_PATH}"
    first = min(unanswered.setdefault(jobid, now), now)  # a time ahead of now: from now
    unanswered[jobid] = first
    waited = now - first
    if waited < limit:
        return "running", (
            f"SLURM did not say how job {jobid} is ({reasons}); asking again next round "
            f"(waited {waited:.0f} of CAPE_SLURM_GIVE_UP_AFTER={limit:g} s)"
        )
    unanswered.pop(jobid)
    return "failed", (
        f"SLURM has not said how job {jobid} is for {waited:.0f} s ({reasons}): given up after "
        f"CAPE_SLURM_GIVE_UP_AFTER={limit:g} s; if `squeue` shows it still, `scancel {jobid}` "
        "it before rerunning snakemake"
    )


def main(argv: list[str]) -> int:
    jobid = argv[1].strip() if len(argv) == 2 else ""
    if not JOB_ID.fullmatch(jobid):  # an empty id would make scontrol list every job
        print("usage: status.py JOBID (a SLURM job id, as submit.py printed it)", file=sys.stderr)
        return 2
    try:
        gap, limit = setting("CAPE_SLURM_ROUND_GAP"), setting("CAPE_SLURM_GIVE_UP_AFTER")
    except ValueError as exc:
        print(f"status.py: {exc}", file=sys.stderr)
        return 2
    now = time.time()
    cache, warning = load()
    # fresh: read within this round (and not dated ahead of now by a clock or a hand)
    fresh = bool(cache) and 0 <= now - cache["called"] < gap and 0 <= now - cache["read"] < MAX_AGE
    if fresh:
        jobs, why, read = cache["jobs"], cache.get("why", ""), cache["read"]
    else:
        (jobs, why), read = queued(), now
    unanswered = dict(cache.get("unanswered", {}))
    said, line = judge(jobid, jobs, why, unanswered, now, limit)
    record = {"called": now, "read": read, "jobs": jobs, "why": why, "unanswered": unanswered}
    lines = [text for text in (line, warning, save(record)) if text]
    if lines:
        print(f"status.py: {'; '.join(lines)}", file=sys.stderr)
    print(said)
    return 0


if __name__ == "__main__":
    sys.exit(guarded("status.py", main, sys.argv))
