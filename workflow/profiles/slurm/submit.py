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
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

LOG_ROOT = Path("results") / "logs" / "slurm"  # cape.layout.paths.log("slurm"), checked by a test
START_MINUTES = 1  # the job's own Snakemake: parsing the workflow before the first rule
ALL_CORES = re.compile(r"--cores '?all'?(?=\s)")
OPTIONAL = {
    "slurm_account": "--account",
    "slurm_partition": "--partition",
    "slurm_qos": "--qos",
    "slurm_constraint": "--constraint",
}


def properties(jobscript: Path) -> dict[str, Any]:
    """The job's properties, from the ``# properties = {...}`` line Snakemake writes."""
    for line in jobscript.read_text().splitlines()[:5]:
        if line.startswith("# properties = "):
            return json.loads(line.removeprefix("# properties = "))
    raise ValueError(f"{jobscript}: no '# properties = ' line (not a Snakemake job script?)")


def job_name(props: dict[str, Any]) -> str:
    """The group's name for a group job, else the rule's."""
    return str(props.get("groupid") if props.get("type") == "group" else props.get("rule"))


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
        command += shlex.split(str(extra))
    return [*command, str(jobscript)]


def cpus(props: dict[str, Any]) -> int:
    return max(1, _whole(props.get("threads")) or 1)


def pin_cores(jobscript: Path, count: int) -> None:
    """Have the job script's Snakemake use ``count`` cores, not all the node shows."""
    text = jobscript.read_text()
    if not ALL_CORES.search(text):
        raise ValueError(f"{jobscript}: no `--cores all` in its Snakemake command to pin")
    jobscript.write_text(ALL_CORES.sub(f"--cores {count}", text, count=1))


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: submit.py JOBSCRIPT", file=sys.stderr)
        return 2
    jobscript = Path(argv[1])
    try:
        props = properties(jobscript)
        pin_cores(jobscript, cpus(props))
    except (OSError, ValueError) as exc:
        print(f"submit.py: {exc}", file=sys.stderr)
        return 2
    (LOG_ROOT / job_name(props)).mkdir(parents=True, exist_ok=True)  # sbatch makes no folders
    done = subprocess.run(sbatch_command(props, jobscript), capture_output=True, text=True)
    if done.returncode != 0:
        print(f"sbatch failed ({done.returncode}): {done.stderr.strip()}", file=sys.stderr)
        return done.returncode
    print(done.stdout.strip().split(";")[0])  # --parsable: "jobid" or "jobid;cluster"
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
