"""The benchmarks count every training, failed ones included (issue 53, item 6), on a study
made by hand (fast): a draw's cost is the cost of the trainings it took, and the cluster
projection models the failures at the measured rate.

The study: three draws (training.replicates 3, training.max_trainings null: a cap of 6), one
seed at η = 0, PID only; the learned study's three models and the ground-truth car with its
true model (ten runs, each 12 s: a fixed part of 2 s and a lap of 10 s, of which the
controller 6 s and the plant 3 s). Each model's trainings pass (P) or fail (F) in seed order:

- DPM ``PPP``, 60 s of CPU each;
- DDM ``FFFFFF`` (every training fails: every draw reaches the cap), 300 s each;
- EPM ``FPFPFP`` (half fail; draws 0, 1 and 2 are seeds 1, 3 and 5), 320 s each.

Each draw's ``meta.json`` records the trainings consulted for it as the workflow chooses them
(``cape.training.draws.choose_training``).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cape.config import REPO_ROOT, load_config
from cape.layout import paths
from cape.layout.record import write_run_files, write_timing
from cape.specs.study import StudySpec
from cape.study.grid import study_grid
from cape.training.draws import choose_training, default_max_trainings
from cape.training.outcome import Outcome

BENCHMARKS = REPO_ROOT / "benchmarks"
REPLICATES = 3
TRAININGS = {"dpm": ("PPP", 60.0), "ddm": ("FFFFFF", 300.0), "epm": ("FPFPFP", 320.0)}
JOB = {"startup": 1.0, "config": 0.0, "build": 1.0, "write": 0.0, "lap": 10.0,
       "controller": 6.0, "plant": 3.0, "steps": 100}  # fmt: skip
"""Every run's phases (timing.json ``job_s``): 2 s fixed, a 10 s lap, 12 s in all."""


