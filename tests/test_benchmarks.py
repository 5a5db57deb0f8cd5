"""Every script in benchmarks/ runs on the smoke study (slow): exit 0 with the smallest
arguments that exercise it, or, for one that needs what the study cannot give, one line saying
what is missing and exit status 2; never a traceback. Its paths come from ``cape.layout.paths``,
as the workflow's do, so a moved folder breaks this test and not a user.

And (fast) a damaged or missing input file, a truncated timing.json, a run folder without its
metrics.json, an empty benchmark TSV, a missing runs table, is one line naming the file and
exit status 2, and a study that lacks a part is told what it lacks, never given a zero.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from commands import one_message

from cape.config import REPO_ROOT, load_config
from cape.layout import paths
from cape.layout.record import write_timing
from cape.layout.runs import RunId
from cape.specs.study import StudySpec
from cape.study.grid import study_grid

BENCHMARKS = REPO_ROOT / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))
SMOKE = ["--configfile", "config/smoke.yaml"]  # the overlay the smoke study was built with

Args = Callable[[Path], list[str]]
"""The smallest arguments that exercise a script on the smoke study (``tmp``: a scratch
folder for what it writes)."""

ARGS: dict[str, Args] = {
    "acados_anchor.py": lambda tmp: [
        "--acados", str(REPO_ROOT / ".acados"), "--internal", "truth", "--eta", "0",
        "--repeats", "1", "--condensing", "fc", "--build", str(tmp / "acados"),
        "--json", str(tmp / "acados.json"), *SMOKE,
    ],
    "compile_flags.py": lambda tmp: [
        "--flags=-O0", "--flags=-O0 -g0", "--internal", "truth", "--eta", "0",
        "--repeats", "1", "--problems", "20", *SMOKE,
    ],
    "ddm_stall.py": lambda tmp: [paths.training_dir("ddm", 0), *SMOKE],
    "cluster_projection.py": lambda tmp: SMOKE,
    "draw_cost.py": lambda tmp: ["--replicate", "1", *SMOKE],
    "model_inference.py": lambda tmp: [
        "--models", "epm", "--rounds", "2", "--block", "2", "--cache", str(tmp / "cache"), *SMOKE,
    ],
    "nmpc_step.py": lambda tmp: [
        "--internal", "epm", "--eta", "0", "--repeats", "1", "--stride", "50",
        "--problems", "30", "--json", str(tmp / "nmpc_step.json"), *SMOKE,
    ],
    "recipes.py": lambda tmp: ["ddm", "epm", "--seeds", "2", *SMOKE],
    # replicate 1's DDM calls the rescue at η = 1 in the smoke study: every variant is timed
    "rescue.py": lambda tmp: [
        "--replicate", "1", "--model", "ddm", "--eta", "1", "--seeds", "0", "--caps", "8",
        "--json", str(tmp / "rescue.json"), *SMOKE,
    ],
    "question_calibration.py": lambda tmp: ["--trials", "200"],
    "rescue_outcomes.py": lambda tmp: [
        "--rescue", "null", "--study", "learned", "--replicate", "1", "--limit", "1",
        "--jobs", "1", "--json", str(tmp / "rescue_outcomes.json"), *SMOKE,
    ],
    "rollout_job.py": lambda tmp: ["--rounds", "1", "--controllers", "pid", "nmpc", *SMOKE],
    "step_inside.py": lambda tmp: [
        "--models", "epm", "--controllers", "nmpc", "--eta", "1", *SMOKE,
    ],
    "study_cost.py": lambda tmp: SMOKE,
    "training_step.py": lambda tmp: [
        "--models", "epm", "--variants", "eager", "--epochs", "1", "--rounds", "1",
        "--steps", "5", *SMOKE,
    ],
    "verdict_calibration.py": lambda tmp: ["--trials", "20", "--bootstrap-trials", "2"],
}  # fmt: skip
"""A script not named here is run without arguments: it must then work on the smoke study
or print its usage and exit 2."""

OPTIONAL = {"acados_anchor.py": "acados"}
"""Scripts of an optional extra: without it, one line naming it and how to install it."""


def benchmark(
    script: str, *args: str, cwd: Path, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """The script run as a user runs it: the real interpreter, from the study's folder."""
    return subprocess.run(
        [sys.executable, str(BENCHMARKS / script), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_every_benchmark_is_covered() -> None:
    """A script named in ARGS exists (a renamed one is not silently left untested)."""
    assert set(ARGS) <= set(SCRIPTS), set(ARGS) - set(SCRIPTS)


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS)
def test_a_benchmark_runs_on_the_smoke_study(
    script: str, smoke_study: Path, tmp_path: Path
) -> None:
    args = ARGS[script](tmp_path) if script in ARGS else []
    start = time.perf_counter()
    result = benchmark(script, *args, cwd=smoke_study)
    seconds = time.perf_counter() - start
    said = result.stdout[-3000:] + result.stderr[-3000:]
    assert "Traceback" not in result.stderr, said
    print(f"{script} {' '.join(args)}: exit {result.returncode}, {seconds:.1f} s")
    if script in OPTIONAL and result.returncode == 2:  # the extra is not installed here
        one_message(result, OPTIONAL[script], "requirements-acados.txt")
        return
    if script not in ARGS and result.returncode == 2:  # needs arguments: its usage
        assert "usage:" in result.stderr, said
        return
    assert result.returncode == 0, said
    assert result.stdout.strip(), said
    for option in ("--json",):
        if option in args:
            written = Path(args[args.index(option) + 1])
            json.loads(written.read_text())  # a JSON document, written whole


@pytest.mark.slow
def test_a_script_that_needs_arguments_prints_its_usage(smoke_study: Path) -> None:
    for script in ("ddm_stall.py", "recipes.py", "rescue_outcomes.py"):
        result = benchmark(script, cwd=smoke_study)
        assert result.returncode == 2, result.stdout + result.stderr
        assert "usage:" in result.stderr and "Traceback" not in result.stderr, result.stderr


# --- damaged and missing inputs, on a study made by hand (fast) -------------------------------
@pytest.fixture
def study(tmp_path: Path) -> Path:
    """A study folder with the repository's config and nothing computed yet."""
    (tmp_path / "config").mkdir()
    shutil.copy(REPO_ROOT / "config" / "config.yaml", tmp_path / "config" / "config.yaml")
    return tmp_path


def _first_run(folder: Path, replicate: int = 0) -> RunId:
    """The config's first computed run of draw ``replicate`` that uses a trained model."""
    grid = study_grid(StudySpec.from_config(load_config(folder / "config" / "config.yaml")))
    return next(
        r for r in dict.fromkeys(grid.values())
        if r.replicate == replicate and r.uses_trained_model()
    )  # fmt: skip


def _draws(folder: Path, replicate: int = 0) -> None:
    """Every model's draw ``replicate``, consulting the training of seed ``replicate``, and
    that training's benchmark file, as the workflow leaves them."""
    for model in load_config(folder / "config" / "config.yaml")["models"]:
        meta = folder / paths.model_dir(model, replicate) / "meta.json"
        meta.parent.mkdir(parents=True)
        meta.write_text(json.dumps({"draw": {"trainings": [{"seed": replicate}]}}))
        tsv = folder / paths.benchmark("train", model, f"seed{replicate}.tsv")
        tsv.parent.mkdir(parents=True, exist_ok=True)
        tsv.write_text("s\th:m:s\tcpu_time\n1.5\t0:00:01\t1.25\n")


def test_a_truncated_timing_json_is_one_line(study: Path) -> None:
    folder = _first_run(study).folder()
    (study / folder).mkdir(parents=True)
    (study / folder / "timing.json").write_text('{"job_s": {"startup": 0.1, ')
    for script, args in (("study_cost.py", []), ("draw_cost.py", ["--replicate", "0"])):
        result = benchmark(script, *args, cwd=study)
        one_message(result, f"{script}: error:", str(folder / "timing.json"), "recompute that run")
        assert "rm " not in result.stderr and "delete" not in result.stderr


def test_a_run_without_its_metrics_json_is_one_line(study: Path) -> None:
    _draws(study)
    folder = _first_run(study).folder()
    job = {"startup": 0.1, "config": 0.0, "build": 0.2, "lap": 1.0, "write": 0.0,
           "controller": 0.5, "plant": 0.2, "steps": 100}  # fmt: skip
    write_timing(study / folder, {"job_s": job}, "0" * 64)  # intact: sealed as a run seals it
    result = benchmark("draw_cost.py", "--replicate", "0", cwd=study)
    one_message(result, "draw_cost.py: error:", str(folder / "metrics.json"), "missing")


def test_an_empty_benchmark_tsv_is_one_line(study: Path) -> None:
    _draws(study)
    tsv = paths.benchmark("train", "dpm", "seed0.tsv")
    (study / tsv).write_text("")
    (study / paths.training_dir("dpm", 0)).mkdir(parents=True)
    (study / paths.training_dir("dpm", 0) / "model.pt").write_bytes(b"")
    for script in ("draw_cost.py", "study_cost.py"):
        args = ["--replicate", "0"] if script == "draw_cost.py" else []
        result = benchmark(script, *args, cwd=study)
        one_message(result, f"{script}: error:", tsv, "not a Snakemake benchmark record")


def test_a_missing_runs_table_is_one_line(study: Path) -> None:
    result = benchmark("rescue_outcomes.py", "--rescue", "null", cwd=study)
    one_message(result, paths.study_runs(paths.REPLICATES_SCOPE), "missing")


def test_a_partial_study_is_told_what_it_lacks_and_given_no_total(study: Path) -> None:
    """Draw 1's training benchmark files missing: named, and no total (never "0 s within
    the budget")."""
    _draws(study, 0)
    _draws(study, 1)
    for model in load_config(study / "config" / "config.yaml")["models"]:
        (study / paths.benchmark("train", model, "seed1.tsv")).unlink()
    result = benchmark("draw_cost.py", "--replicate", "1", cwd=study)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "budget" not in result.stdout and "not given" in result.stdout, result.stdout
    assert paths.benchmark("train", "dpm", "seed1.tsv") in result.stdout, result.stdout
    assert "runs not computed" in result.stdout, result.stdout
    costs = benchmark("study_cost.py", cwd=study)
    assert costs.returncode == 0, costs.stdout + costs.stderr
    assert "no total" in costs.stdout and "runs not computed" in costs.stdout, costs.stdout


def test_a_partial_study_is_not_projected_and_told_what_it_lacks(study: Path) -> None:
    _draws(study, 0)
    result = benchmark("cluster_projection.py", cwd=study)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "not projected" in result.stdout and "| R draws" not in result.stdout, result.stdout
    assert "runs not computed" in result.stdout, result.stdout


def test_a_projection_of_impossible_numbers_is_one_line(study: Path) -> None:
    for option, value in (("--queue-wait", "nan"), ("--run-overhead", "-5"),
                          ("--draws", "100000"), ("--nodes", "0")):  # fmt: skip
        result = benchmark("cluster_projection.py", option, value, cwd=study)
        one_message(result, f"argument {option}: {value}")


def test_the_projection_schedules_as_computed_by_hand() -> None:
    """Draw 0: DPM's training (10 s) then its retry (5 s), EPM's (8 s), a DPM solver (2 s),
    one group of two 1 s runs (+ 0.5 s each, + 1 s per group). On one slot the jobs go one
    after another (10 + 8 + 5 + 2 + 4 = 29 s); on two, the retry and solver follow DPM's
    training (10 + 5 + 2), then the group (4): 21 s; a 1 s queue wait adds 1 s to each of
    those four steps: 25 s."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        from cluster_projection import Draw, makespan, study_jobs
    finally:
        sys.path.remove(str(BENCHMARKS))
    draw = Draw({"dpm": [10.0, 5.0], "epm": [8.0]}, [("dpm", 2.0)], {(0.0, 0): [1.0, 1.0]})
    jobs = study_jobs([draw, draw], 1, 0.5, 1.0)
    assert [j.seconds for j in jobs] == [10.0, 5.0, 8.0, 2.0, 4.0]
    assert makespan(jobs, 1, 0.0) == 29.0
    assert makespan(jobs, 2, 0.0) == 21.0
    assert makespan(jobs, 2, 1.0) == 25.0
    two = study_jobs([draw, draw], 2, 0.5, 1.0)  # a second draw: its own, independent jobs
    assert makespan(two, 10, 0.0) == 21.0 and makespan(two, 1, 0.0) == 58.0


def test_acados_missing_is_one_line_naming_the_install(tmp_path: Path) -> None:
    result = benchmark("acados_anchor.py", "--acados", str(tmp_path / "none"), cwd=tmp_path)
    one_message(result, "acados", "requirements-acados.txt")


def _processes_in(folder: Path) -> list[int]:
    """The live processes (not zombies) whose working folder is ``folder``."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if os.readlink(proc / "cwd") != str(folder):
                continue
            if "\nState:\tZ" not in (proc / "status").read_text():
                found.append(int(proc.name))
        except OSError:
            continue
    return found


def test_scheduler_threads_stopped_stops_its_snakemake_and_removes_its_toy(
    tmp_path: Path,
) -> None:
    """scheduler_threads.py stopped as `timeout` stops it (SIGTERM to its process group) while
    its toy `snakemake` runs: one line, exit 143, no process of the toy left (Snakemake and its
    jobs) and no toy folder (both were left: a snakemake asleep for 70 minutes, once)."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}  # the toy's folder goes here
    script = subprocess.Popen(
        [sys.executable, str(BENCHMARKS / "scheduler_threads.py"), "--toy", "400"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )  # fmt: skip
    try:
        deadline, running = time.monotonic() + 120, []
        while not running and time.monotonic() < deadline and script.poll() is None:
            toys = list(tmp_path.glob("cape-threads-*"))
            if toys and (toys[0] / "out").is_dir():  # its snakemake has started jobs
                running = _processes_in(toys[0].resolve())
            time.sleep(0.1)
        assert running, "the toy snakemake did not start"
        os.killpg(script.pid, signal.SIGTERM)  # `timeout`'s stop: the whole process group
        _, err = script.communicate(timeout=60)
    finally:
        if script.poll() is None:
            os.killpg(script.pid, signal.SIGKILL)
            script.wait()
    assert script.returncode == 143, err
    assert len(err.strip().splitlines()) == 1 and "terminated" in err, err
    time.sleep(0.5)
    left = [pid for pid in running if Path(f"/proc/{pid}").exists()
            and "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()]  # fmt: skip
    assert not left, left
    assert not list(tmp_path.glob("cape-threads-*"))
