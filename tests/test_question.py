"""`cape question` through the real command (slow): a smoke question of two stages, killed in
its second and resumed, a row settled as `equivalent`, and only the question's runs made."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from commands import cape, one_message
from conftest import workdir

from cape.config import REPO_ROOT

QUESTION = {
    # two models, looks at two and three draws; margins so wide that a row must be equivalent
    "question": {"models": ["epm", "dpm"], "stages": [2, 3]},
    "scorecard": {
        "margins": {
            "lap_time_penalised": 100.0,
            "mean_abs_ex_penalised": 1000.0,
            "mean_abs_ey_penalised": 1000.0,
            "mean_speed": 1000.0,
            "failures": 100.0,
        }
    },
}
ARGS = ["question", "--no-question-config", "--configfile", "config/smoke.yaml", "config/q.yaml"]


@pytest.fixture
def work(tmp_path: Path) -> Path:
    work = workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    (work / "config" / "q.yaml").write_text(yaml.safe_dump(QUESTION))
    return work


@pytest.mark.slow
def test_the_question_runs_in_stages_resumes_and_settles_a_row(work: Path) -> None:
    """Killed (SIGTERM) once its second stage has begun, the command stops Snakemake and its
    jobs; run again it resumes: the first stage's runs are not redone, the second stage's
    draws come, the report has both stages and a row settled as ``equivalent``. A further draw
    runs the ground-truth study's NMPC runs only, none of the paper's study."""
    proc = subprocess.Popen(
        ["cape", *ARGS], cwd=work, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.startswith("stage 2/2"):
            time.sleep(5)  # some of the second stage's jobs are running
            proc.send_signal(signal.SIGTERM)
            break
    rest = proc.communicate(timeout=300)[0]
    assert proc.returncode == 143, "".join(seen) + rest
    assert "terminated" in rest
    time.sleep(2)  # the jobs' own SIGTERM handling
    left = subprocess.run(["pgrep", "-f", f"snakemake.*{work}"], capture_output=True, text=True)
    assert not left.stdout.strip(), "Snakemake outlived the command"
    jobs = [p for p in Path("/proc").glob("[0-9]*/cwd") if _resolves_to(p, work)]
    assert not jobs, "a job of Snakemake's outlived the command"
    question = work / "results" / "question"
    stopped = json.loads((question / "looks.json").read_text())
    assert stopped["stopped"]["2"] > 0  # the stopped stage's wall time, kept
    first_runs = sorted((work / "results" / "runs").rglob("metrics.json"))
    stamps = {p: p.stat().st_mtime_ns for p in first_runs}
    assert any("rep0" in str(p) for p in first_runs)

    again = cape(*ARGS, cwd=work, timeout=1200)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "stage 2: " in again.stdout and "report in" in again.stdout
    assert all(p.stat().st_mtime_ns == t for p, t in stamps.items())  # nothing redone

    stages = json.loads((question / "looks.json").read_text())["looks"]
    assert [s["look at draws"] for s in stages] == [2, 3]
    assert stages[1]["wall_s"] > stopped["stopped"]["2"]  # the stopped part counted too
    assert (
        "stopped" not in json.loads((question / "looks.json").read_text())
        or not json.loads((question / "looks.json").read_text())["stopped"]
    )
    assert (question / "logs" / "stage2.log").read_text().count("\n--- ") >= 1  # both attempts
    looks = pd.read_csv(question / "looks.csv")
    final = looks.sort_values("look").groupby(["claim", "comparison"]).tail(1)
    assert (final["decision"] == "equivalent").any(), final.to_string()
    report = (question / "RESULTS.md").read_text()
    assert "| 2 | EPM 3, DPM 3 |" in report and "**Where it stopped:**" in report
    for produced in ("figures/fig15_question_looks.png", "tables/table10_question.md",
                     "notebooks/question.html"):  # fmt: skip
        assert (question / produced).is_file(), produced
    runs = work / "results" / "runs"
    assert (runs / "truth" / "rep2" / "truth" / "dpm" / "anmpc").is_dir()
    assert (runs / "truth" / "rep2" / "truth" / "dpm" / "anmpc" / "eta0" / "seed2000").is_dir()
    assert (
        not (runs / "learned").exists()
        and not (runs / "truth" / "rep2" / "truth" / "truth").exists()
    )


def _resolves_to(link: Path, folder: Path) -> bool:
    """A process whose working folder is ``folder`` (a job runs in the study's folder)."""
    try:
        return link.resolve() == folder.resolve()
    except OSError:
        return False


def test_a_bad_question_is_one_line(tmp_path: Path) -> None:
    """Unknown models, stages that do not increase, a missing file: one line naming the field
    or file and the fix, exit status 2, nothing run."""
    work = workdir(tmp_path)
    bad = work / "config" / "bad.yaml"
    bad.write_text("question: {models: [epm, nosuch]}\n")
    one_message(cape("question", "--no-question-config", "--configfile", str(bad), "--dry-run",
                     cwd=work), "question.models", "nosuch is not one")  # fmt: skip
    bad.write_text("question: {stages: [6, 3]}\n")
    one_message(cape("question", "--no-question-config", "--configfile", str(bad), "--dry-run",
                     cwd=work), "question.stages", "increase")  # fmt: skip
    missing = cape("question", "--no-question-config", "--configfile", "nope.yaml", "--dry-run",
                   cwd=work)  # fmt: skip
    one_message(missing, "nope.yaml not found")
    assert not (work / "results").exists()


def test_a_users_model_is_put_to_the_same_question() -> None:
    """examples/extension.yaml's MLP (one module plus one config entry) against EPM: the same
    five rows for the one pair, the stage plan adding both to the ground-truth study."""
    result = cape("question", "--no-question-config", "--configfile", "examples/extension.yaml",
                  "examples/question_mlp.yaml", "--dry-run", cwd=REPO_ROOT)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "5 rows (5 metrics × 1 pairs of epm, mlp)" in result.stdout
    plan = yaml.safe_load(result.stdout.split("\n", 1)[1].rsplit("$ snakemake", 1)[0])
    assert plan["question"]["plan"]["draws"] == {"epm": 3, "mlp": 3}
    assert {"epm", "mlp"} <= set(plan["study"]["studies"]["truth"]["internal"])


@pytest.mark.slow
def test_a_published_question_rederives_and_resumes_on_a_fresh_tree(work: Path) -> None:
    """The smoke question run to its end, published, re-derived from the published folder; then
    on a tree that lost results/question/ and every run, `--reuse` of the published folder takes
    the same looks without running a single rollout again."""
    first = cape(*ARGS, cwd=work, timeout=1800)
    assert first.returncode == 0, first.stdout + first.stderr
    folder = work / "published"
    published = cape(*ARGS, "--publish", str(folder), cwd=work)
    assert published.returncode == 0, published.stderr
    provenance = json.loads((folder / "provenance.json").read_text())
    assert provenance["config_sha256"] and provenance["stages"] and provenance["draws"]["epm"]
    assert provenance["draws"]["epm"][1]["disturbance seeds"][0] == 1000
    again = cape("question", "--from", str(folder), cwd=work)
    assert again.returncode == 0 and "identical to looks.csv" in again.stdout, again.stderr

    looks = (work / "results" / "question" / "looks.csv").read_text()
    shutil.move(work / "results" / "question", work / "question-earlier")
    shutil.rmtree(work / "results" / "runs" / "truth")
    resumed = cape(*ARGS, "--reuse", str(folder), cwd=work, timeout=1800)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert (work / "results" / "question" / "looks.csv").read_text() == looks
    assert not (work / "results" / "runs" / "truth").exists()  # no rollout ran