def benchmark(script: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """The script run as a user runs it: the real interpreter, from the study's folder."""
    return subprocess.run(
        [sys.executable, str(BENCHMARKS / script), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def _config(folder: Path) -> dict:
    """The repository's config, cut down to the study above, as config/config.yaml."""
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["training"]["replicates"] = REPLICATES
    config["training"]["max_trainings"] = None
    config["disturbances"]["eta"] = ["0"]
    config["study"]["seeds"] = 1
    config["study"]["studies"] = {
        "learned": {"plants": ["dpm", "ddm", "epm"], "controllers": ["pid"], "replicates": "all"},
        "truth": {"plants": ["truth"], "internal": ["truth"], "controllers": ["pid"]},
    }
    (folder / "config").mkdir()
    (folder / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return load_config(folder / "config" / "config.yaml")


def _trainings(folder: Path, model: str, outcomes: str, cpu: float) -> None:
    """The model's trainings' benchmark files and its draws' meta.json."""
    health = [Outcome(k, flag == "P") for k, flag in enumerate(outcomes)]
    for k in range(len(outcomes)):
        tsv = folder / paths.benchmark("train", model, f"seed{k}.tsv")
        tsv.parent.mkdir(parents=True, exist_ok=True)
        tsv.write_text(f"s\th:m:s\tcpu_time\n{cpu + 1}\t0:05:00\t{cpu}\n")
    cap = default_max_trainings(REPLICATES)
    for r in range(REPLICATES):
        choice = choose_training(r, cap, lambda k: health[k])
        meta = folder / paths.model_dir(model, r) / paths.META
        meta.parent.mkdir(parents=True)
        meta.write_text(json.dumps({"name": model, "replicate": r, "draw": {
            "training": paths.training_dir(model, choice.index), "index": choice.index,
            "trained": choice.trained, "cap_reached": choice.cap_reached,
            "max_trainings": cap, "trainings": [o.to_dict() for o in choice.consulted],
        }}))  # fmt: skip


def _runs(folder: Path, config: dict) -> None:
    """Every run of the grid, as `cape rollout` writes it, with the phases of ``JOB``."""
    for run in dict.fromkeys(study_grid(StudySpec.from_config(config)).values()):
        out = folder / run.folder()
        out.mkdir(parents=True)
        metrics = {
            "study": run.study, "plant": run.plant, "internal": run.internal,
            "controller": run.controller, "eta": run.eta, "seed": run.seed,
            "replicate": run.replicate, "success": True, "failure": None, "lap_time": 7.0,
            "lap_time_penalised": 7.0, "mean_abs_ex": 0.01, "mean_abs_ey": 0.01,
            "mean_abs_ex_penalised": 0.01, "mean_abs_ey_penalised": 0.01, "mean_abs_cte": 0.01,
            "mean_speed": 1.5, "mean_abs_dT": 0.01, "mean_abs_ddelta": 0.01, "steps": 100,
            "fallbacks": 0, "rescues": 0, "time_limit": 15.0,
        }  # fmt: skip
        digest = write_run_files(out, metrics, {"t": np.arange(3.0), "X": np.zeros(3)})
        write_timing(out, {"job_s": JOB}, digest)


def _tail(folder: Path) -> None:
    """The replicates scope's aggregation (20 s) and two notebooks (30 s, 40 s)."""
    aggregate = paths.scoped(paths.REPLICATES_SCOPE, "benchmarks", "study", "aggregate.tsv")
    for path, cpu in ((aggregate, 20.0), (paths.benchmark("notebooks", "a.tsv"), 30.0),
                      (paths.benchmark("notebooks", "b.tsv"), 40.0)):  # fmt: skip
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_text(f"s\th:m:s\tcpu_time\n{cpu}\t0:00:01\t{cpu}\n")


@pytest.fixture
def study(tmp_path: Path) -> Path:
    """The finished study above."""
    config = _config(tmp_path)
    for model, (outcomes, cpu) in TRAININGS.items():
        _trainings(tmp_path, model, outcomes, cpu)
    _runs(tmp_path, config)
    _tail(tmp_path)
    return tmp_path


def _ok(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 0 and "Traceback" not in result.stderr, (
        result.stdout + result.stderr
    )
    return result.stdout


# --- draw_cost.py: a draw's cost is the cost of the trainings it took -------------------------
def test_a_draw_costs_its_failed_trainings_too(study: Path) -> None:
    """Draw 1: DPM's seed 1 (60 s); EPM's seeds 2 (failed) and 3 (640 s); DDM reached the cap
    with no training passed, so its six trainings (1800 s) are shared by its three draws, 600 s
    each (without the fix: 0 s). Its three runs: 36 s (fixed 6, plant 9, controller 18, loop 3).
    Training 60 + 600 + 640 = 1300 s; total 1336 s, over a 1000 s budget (without the fix: 736
    s, "within")."""
    out = _ok(benchmark("draw_cost.py", "--replicate", "1", "--budget", "1000", cwd=study))
    assert re.search(r"training\s+1300 s\s+\(5 trainings, 3 failed\)", out), out
    assert "ddm/seed0 100 (1/3 of 300)" in out and "ddm/seed5 100 (1/3 of 300)" in out, out
    assert "epm/seed2 320" in out and "epm/seed3 320" in out, out
    assert re.search(r"total\s+1336 s of CPU \(over the 1000 s budget\)", out), out


@pytest.mark.parametrize(
    ("outcomes", "per_draw"),
    [
        # every training fails: the three draws share the six, 1800 / 3 = 600 s each (without
        # the fix: 1800, 0, 0)
        ("FFFFFF", (600, 600, 600)),
        # seed 1 passes: draw 0 takes seeds 0 and 1 (600 s); draws 1 and 2 reach the cap and
        # share seeds 2–5 (1200 s), 600 s each (without the fix: 600, 1200, 0)
        ("FPFFFF", (600, 600, 600)),
        # draws 0, 1, 2 are seeds 1, 2, 5: they take 0–1, 2, 3–5 (no cap reached)
        ("FPPFFP", (600, 300, 900)),
    ],
)
def test_each_training_counts_once_over_the_draws(
    study: Path, outcomes: str, per_draw: tuple[int, ...]
) -> None:
    """DDM's draws alone (``--models ddm``: one 12 s run each): each draw's training CPU, and
    over the draws the six trainings' 1800 s."""
    for r in range(REPLICATES):
        shutil.rmtree(study / paths.model_dir("ddm", r))
    _trainings(study, "ddm", outcomes, 300.0)
    for r, seconds in enumerate(per_draw):
        args = ["--replicate", str(r), "--models", "ddm", "--budget", "5000"]
        out = _ok(benchmark("draw_cost.py", *args, cwd=study))
        assert re.search(rf"training\s+{seconds} s ", out), (r, out)
        assert re.search(rf"total\s+{seconds + 12} s of CPU \(within", out), (r, out)
    assert sum(per_draw) == 6 * 300


def test_a_draw_of_a_config_with_other_replicates_is_one_line(study: Path) -> None:
    """Draw 2 of DDM (it reached the cap) read with a config of two draws, which has no
    draw 2: one line naming the meta.json and the fix."""
    config = study / "config" / "config.yaml"
    text = yaml.safe_load(config.read_text())
    text["training"]["replicates"] = 2
    config.write_text(yaml.safe_dump(text, sort_keys=False))
    result = benchmark("draw_cost.py", "--replicate", "2", "--models", "ddm", cwd=study)
    err = result.stderr
    assert result.returncode == 2 and len(err.strip().splitlines()) == 1, result.stdout + err
    assert "Traceback" not in err and paths.model_dir("ddm", 2) in err, err
    assert "give the config the study was built with" in err, err


# --- cluster_projection.py: failures at the measured rate -------------------------------------
def test_the_projection_counts_failed_trainings_at_the_measured_rate(study: Path) -> None:
    """Measured: every draw took DPM 60 s (1 training), DDM 600 s (2: its share of the six
    failed ones; without the fix, draw 0 1800 s (6) and draws 1, 2 "0 s (0)") and EPM 640 s
    (2). Rates: DPM 0 of 3, DDM 6 of 6, EPM 3 of 6; mean trainings 60, 300, 320 s.

    Trainings per draw, E[min(τ, cap)] / R with cap 2R: DPM 1; DDM cap / R = 2; EPM, R = 3
    (cap 6): Σ_{k<6} P(fewer than 3 of k pass) = 1 + 1 + 1 + 7/8 + 11/16 + 1/2 = 81/16, / 3 =
    1.6875 (not 1 / (1 − 0.5) = 2); R = 6 (cap 12): 6 + 63/64 + 120/128 + 219/256 + 382/512
    + 638/1024 + 1/2 = 10.646484375, / 6 = 1.7744140625.

    A draw's trainings: 60 + 600 + 320 e. Runs: draw 0 four (48 s, with the ground-truth
    car's), every further draw three (36 s). Tail: 20 + max(30, 40) = 60 s. On one core, no
    overheads, the wall time is the work plus the tail:
    - R = 3: 3 × (660 + 540) + 48 + 2 × 36 + 60 = 3780 s = 1:03 (without the fix 1:08);
      work: draw 0 1248 s = 0.35 h, a further draw 1236 s = 0.34 h;
    - R = 6: 6 × (660 + 567.8125) + 48 + 5 × 36 + 60 = 7654.875 s = 2:08 (127.6 min)."""
    args = ["--draws", "3", "6", "--nodes", "1", "--cores", "1", "--run-overhead", "0",
            "--group-overhead", "0"]  # fmt: skip
    out = _ok(benchmark("cluster_projection.py", *args, cwd=study))
    for r in range(REPLICATES):
        assert f"draw {r}: trainings dpm 60 s (1), ddm 600 s (2), epm 640 s (2);" in out, out
    assert "dpm: 3 trainings, 0 failed (0%), mean 60 s; per draw R = 3: 1 (cap 6), " in out, out
    assert "ddm: 6 trainings, 6 failed (100%), mean 300 s; per draw R = 3: 2 (cap 6), " in out
    assert "epm: 6 trainings, 3 failed (50%), mean 320 s; per draw R = 3: 1.688 (cap 6), " in out
    assert "R = 6: 1.774 (cap 12)" in out and "R = 6: 2 (cap 12)" in out, out
    assert "E[min(τ, cap)] / R" in out, out
    assert "work: draw 0 0.35 CPU hours (with the runs computed once), a further draw 0.34" in out
    assert "| 3 | 1:03 |" in out and "| 6 | 2:08 |" in out, out


def test_draws_that_do_not_record_their_trainings_outcomes_are_one_line(study: Path) -> None:
    """Draws of an older version (``draw.trainings`` without ``trained``): no failure rate to
    project with, one line saying so and the fix."""
    for r in range(REPLICATES):
        meta = study / paths.model_dir("dpm", r) / paths.META
        meta.write_text(json.dumps({"draw": {"trainings": [{"seed": k} for k in range(r + 1)]}}))
    result = benchmark("cluster_projection.py", cwd=study)
    err = result.stderr
    assert result.returncode == 2 and len(err.strip().splitlines()) == 1, result.stdout + err
    assert "Traceback" not in err and "no `trained` for seed 0" in err, err
    assert "snakemake --cores 2 all replicates" in err, err
