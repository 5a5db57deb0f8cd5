"""The SLURM profile's submit.py and status.py on bad input: one line on stderr and no
traceback, nothing changed before the inputs are checked, and a job reported failed, with the
reason, once SLURM's commands are missing or keep failing. The scripts run as Snakemake runs
them, with PATH holding only fake SLURM commands."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cape.config import REPO_ROOT

PROFILE = REPO_ROOT / "workflow" / "profiles" / "slurm"
CACHE = Path(".snakemake") / "slurm-status.json"
SNAKEMAKE_LINE = "cd /study && python -m snakemake --target-jobs 'rollout:eta=0' --cores 'all'"
BUSY = 'echo "slurm_load_jobs error: Socket timed out on send/recv operation" >&2\nexit 1\n'


def _fake(bin_dir: Path, name: str, body: str) -> None:
    """A fake SLURM command (shell builtins only: PATH holds nothing else)."""
    bin_dir.mkdir(exist_ok=True)
    path = bin_dir / name
    path.write_text("#!/bin/sh\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


def _script(name: str, *args: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """Run a profile script with PATH = ``cwd/bin`` only (no real SLURM command is seen)."""
    (cwd / "bin").mkdir(exist_ok=True)
    return subprocess.run(
        [sys.executable, str(PROFILE / name), *args],
        cwd=cwd, env={**os.environ, "PATH": str(cwd / "bin"), **env}, capture_output=True,
        text=True, timeout=60,
    )  # fmt: skip


def _one_line(done: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr
    return done.stderr


def _jobscript(tmp_path: Path, properties: object) -> Path:
    path = tmp_path / "snakejob.sh"
    path.write_text(f"#!/bin/sh\n# properties = {json.dumps(properties)}\n{SNAKEMAKE_LINE}\n")
    return path


JOB = {"type": "single", "rule": "train", "threads": 2, "resources": {"mem_mb": 100}}


def test_submit_without_sbatch_says_so_and_changes_nothing(tmp_path: Path) -> None:
    script = _jobscript(tmp_path, JOB)
    before = script.read_bytes()
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode != 0 and done.stdout == ""
    said = _one_line(done)
    assert "sbatch" in said and "PATH" in said
    assert script.read_bytes() == before
    assert not (tmp_path / "results").exists()  # no log folder made either


BAD_JOBS = {
    "unbalanced slurm_extra": (
        {**JOB, "resources": {"slurm_extra": '--comment "x'}},
        ["slurm_extra", '--comment "x', "quote"],
    ),
    "properties not an object": ([1, 2], ["properties"]),
    "resources not an object": ({**JOB, "resources": ["mem_mb"]}, ["resources"]),
    "no rule named": ({"type": "single", "resources": {}}, ["rule"]),
}


@pytest.mark.parametrize("case", BAD_JOBS)
def test_submit_refuses_bad_properties_before_changing_anything(tmp_path: Path, case: str) -> None:
    """One line naming what is wrong (for slurm_extra: the resource, its value, the fix); the
    job script byte-identical, no folder made, no sbatch called."""
    properties, words = BAD_JOBS[case]
    _fake(tmp_path / "bin", "sbatch", f"echo called > {tmp_path}/called\necho 7\n")
    script = _jobscript(tmp_path, properties)
    before = script.read_bytes()
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode == 2 and done.stdout == ""
    said = _one_line(done)
    assert all(word in said for word in words), said
    assert script.read_bytes() == before
    assert not (tmp_path / "called").exists() and not (tmp_path / "results").exists()


@pytest.mark.parametrize("text", ["# properties = {oops\n", "no --cores here\n", None, b"\xff"])
def test_submit_refuses_a_bad_job_script_in_one_line(tmp_path: Path, text: str | None) -> None:
    """Broken JSON, no `--cores all` to pin, a folder, bytes that are not text."""
    _fake(tmp_path / "bin", "sbatch", "echo 7\n")
    script = tmp_path / "snakejob.sh"
    if text is None:
        script.mkdir()
    elif isinstance(text, bytes):
        script.write_bytes(text)
    else:
        script.write_text(f"#!/bin/sh\n{text}")
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode == 2 and done.stdout == ""
    _one_line(done)


def test_submit_reports_sbatch_in_one_line(tmp_path: Path) -> None:
    """sbatch's multi-line error is one line; an sbatch that prints no job id is an error;
    either way the job script is left as it was."""
    script = _jobscript(tmp_path, JOB)
    before = script.read_bytes()
    _fake(
        tmp_path / "bin", "sbatch", 'echo "sbatch: error: first" >&2\necho "second" >&2\nexit 1\n'
    )
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode == 1 and "first" in _one_line(done) and "second" in done.stderr
    assert script.read_bytes() == before
    _fake(tmp_path / "bin", "sbatch", "echo\n")
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode == 1 and done.stdout == "" and "job id" in _one_line(done)
    assert script.read_bytes() == before
    _fake(tmp_path / "bin", "sbatch", 'echo "4242;cluster"\n')
    done = _script("submit.py", str(script), cwd=tmp_path)
    assert done.returncode == 0 and done.stdout == "4242\n" and done.stderr == ""
    assert script.read_text().endswith("--cores 2\n")


CORRUPT = {
    "not JSON": "{oops",
    "not an object": "[]",
    "jobs a list": '{"called": NOW, "read": NOW, "jobs": ["x"]}',
    "a state not text": '{"called": NOW, "read": NOW, "jobs": {"11": 5}}',
    "times in the future": '{"called": 1e300, "read": 1e300, "jobs": {"11": "FAILED"}}',
    "times not numbers": '{"called": "now", "read": NOW, "jobs": {}}',
    "unanswered not times": '{"called": 0, "read": 0, "jobs": null, "unanswered": {"11": "x"}}',
}


@pytest.mark.parametrize("case", CORRUPT)
def test_status_rebuilds_a_corrupt_cache(tmp_path: Path, case: str) -> None:
    """A hand-edited cache is ignored (a one-line warning at most) and written anew; a cache
    dated in the future is not trusted to be fresh."""
    _fake(tmp_path / "bin", "squeue", 'echo "11|RUNNING"\n')
    (tmp_path / CACHE).parent.mkdir()
    (tmp_path / CACHE).write_text(CORRUPT[case].replace("NOW", str(time.time())))
    done = _script("status.py", "11", cwd=tmp_path)
    assert done.returncode == 0 and done.stdout == "running\n", done
    assert "Traceback" not in done.stderr and len(done.stderr.splitlines()) <= 1, done.stderr
    assert json.loads((tmp_path / CACHE).read_text())["jobs"] == {"11": "RUNNING"}
    again = _script("status.py", "11", cwd=tmp_path)
    assert again.stdout == "running\n" and again.stderr == ""  # rebuilt: no more warning


def test_status_without_a_snakemake_folder_asks_slurm_every_call(tmp_path: Path) -> None:
    """A `.snakemake` that is a file: no cache, each call asks squeue itself (one line says
    so), and the answers are right."""
    _fake(tmp_path / "bin", "squeue", f'echo squeue >> {tmp_path}/calls\necho "11|RUNNING"\n')
    _fake(tmp_path / "bin", "sacct", "echo COMPLETED\n")
    (tmp_path / ".snakemake").write_text("not a folder\n")
    for jobid, said in (("11", "running"), ("12", "success")):
        done = _script("status.py", jobid, cwd=tmp_path, CAPE_SLURM_ROUND_GAP="600")
        assert done.returncode == 0 and done.stdout == f"{said}\n", done
        assert ".snakemake" in _one_line(done)
    assert (tmp_path / ".snakemake").read_text() == "not a folder\n"
    assert (tmp_path / "calls").read_text().split() == ["squeue", "squeue"]


def test_status_fails_a_job_at_once_when_slurm_commands_are_missing(tmp_path: Path) -> None:
    """No squeue, sacct or scontrol: failed, naming them; a queue without the job and nothing
    to say how it ended: failed; squeue missing but sacct answering: sacct's word."""
    done = _script("status.py", "11", cwd=tmp_path)
    assert done.returncode == 0 and done.stdout == "failed\n", done
    said = _one_line(done)
    assert all(name in said for name in ("squeue", "sacct", "scontrol", "PATH")), said
    _fake(tmp_path / "bin", "squeue", 'echo "11|RUNNING"\n')
    done = _script("status.py", "12", cwd=tmp_path, CAPE_SLURM_ROUND_GAP="0")
    assert done.stdout == "failed\n" and "sacct" in _one_line(done)
    (tmp_path / "bin" / "squeue").unlink()
    _fake(tmp_path / "bin", "sacct", "echo RUNNING\n")
    done = _script("status.py", "12", cwd=tmp_path, CAPE_SLURM_ROUND_GAP="0")
    assert done.stdout == "running\n" and done.stderr == "", done


