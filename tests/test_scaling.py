"""More draws and more machines: raising training.replicates plans only the new draws' jobs, and
the SLURM profile puts rollouts in groups of one draw, η and seed (one submission each) with
its submit and status scripts. The real cluster run is tests/cluster/ (``pytest -m cluster``)."""

from __future__ import annotations

import json
import os
import re
import stat
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

import pytest
import yaml
from commands import snakemake
from conftest import workdir

from cape.config import REPO_ROOT
from cape.layout import paths

PROFILE = REPO_ROOT / "workflow" / "profiles" / "slurm"
RULE = re.compile(r"^(\s*)(?:local)?(?:rule|checkpoint) (\w+):")
GROUP = re.compile(r"Group job (\S+) \(jobs")


def planned(out: str) -> tuple[list[tuple[str, dict]], dict[int, list[tuple[str, dict]]]]:
    """The jobs a dry run plans, as (rule, wildcards), and the members of each group job (by
    the order the groups are printed in; several groups may share a name)."""
    jobs: list[tuple[str, dict]] = []
    groups: dict[int, list[tuple[str, dict]]] = defaultdict(list)
    group, count = None, -1
    for line in out.splitlines():
        if GROUP.search(line):
            count += 1
            group = count
        elif line.startswith("[") and "Group job" not in line:
            group = None
        elif match := RULE.match(line):
            if not match.group(1):
                group = None
            jobs.append((match.group(2), {}))
            if group is not None:
                groups[group].append(jobs[-1])
        elif line.strip().startswith("wildcards:") and jobs:
            pairs = line.split("wildcards:", 1)[1].split(",")
            jobs[-1][1].update(p.strip().split("=", 1) for p in pairs if "=" in p)
    return jobs, dict(groups)


def _runs(replicates: range) -> list[str]:
    return [
        f"results/runs/learned/rep{r}/{m}/{m}/{c}/eta0/seed0/metrics.json"
        for r in replicates
        for m in ("dpm", "ddm", "epm")
        for c in ("pid", "nmpc")
    ]


@pytest.mark.slow
def test_raising_replicates_from_3_to_10_plans_only_the_new_draws(tmp_path: Path) -> None:
    """Three draws of every model and their PID and NMPC runs are built; with
    training.replicates raised to 10 (so the default cap, 2R, rises from 6 to 20) the dry run
    plans the seven new draws' trainings, checks, draws, exports and runs, and nothing of the
    first three. Each new draw's training is planned at once (draw r asks training r first),
    so no draw waits for another. Fails where a draw's command carried the configured cap."""
    work = workdir(tmp_path)
    overrides = {
        "models": {m: {"train": {"epochs": 2}} for m in ("dpm", "ddm", "epm")},
        "training": {
            "replicates": 3, "max_trainings": None, "health": {"models": []},
            "compile": {"enabled": False},
        },
        "rollout": {"compile": {"enabled": False}},
        "controllers": {"nmpc": {"compile": {"enabled": False}}},
    }  # fmt: skip
    (work / "config" / "three.yaml").write_text(yaml.safe_dump(overrides))
    (work / "config" / "ten.yaml").write_text(yaml.safe_dump({"training": {"replicates": 10}}))
    built = snakemake(
        "--cores", "2", "-d", str(work), *_runs(range(3)),
        "--configfile", "config/three.yaml", cwd=work, timeout=1200,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]

    dry = snakemake(
        "-n", "--cores", "2", "-d", str(work), *_runs(range(10)),
        "--configfile", "config/three.yaml", "config/ten.yaml", cwd=work,
    )  # fmt: skip
    assert dry.returncode == 0, dry.stdout[-3000:] + dry.stderr[-3000:]
    jobs, _ = planned(dry.stdout)
    counts = Counter(rule for rule, _ in jobs)
    new = 7 * 3  # seven new draws of three models
    assert counts == {
        "train": new, "training_health": new, "draw": new, "export_network": new,
        "rollout": 2 * new,
    }, counts  # fmt: skip
    assert all(int(w["replicate"]) >= 3 for _, w in jobs if "replicate" in w)
    seeds = defaultdict(set)
    for rule, w in jobs:
        if rule == "train":
            seeds[w["model"]].add(int(w["training_seed"]))
    assert seeds == {m: set(range(3, 10)) for m in ("dpm", "ddm", "epm")}


def _profile_dry_run(tmp_path: Path, *configfiles: str) -> str:
    work = workdir(tmp_path)
    for name in configfiles:
        (work / "config" / name).write_text((REPO_ROOT / "config" / name).read_text())
    extra = ["--configfile", *(f"config/{n}" for n in configfiles)] if configfiles else []
    result = snakemake("-n", "-d", str(work), "--workflow-profile", str(PROFILE), *extra, cwd=work)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout


