"""The real command line, as the tests call it: ``cape`` and ``snakemake`` in a subprocess,
and what a refusal must look like (one line, exit status 2, no traceback)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from cape.config import REPO_ROOT


def cape(*args: str, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(["cape", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def snakemake(*args: str, cwd: Path = REPO_ROOT, timeout: float = 300):
    return subprocess.run(
        ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def sampled_snakemake(*args: str, cwd: Path = REPO_ROOT, timeout: float = 300):
    """``snakemake(*args)``, and the most threads its own process held (sampled every 0.1 s;
    None where /proc cannot tell)."""
    import tempfile
    import time

    from cape.processes import threads_of

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        command = ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), *args]
        process = subprocess.Popen(command, cwd=cwd, stdout=out, stderr=err, text=True)
        most: int | None = None
        deadline = time.monotonic() + timeout
        while process.poll() is None:
            if time.monotonic() > deadline:
                process.kill()
                process.wait()
                raise subprocess.TimeoutExpired(command, timeout)
            n = threads_of(process.pid)
            if n is not None:
                most = max(most or 0, n)
            time.sleep(0.1)
        out.seek(0)
        err.seek(0)
        result = subprocess.CompletedProcess(command, process.returncode, out.read(), err.read())
    return result, most


def one_message(result: subprocess.CompletedProcess, *needles: str) -> str:
    """The command failed with exit status 2 and one message holding every needle."""
    err = result.stderr
    assert result.returncode == 2, result.stdout + err
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def rollout_args(setup: dict, out: Path, config: Path | None = None, **names: str) -> list[str]:
    """`cape rollout` of PID on the ground-truth car at η = 0 (``names`` override the plant,
    controller, internal model, η, seed or study) with the test's config and raceline."""
    run = {"plant": "truth", "controller": "pid", "eta": "0", "seed": "0", "study": "truth"}
    run.update(names)
    options = [item for key, value in run.items() for item in (f"--{key}", value)]
    return ["cape", "rollout", *options, "--out", str(out), "--raceline", str(setup["raceline"]),
            "--training-data", str(setup["data"]),
            "--config", str(config or setup["config"])]  # fmt: skip


def rollout(setup: dict, out: Path, cwd: Path | None = None, **names: str):
    return cape(*rollout_args(setup, out, **names)[1:], cwd=cwd)