def test_status_gives_up_once_slurm_keeps_failing_past_the_bound(tmp_path: Path) -> None:
    """SLURM's commands fail (a controller that is down): running while the first failure
    about the job is recent (the time kept across calls), failed with the reason after."""
    for name in ("squeue", "sacct", "scontrol"):
        _fake(tmp_path / "bin", name, BUSY)
    bound = {"CAPE_SLURM_GIVE_UP_AFTER": "0.5", "CAPE_SLURM_ROUND_GAP": "0"}
    done = _script("status.py", "11", cwd=tmp_path, **bound)
    assert done.returncode == 0 and done.stdout == "running\n", done
    assert "asking again next round" in _one_line(done)
    time.sleep(0.6)
    later = _script("status.py", "12", cwd=tmp_path, **bound)  # its own clock starts now
    assert later.stdout == "running\n", later
    done = _script("status.py", "11", cwd=tmp_path, **bound)
    assert done.returncode == 0 and done.stdout == "failed\n", done
    said = _one_line(done)
    assert "11" in said and "Socket timed out" in said and "CAPE_SLURM_GIVE_UP_AFTER" in said
    _fake(tmp_path / "bin", "squeue", 'echo "12|RUNNING"\n')  # SLURM answers again
    time.sleep(0.6)
    done = _script("status.py", "12", cwd=tmp_path, **bound)
    assert done.stdout == "running\n" and done.stderr == "", done


