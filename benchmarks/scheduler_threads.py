"""The threads and CPU of the ``snakemake`` process itself, sampled from outside.

Two measurements, each from ``/proc/<pid>/status`` and ``/proc/<pid>/stat`` every 0.2 s:

- ``--toy N`` (default 1500): a workflow of N jobs of 50 ms each, all ready at once, run with
  Snakemake as released and with CAPE's bound (cape/workflow/scheduler.py), side by side;
- ``--study TARGET…``: this folder's workflow (``snakemake --cores 2 TARGET…``), which always
  runs with the bound.

``--nproc N`` runs each ``snakemake`` under ``ulimit -u N`` (RLIMIT_NPROC). That limit binds no
root process: as root, the run goes into a new pids cgroup with ``pids.max`` N instead (every
thread of ``snakemake`` and its jobs counts, as ``ulimit -u`` counts a login node's user's).
Prints, per run: the most and the median threads, the process's own CPU seconds, the wall time
and the exit status.

Each ``snakemake`` runs in a session of its own and is waited for at most ``--timeout`` seconds.
Stopped itself (SIGTERM, as ``timeout`` sends it, or Ctrl-C), or past that bound, the script stops
its ``snakemake`` and every job it started, removes the toy's folder and ends in one line; killed
outright (SIGKILL), it leaves a toy ``snakemake`` no parent (the kernel sends it SIGTERM).

    python benchmarks/scheduler_threads.py [--toy 1500] [--nproc 256] [--study TARGET…]
                                           [--configfile config/smoke.yaml] [--json PATH]
                                           [--timeout 21600]
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from _common import json_output, run

from cape.errors import CapeError
from cape.processes import stop, threads_of

TIMEOUT = 6 * 3600.0  # s: the default bound on one snakemake run (--timeout)
GRACE = 10.0  # s: how long a stopped snakemake gets to end its jobs before it is killed
PR_SET_PDEATHSIG = 1

TOY = """\
{bound}
rule all:
    input: expand("out/{{i}}.txt", i=range({jobs}))

rule one:
    output: "out/{{i}}.txt"
    shell: "sleep 0.05; touch {{output}}"
"""
BOUND = "from cape.workflow.scheduler import bound_wakeup_timers\nbound_wakeup_timers()\n"


@dataclass(frozen=True)
class Sampled:
    """One ``snakemake`` run as seen from outside."""

    label: str
    max_threads: int
    median_threads: float
    cpu_s: float
    wall_s: float
    returncode: int


def _cpu(pid: int) -> float | None:
    """The process's own user + system CPU seconds (not its children's)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _pids_cgroup(limit: int) -> Path | None:
    """A new pids cgroup holding at most ``limit`` tasks (threads count), or None when this
    machine gives none to write (v1's pids hierarchy, or v2 with the pids controller)."""
    for root in (Path("/sys/fs/cgroup/pids"), Path("/sys/fs/cgroup")):
        if not (root / "cgroup.procs").is_file():
            continue
        if root.name != "pids" and "pids" not in (root / "cgroup.subtree_control").read_text():
            continue
        group = root / f"cape-threads-{os.getpid()}"
        try:
            group.mkdir()
            (group / "pids.max").write_text(f"{limit}\n")
        except OSError:
            continue
        return group
    return None


def _limit(nproc: int | None, group: Path | None) -> Callable[[], None]:
    """In the child before exec: SIGTERM when this script dies (Linux's parent-death signal:
    even killed outright, it leaves no snakemake running on its own), and ``ulimit -u nproc``,
    or the pids cgroup for root (whom RLIMIT_NPROC does not bind)."""

    def apply() -> None:
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if nproc is None:
            return
        resource.setrlimit(resource.RLIMIT_NPROC, (nproc, nproc))
        if group is not None:
            (group / "cgroup.procs").write_text(f"{os.getpid()}\n")

    return apply


def _stopped(signum: int, _frame: object) -> None:
    """SIGTERM to this script (``timeout``, a scheduler): raised where it is, so that its
    ``snakemake`` is stopped and its toy folder removed on the way out (``run``: one line, exit
    status 143)."""
    from cape.cli import Interrupted

    raise Interrupted(signum)


