#!/usr/bin/env python3
"""Submit one Snakemake job script to SLURM: the SLURM profile's submit command.

Snakemake's cluster-generic executor calls ``submit.py JOBSCRIPT``; the job script's second
line holds the job's properties (JSON). This turns them into one ``sbatch`` call and prints
the SLURM job id. Resources read (each optional; without ``runtime`` or ``mem_mb``, which the
profile's ``default-resources`` give every job, the cluster's defaults apply):

  runtime (minutes; one more is asked for the job's own Snakemake to start), mem_mb, threads
  (a group job: the CPUs its widest layer uses), slurm_account, slurm_partition, slurm_qos,
  slurm_constraint, slurm_extra (more sbatch options, one string).

The job script's Snakemake is given the job's CPUs (``--cores <threads>``, not ``all``), so a
group runs as many rollouts at once as it asked CPUs for, whatever the node shows. A group job
(many rollouts) is one submission named after its group; its SLURM log goes to
``results/logs/slurm/<group or rule>/<slurm job id>.log``.

A rule or group name is used in the log's path only as a safe folder name (any character but
letters, digits, ``_``, ``-`` and ``.`` becomes ``_``, and a name of dots is not ``.`` or ``..``),
so the log always lands inside ``results/logs/slurm``.

Every input (``sbatch`` on PATH, the properties, the resources, ``CAPE_SLURM_SUBMIT_TIMEOUT``) is
checked before any file is changed; a bad one ends the script with one line on stderr and exit 2.
An ``sbatch`` that has not answered within ``CAPE_SLURM_SUBMIT_TIMEOUT`` seconds (default 60, as
status.py waits for SLURM's commands) is stopped, and the job reported not submitted in one line.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

LOG_ROOT = Path("results") / "logs" / "slurm"  # cape.layout.paths.log("slurm"), checked by a test
START_MINUTES = 1  # the job's own Snakemake: parsing the workflow before the first rule
ALL_CORES = re.compile(r"--cores '?all'?(?=\s)")
JOB_ID = re.compile(r"[0-9]+(_[0-9]+)?")
UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")  # what a log folder's name may not hold (/, %, …)
SUBMIT_TIMEOUT = 60.0  # s: an sbatch that has not answered by then has not answered
TIMEOUT_SETTING = "CAPE_SLURM_SUBMIT_TIMEOUT"
ON_PATH = (
    "run snakemake on the cluster's login node, where SLURM's commands are, or add them to PATH"
)
OPTIONAL = {
    "slurm_account": "--account",
    "slurm_partition": "--partition",
    "slurm_qos": "--qos",
    "slurm_constraint": "--constraint",
}


def one_line(text: str) -> str:
    """A command's (perhaps multi-line) message as one line."""
    return " ".join(text.split())


def properties(text: str, jobscript: Path) -> dict[str, Any]:
    """The job's properties, from the ``# properties = {...}`` line Snakemake writes."""
    for line in text.splitlines()[:5]:
        if line.startswith("# properties = "):
            props = json.loads(line.removeprefix("# properties = "))
            if not isinstance(props, dict):
                raise ValueError(f"{jobscript}: its properties are not a JSON object")
            if not isinstance(props.get("resources", {}), dict):
                raise ValueError(f"{jobscript}: its properties' resources are not a JSON object")
            if not str(props.get("groupid" if props.get("type") == "group" else "rule") or ""):
                raise ValueError(f"{jobscript}: its properties name no rule (or group)")
            return props
    raise ValueError(f"{jobscript}: no '# properties = ' line (not a Snakemake job script?)")


def job_name(props: dict[str, Any]) -> str:
    """The group's name for a group job, else the rule's, as one safe folder name: never a
    path out of ``LOG_ROOT`` (``../``), nor a pattern sbatch would expand (``%``)."""
    raw = str(props.get("groupid") if props.get("type") == "group" else props.get("rule"))
    name = UNSAFE.sub("_", raw)
    return name.replace(".", "_") if not name.strip(".") else name


def submit_timeout() -> float:
    """Seconds ``sbatch`` may take (``CAPE_SLURM_SUBMIT_TIMEOUT``, else ``SUBMIT_TIMEOUT``)."""
    raw = os.environ.get(TIMEOUT_SETTING, "").strip()
    if not raw:
        return SUBMIT_TIMEOUT
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{TIMEOUT_SETTING}={raw!r} is not a number of seconds > 0: unset it "
                         "or give one")  # fmt: skip
    return value


def _whole(value: Any) -> int | None:
    """A resource as a whole number, or None (missing, or Snakemake's "<TBD>")."""
    try:
        return int(value)
    except (TypeError, ValueError, OverflowError):
        return None