@pytest.mark.parametrize("name", ["CAPE_SLURM_GIVE_UP_AFTER", "CAPE_SLURM_ROUND_GAP"])
@pytest.mark.parametrize("value", ["ten", "-1", "nan"])
def test_status_refuses_a_bad_setting_in_one_line(tmp_path: Path, name: str, value: str) -> None:
    _fake(tmp_path / "bin", "squeue", 'echo "11|RUNNING"\n')
    done = _script("status.py", "11", cwd=tmp_path, **{name: value})
    assert done.returncode == 2 and done.stdout == ""
    assert name in _one_line(done)


# --- issue 61: an sbatch that never answers, a rule name that leaves the log folder -----------
def test_submit_stops_an_sbatch_that_never_answers(tmp_path: Path) -> None:
    """An sbatch that hangs (a controller that takes the connection and never replies) is
    stopped after CAPE_SLURM_SUBMIT_TIMEOUT seconds with what it started, the job reported not
    submitted in one line, the job script as it was (it waited forever)."""
    body = (f"echo $$ > {tmp_path}/pid\n/bin/sleep 30 &\necho $! > {tmp_path}/child\nwait\n"
            "echo 7\n")  # fmt: skip
    _fake(tmp_path / "bin", "sbatch", body)
    script = _jobscript(tmp_path, JOB)
    before = script.read_bytes()
    start = time.monotonic()
    done = _script("submit.py", str(script), cwd=tmp_path, CAPE_SLURM_SUBMIT_TIMEOUT="1")
    assert time.monotonic() - start < 20, done
    assert done.returncode == 1 and done.stdout == "", done
    said = _one_line(done)
    assert "no answer in 1 s" in said and "CAPE_SLURM_SUBMIT_TIMEOUT" in said, said
    assert "squeue" in said and "cape-train" in said, said  # how to look for a late queued job
    assert script.read_bytes() == before
    time.sleep(0.5)
    for name in ("pid", "child"):  # the fake and its sleep: both stopped, not left running
        pid = int((tmp_path / name).read_text())
        status = Path(f"/proc/{pid}/status")
        alive = status.exists() and "\nState:\tZ" not in status.read_text()
        assert not alive, (name, pid)


@pytest.mark.parametrize("value", ["ten", "0", "-1", "nan", "inf"])
def test_submit_refuses_a_bad_timeout_setting_before_changing_anything(
    tmp_path: Path, value: str
) -> None:
    _fake(tmp_path / "bin", "sbatch", f"echo called > {tmp_path}/called\necho 7\n")
    script = _jobscript(tmp_path, JOB)
    before = script.read_bytes()
    done = _script("submit.py", str(script), cwd=tmp_path, CAPE_SLURM_SUBMIT_TIMEOUT=value)
    assert done.returncode == 2 and done.stdout == ""
    assert "CAPE_SLURM_SUBMIT_TIMEOUT" in _one_line(done)
    assert script.read_bytes() == before
    assert not (tmp_path / "called").exists() and not (tmp_path / "results").exists()


ESCAPES = ["../../../../escape", "..", "a/../../../../../b", "x%j", "../"]


@pytest.mark.parametrize("kind", ["single", "group"])
@pytest.mark.parametrize("name", ESCAPES)
def test_a_job_name_never_sends_the_slurm_log_outside_its_folder(
    tmp_path: Path, name: str, kind: str
) -> None:
    """A rule or group named with `../` (or `%`, which sbatch expands in --output) is
    submitted with its log, and the folder made for it, inside results/logs/slurm (it went to
    ../../../../escape/<id>.log)."""
    _fake(tmp_path / "bin", "sbatch", f'for a in "$@"; do echo "$a"; done > {tmp_path}/args\n'
                                      "echo 7\n")  # fmt: skip
    job = {**JOB, "rule": name} if kind == "single" else {**JOB, "type": "group", "groupid": name}
    work = tmp_path / "study"
    work.mkdir()
    script = _jobscript(work, job)
    (work / "bin").symlink_to(tmp_path / "bin")
    done = _script("submit.py", str(script), cwd=work)
    assert done.returncode == 0 and done.stdout == "7\n", done
    args = (tmp_path / "args").read_text().splitlines()
    output = next(a.removeprefix("--output=") for a in args if a.startswith("--output="))
    logs = (work / "results" / "logs" / "slurm").resolve()
    folder = (work / output).parent.resolve()
    assert folder.parent == logs, output  # one folder under the logs' folder
    assert "%" not in folder.name and output.endswith("/%j.log"), output
    assert folder.is_dir()
    made = {p.name for p in tmp_path.iterdir()}
    assert made == {"bin", "study", "args"}, made  # nothing made beside the study
    assert {p.name for p in (work / "results").iterdir()} == {"logs"}