def test_the_slurm_profile_submits_a_draws_runs_at_one_eta_and_seed_together(
    tmp_path: Path,
) -> None:
    """The smoke study through the profile: every rollout is in a group job whose members
    share replicate, η and seed (so no draw waits for another's), 58 rollouts in two
    submissions; each training is one submission with its health check."""
    jobs, groups = planned(_profile_dry_run(tmp_path, "smoke.yaml"))
    rollouts = [w for rule, w in jobs if rule == "rollout"]
    grouped = [m for members in groups.values() for m in members]
    assert len(rollouts) == 58
    rollout_groups = [g for g in groups.values() if {r for r, _ in g} == {"rollout"}]
    assert sum(len(g) for g in rollout_groups) == len(rollouts)
    for members in rollout_groups:
        cells = {(w["replicate"], w["eta"], w["seed"]) for _, w in members}
        assert len(cells) == 1, cells
    assert len(rollout_groups) * 20 <= len(rollouts)
    trainings = [g for g in groups.values() if "train" in {r for r, _ in g}]
    assert len(trainings) == 3
    for members in trainings:
        assert sorted(r for r, _ in members) == ["train", "training_health"]
        assert len({(w["model"], w["training_seed"]) for _, w in members}) == 1
    assert len(grouped) == len(rollouts) + 2 * len(trainings)


def _fake(bin_dir: Path, name: str, script: str) -> None:
    path = bin_dir / name
    path.write_text("#!/bin/sh\n" + script)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


def _script(
    name: str, *args: str, cwd: Path, bin_dir: Path, **env: str
) -> subprocess.CompletedProcess:
    path = f"{bin_dir}{os.pathsep}{os.environ['PATH']}"
    return subprocess.run(
        [sys.executable, str(PROFILE / name), *args],
        cwd=cwd, env={**os.environ, "PATH": path, **env}, capture_output=True, text=True,
        timeout=60,
    )  # fmt: skip


SNAKEMAKE_LINE = (
    "cd /study && python -m snakemake --target-jobs 'rollout:eta=0' --cores 'all' --nolock"
)


def _jobscript(tmp_path: Path, properties: dict) -> Path:
    """A job script as Snakemake's cluster-generic executor writes one."""
    path = tmp_path / "snakejob.sh"
    path.write_text(f"#!/bin/sh\n# properties = {json.dumps(properties)}\n{SNAKEMAKE_LINE}\n")
    return path