def sbatch_command(props: dict[str, Any], jobscript: Path) -> list[str]:
    """The ``sbatch`` call for one job (or group job) of the given properties."""
    resources = props.get("resources", {})
    name = job_name(props)
    command = [
        "sbatch",
        "--parsable",
        f"--job-name=cape-{name}",
        f"--output={LOG_ROOT / name / '%j.log'}",
        f"--cpus-per-task={cpus(props)}",
    ]
    if (memory := _whole(resources.get("mem_mb"))) is not None:
        command.append(f"--mem={memory}")
    if (minutes := _whole(resources.get("runtime"))) is not None:
        command.append(f"--time={max(1, minutes) + START_MINUTES}")
    for key, option in OPTIONAL.items():
        value = resources.get(key)
        if value not in (None, ""):
            command.append(f"{option}={value}")
    extra = resources.get("slurm_extra")
    if extra:
        try:
            command += shlex.split(str(extra))
        except ValueError as exc:  # "No closing quotation", "No escaped character"
            raise ValueError(
                f"resource slurm_extra={str(extra)!r} is not a list of sbatch options "
                f"({str(exc).lower()}): balance its quotes (or escape them with \\) in the "
                "profile's set-resources or in --set-resources"
            ) from None
    return [*command, str(jobscript)]


def cpus(props: dict[str, Any]) -> int:
    return max(1, _whole(props.get("threads")) or 1)


def pin_cores(text: str, count: int, jobscript: Path) -> str:
    """The job script with its Snakemake using ``count`` cores, not all the node shows."""
    if not ALL_CORES.search(text):
        raise ValueError(f"{jobscript}: no `--cores all` in its Snakemake command to pin")
    return ALL_CORES.sub(f"--cores {count}", text, count=1)


def _run(command: list[str], timeout: float) -> subprocess.CompletedProcess[str] | None:
    """``command``, finished; None when it had not within ``timeout`` s (then it, and whatever
    it started, is killed: its own session)."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.communicate(timeout=5)
        return None
    return subprocess.CompletedProcess(command, proc.returncode, out, err)


def _submit(command: list[str], timeout: float, name: str) -> tuple[str, tuple[int, str] | None]:
    """The job id sbatch printed, or the exit code and the line that say why there is none."""
    done = _run(command, timeout)
    if done is None:
        return "", (1, f"sbatch gave no answer in {timeout:g} s ({TIMEOUT_SETTING}), so it was "
                       "stopped and the job counts as not submitted; if `squeue --me --name "
                       f"cape-{name}` shows it queued all the same, `scancel` it before rerunning "
                       "snakemake")  # fmt: skip
    if done.returncode != 0:
        said = one_line(done.stderr) or one_line(done.stdout)
        return "", (max(done.returncode, 1), f"sbatch failed ({done.returncode}): {said}")
    jobid = done.stdout.strip().split(";")[0]  # --parsable: "jobid" or "jobid;cluster"
    if not JOB_ID.fullmatch(jobid):
        said = one_line(done.stdout) or "nothing"
        return "", (1, f"sbatch printed no job id (it printed {said!r})")
    return jobid, None


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: submit.py JOBSCRIPT", file=sys.stderr)
        return 2
    jobscript = Path(argv[1])
    try:  # every check first: a refused job leaves no file changed
        if shutil.which("sbatch") is None:
            raise ValueError(f"no `sbatch` on PATH to submit {jobscript} with: {ON_PATH}")
        timeout = submit_timeout()
        text = jobscript.read_text()
        props = properties(text, jobscript)
        command = sbatch_command(props, jobscript)
        pinned = pin_cores(text, cpus(props), jobscript)
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError too
        print(f"submit.py: {one_line(str(exc))}", file=sys.stderr)
        return 2
    try:
        (LOG_ROOT / job_name(props)).mkdir(parents=True, exist_ok=True)  # sbatch makes none
        jobscript.write_text(pinned)
        jobid, error = _submit(command, timeout, job_name(props))
    except OSError as exc:
        jobid, error = "", (1, one_line(str(exc)))
    if error:  # not submitted: the job script as it was (sbatch copied it if it queued one)
        with contextlib.suppress(OSError):
            jobscript.write_text(text)
        print(f"submit.py: {error[1]}", file=sys.stderr)
        return error[0]
    print(jobid)
    return 0


def guarded(script: str, main_: Callable[[list[str]], int], argv: list[str]) -> int:
    """``main_(argv)``; a bug still ends in one line on stderr (where it is), not a traceback."""
    try:
        return main_(argv)
    except Exception as exc:
        where = traceback.extract_tb(exc.__traceback__)[-1]
        place = f"{Path(where.filename).name} line {where.lineno}"
        print(f"{script}: internal error {type(exc).__name__} ({place}): {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(guarded("submit.py", main, sys.argv))