def sample(
    label: str,
    command: Sequence[str],
    cwd: Path,
    nproc: int | None,
    log: Path,
    timeout: float = TIMEOUT,
) -> Sampled:
    """Run ``command`` in ``cwd`` and sample its process until it ends; stopped (with what it
    started) past ``timeout`` s, or when this script is stopped."""
    threads: list[int] = []
    cpu = 0.0
    start = time.monotonic()
    group = None
    if nproc is not None and os.geteuid() == 0:
        group = _pids_cgroup(nproc)
        if group is None:
            raise CapeError(
                "--nproc as root needs a writable pids cgroup (RLIMIT_NPROC binds no root "
                "process); run as another user, or without --nproc"
            )
    try:
        with log.open("w") as out:
            proc = subprocess.Popen(
                command,
                cwd=cwd,
                stdout=out,
                stderr=subprocess.STDOUT,
                preexec_fn=_limit(nproc, group),
                start_new_session=True,  # stopped as a whole, by this script alone
            )
            try:
                while proc.poll() is None:
                    if time.monotonic() - start > timeout:
                        raise CapeError(
                            f"{label}: snakemake had not ended after --timeout {timeout:g} s, so "
                            f"it was stopped (its log: {log})"
                        )
                    n, c = threads_of(proc.pid), _cpu(proc.pid)
                    if n is not None:
                        threads.append(n)
                    if c is not None:
                        cpu = c
                    time.sleep(0.2)
            except BaseException:  # stopped, or past --timeout: snakemake and its jobs with it
                stop(proc, GRACE)
                raise
    finally:
        if group is not None:
            with contextlib.suppress(OSError):
                group.rmdir()
    wall = time.monotonic() - start
    return Sampled(
        label,
        max(threads, default=0),
        statistics.median(threads) if threads else 0.0,
        round(cpu, 2),
        round(wall, 1),
        proc.returncode,
    )


def toy(jobs: int, nproc: int | None, timeout: float = TIMEOUT) -> list[Sampled]:
    """The toy workflow, as released and bounded, each in a folder removed after it (stopped
    or not)."""
    results = []
    for label, bound in (("snakemake as released", ""), ("with CAPE's bound", BOUND)):
        with tempfile.TemporaryDirectory(prefix="cape-threads-") as tmp:
            folder = Path(tmp)
            (folder / "Snakefile").write_text(TOY.format(bound=bound, jobs=jobs))
            command = [sys.executable, "-m", "snakemake", "--cores", "2", "--quiet", "all"]
            label = f"toy, {jobs} jobs, {label}"
            result = sample(label, command, folder, nproc, folder / "log", timeout)
            if result.returncode != 0:
                print((folder / "log").read_text()[-2000:], file=sys.stderr)
            results.append(result)
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--toy", type=int, default=1500, metavar="N",
                        help="jobs of the toy workflow (0: no toy run; default 1500)")  # fmt: skip
    parser.add_argument("--study", nargs="+", metavar="TARGET", default=[],
                        help="also run this folder's workflow for these targets")  # fmt: skip
    parser.add_argument("--configfile", action="append", default=[])
    parser.add_argument("--nproc", type=int, help="RLIMIT_NPROC of each snakemake (ulimit -u)")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--timeout", type=float, default=TIMEOUT, metavar="S",
                        help="stop a snakemake run after S s (default %(default)g)")  # fmt: skip
    args = parser.parse_args()
    if not 1 <= args.timeout <= 30 * 86400:  # NaN too
        parser.error("--timeout: give 1 to 2592000 seconds")
    signal.signal(signal.SIGTERM, _stopped)  # Ctrl-C is KeyboardInterrupt: stopped the same way
    if not 0 <= args.toy <= 100_000:
        parser.error("--toy: give 0 to 100000 jobs")
    if args.nproc is not None and not 16 <= args.nproc <= 1_000_000:
        parser.error("--nproc: give 16 to 1000000")
    if shutil.which("snakemake") is None:
        parser.error("snakemake is not on PATH: activate the environment of requirements.txt")
    with json_output(args.json, "scheduler_threads") as write:
        results = toy(args.toy, args.nproc, args.timeout) if args.toy else []
        if args.study:
            command = ["snakemake", "--cores", "2", *args.study]  # targets before the options
            for configfile in args.configfile:
                command += ["--configfile", configfile]
            log = Path(tempfile.mkstemp(prefix="cape-threads-", suffix=".log")[1])
            label = f"CAPE workflow: {' '.join(args.study)}"
            results.append(sample(label, command, Path.cwd(), args.nproc, log, args.timeout))
            print(f"(its log: {log})")
        limit = f"ulimit -u {args.nproc}" if args.nproc else "no thread limit"
        print(f"snakemake's own process, sampled every 0.2 s ({limit}):")
        for r in results:
            print(f"  {r.label}: threads max {r.max_threads}, median {r.median_threads:g}; "
                  f"CPU {r.cpu_s:.1f} s in {r.wall_s:.0f} s; exit {r.returncode}")  # fmt: skip
        write({"nproc": args.nproc, "runs": [asdict(r) for r in results]})
        return 0 if all(r.returncode == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(run(main))