def test_submit_turns_a_group_job_into_one_sbatch_call(tmp_path: Path) -> None:
    """A group job of 50 rollouts on 2 lanes: one sbatch with the group's CPUs, memory and
    runtime (one minute more for its Snakemake to start), named after the group, its log in
    the group's folder under results/logs/slurm (made, since sbatch makes none); account and
    partition only when given; the job's Snakemake pinned to the job's CPUs."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    _fake(bin_dir, "sbatch", f'printf "%s\\n" "$@" > {tmp_path}/argv\necho "4242;cape"\n')
    group = {
        "type": "group", "groupid": "rollouts-r0-eta0.5-seed1", "threads": 2,
        "resources": {"mem_mb": 3000, "runtime": 25, "slurm_partition": "short"},
    }  # fmt: skip
    script = _jobscript(tmp_path, group)
    done = _script("submit.py", str(script), cwd=tmp_path, bin_dir=bin_dir)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "4242"
    argv = (tmp_path / "argv").read_text().splitlines()
    assert argv[:2] == ["--parsable", "--job-name=cape-rollouts-r0-eta0.5-seed1"]
    log = f"{paths.log('slurm')}/rollouts-r0-eta0.5-seed1/%j.log"
    assert f"--output={log}" in argv
    assert {"--cpus-per-task=2", "--mem=3000", "--time=26", "--partition=short"} <= set(argv)
    assert not any(a.startswith("--account") for a in argv)
    assert argv[-1] == str(script)
    assert (tmp_path / paths.log("slurm") / "rollouts-r0-eta0.5-seed1").is_dir()
    assert script.read_text().splitlines()[2] == SNAKEMAKE_LINE.replace("'all'", "2")

    # --default-resources on the command line replaces the profile's: no runtime, no memory
    single = {"type": "single", "rule": "train", "threads": 4, "resources": {
        "mem_mb": "<TBD>", "slurm_account": "lab", "slurm_extra": "--exclusive"}}  # fmt: skip
    done = _script("submit.py", str(_jobscript(tmp_path, single)), cwd=tmp_path, bin_dir=bin_dir)
    assert done.returncode == 0, done.stderr
    argv = (tmp_path / "argv").read_text().splitlines()
    assert {"--job-name=cape-train", "--cpus-per-task=4", "--account=lab", "--exclusive"} <= set(
        argv
    )
    assert not any(a.startswith(("--time", "--mem")) for a in argv)
    _fake(bin_dir, "sbatch", 'echo "sbatch: error: invalid partition" >&2\nexit 1\n')
    failed = _script("submit.py", str(_jobscript(tmp_path, single)), cwd=tmp_path, bin_dir=bin_dir)
    assert failed.returncode == 1 and "invalid partition" in failed.stderr
    (tmp_path / "other.sh").write_text("#!/bin/sh\necho not a job script\n")
    other = _script("submit.py", str(tmp_path / "other.sh"), cwd=tmp_path, bin_dir=bin_dir)
    assert other.returncode == 2 and "no '# properties = ' line" in other.stderr


def test_status_reads_the_queue_once_per_round_and_a_finished_job_once(tmp_path: Path) -> None:
    """Queued jobs are running (one squeue for a round of questions); a job no longer
    queued is success or failed by sacct, or by scontrol where sacct has no answer; a job
    SLURM says it does not know is failed, with the reason on stderr, as is a job that ended
    badly (its state and SLURM log named)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls"
    _fake(bin_dir, "squeue", f'echo squeue >> {calls}\necho "11|RUNNING"\necho "12|PENDING"\n')
    _fake(bin_dir, "sacct", f'echo sacct >> {calls}\ncase "$5" in\n'
          '  21) echo COMPLETED ;;\n  22) echo "CANCELLED by 0" ;;\n  23) echo OUT_OF_MEMORY ;;\n'
          "  *) exit 1 ;;\nesac\n")  # fmt: skip
    unknown = 'echo "slurm_load_jobs error: Invalid job id specified" >&2; exit 1'
    _fake(bin_dir, "scontrol", 'case "$4" in\n  31) echo "JobId=31 JobState=TIMEOUT Reason=x" ;;\n'
          f'  32) echo "JobId=32 JobState=COMPLETED" ;;\n  *) {unknown} ;;\nesac\n')  # fmt: skip
    log = tmp_path / paths.log("slurm") / "rollouts-r0-eta0-seed0" / "23.log"
    log.parent.mkdir(parents=True)
    log.write_text("oom-kill event\n")
    expected = {"11": "running", "12": "running", "21": "success", "22": "failed",
                "23": "failed", "31": "failed", "32": "success", "99": "failed"}  # fmt: skip
    one_round = {"CAPE_SLURM_ROUND_GAP": "600"}
    for jobid, verdict in expected.items():
        done = _script("status.py", jobid, cwd=tmp_path, bin_dir=bin_dir, **one_round)
        assert done.returncode == 0 and done.stdout.strip() == verdict, (jobid, done)
        assert bool(done.stderr) == (verdict == "failed"), done.stderr
        if jobid == "23":
            where = log.relative_to(tmp_path)
            said = f"status.py: SLURM job 23 ended OUT_OF_MEMORY; its log: {where}"
            assert done.stderr.strip() == said
    made = calls.read_text().split()
    assert made.count("squeue") == 1  # one round
    assert made.count("sacct") == 6  # the six jobs squeue did not list, once each
    done = _script("status.py", "11", cwd=tmp_path, bin_dir=bin_dir, CAPE_SLURM_ROUND_GAP="0")
    assert done.stdout.strip() == "running"
    assert calls.read_text().split().count("squeue") == 2  # the next round reads it again
    for bad in ("", "12; rm -rf x", "abc"):  # an empty id would make scontrol list every job
        refused = _script("status.py", bad, cwd=tmp_path, bin_dir=bin_dir)
        assert refused.returncode == 2 and refused.stdout == "", refused
        assert len(refused.stderr.splitlines()) == 1 and "usage" in refused.stderr
    (tmp_path / ".snakemake" / "slurm-status.json").unlink()
    (tmp_path / ".snakemake" / "slurm-status.json").mkdir()  # a cache it cannot write
    done = _script("status.py", "11", cwd=tmp_path, bin_dir=bin_dir)
    assert done.returncode == 0 and done.stdout.strip() == "running", done


def test_status_waits_for_a_job_while_slurm_does_not_answer(tmp_path: Path) -> None:
    """A busy controller (squeue and scontrol time out, no accounting): every job is still
    running, asked about again next round (for at most CAPE_SLURM_GIVE_UP_AFTER, default
    10 minutes: tests/test_slurm_scripts.py), and squeue is not asked again within the round."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls"
    busy = 'echo "slurm_load_jobs error: Socket timed out on send/recv operation" >&2\nexit 1\n'
    _fake(bin_dir, "squeue", f"echo squeue >> {calls}\n{busy}")
    _fake(bin_dir, "scontrol", busy)
    _fake(
        bin_dir, "sacct", 'echo "sacct: error: Slurm accounting storage is disabled" >&2\nexit 1\n'
    )
    for jobid in ("11", "12"):
        done = _script(
            "status.py", jobid, cwd=tmp_path, bin_dir=bin_dir, CAPE_SLURM_ROUND_GAP="600"
        )
        assert done.returncode == 0 and done.stdout.strip() == "running", done
        assert "asking again next round" in done.stderr
    assert calls.read_text().split().count("squeue") == 1
