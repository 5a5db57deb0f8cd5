"""The workflow's logic in the package (cape/workflow: one object per stage), without
Snakemake: what a job reads, which runs and files a target names, the wildcards' patterns."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from cape.config import load_config
from cape.layout import paths
from cape.workflow.notebooks import run_notebook
from cape.workflow.targets import StudyWorkflow


def _outputs(rule: str, **wildcards: object) -> list[str]:
    """A stand-in for Snakemake's rules: one file per job, named by its rule and wildcards."""
    return [f"{rule}:" + ",".join(f"{k}={v}" for k, v in sorted(wildcards.items()))]


def _health(model: str, seed: int) -> str:
    raise AssertionError("no draw is chosen in these tests")


@pytest.fixture(scope="module")
def flow() -> StudyWorkflow:
    return StudyWorkflow.from_config(load_config("config/config.yaml"), _outputs, _health)


def _run(**fields: str) -> SimpleNamespace:
    return SimpleNamespace(replicate="2", eta="1", seed="0", study="truth", **fields)


def test_a_true_plant_reads_no_training_data_and_a_learned_one_does(flow: StudyWorkflow) -> None:
    truth = flow.runs.rollout_inputs(_run(plant="truth", internal="epm", controller="nmpc"))
    assert "training_data" not in truth and "plant_meta" not in truth
    assert truth["internal_network"] == f"{paths.model_dir('epm', 2)}/{paths.NETWORK}"
    learned = flow.runs.rollout_inputs(_run(plant="dpm", internal="dpm", controller="pid"))
    assert learned["training_data"] == paths.dataset("ETHZ")
    assert "internal_meta" not in learned  # PID has no internal model
    frozen = flow.runs.rollout_inputs(
        _run(plant="epm-fixed", internal="epm-fixed", controller="pid")
    )
    assert frozen["plant_frozen"] == f"{paths.model_dir('epm', 2)}/{paths.FROZEN_PHI}"


def test_the_true_models_solver_is_draw_zeros_for_every_draw(flow: StudyWorkflow) -> None:
    assert flow.runs.solver_path("nmpc", "truth", 3) == paths.solver("nmpc", "truth", 0)
    assert flow.runs.solver_path("nmpc", "epm", 3) == paths.solver("nmpc", "epm", 3)
    run = _run(plant="truth", internal="truth", controller="nmpc")
    assert flow.runs.rollout_inputs(run).get("solver") == (
        paths.solver("nmpc", "truth", 0) if flow.runs.compiles_solver("nmpc") else None
    )


def test_the_default_target_names_each_computed_run_of_draw_zero_once(flow: StudyWorkflow) -> None:
    runs = flow.runs.computed_runs({0})
    assert runs and len(set(runs)) == len(runs) and {r.replicate for r in runs} == {0}
    shared = [run for run, computed in flow.runs.grid.items() if run != computed]
    assert shared  # the ablation's diagonal is computed by another study's folder
    rollouts = [f for f in flow.all_targets() if f.startswith("rollout:")]
    assert len(rollouts) == len(runs)
    assert flow.runs.rollout_targets({0}) == [f"{r.folder()}/{paths.METRICS}" for r in runs]


def test_the_question_target_is_empty_without_a_plan(flow: StudyWorkflow) -> None:
    assert flow.question.targets() == []


def test_the_wildcards_patterns_name_the_configs_entries(flow: StudyWorkflow) -> None:
    patterns = flow.constraints()
    assert set(patterns["model"].split("|")) == {"dpm", "ddm", "epm"}
    assert "truth" in patterns["plant"].split("|") and "epm-fixed" in patterns["plant"]
    assert flow.notebooks.studies_of_kind("nothing") == "(?!)"


def test_model_arguments_name_the_draws_folders(flow: StudyWorkflow) -> None:
    args = flow.runs.model_folder_args(
        SimpleNamespace(replicate="1"), ["truth", "epm-fixed", "dpm"]
    )
    assert args == (f"--model dpm={paths.model_dir('dpm', 1)} "
                    f"--model epm={paths.model_dir('epm', 1)}")  # fmt: skip


def test_no_stale_summary_without_one(flow: StudyWorkflow, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert flow.notebooks.stale_summaries() == []


def test_a_notebooks_shell_command_quotes_every_path() -> None:
    command = run_notebook("-f x")
    assert "{input.notebook:q}" in command and "{output.html:q}" in command
    assert "{input.notebook}" not in command and "{log}" not in command


def test_no_class_of_the_workflow_holds_more_than_25_members() -> None:
    """One object per stage (issue 60): a class's fields, methods and properties, at most 25."""
    import ast

    from cape.config import REPO_ROOT

    sizes = {}
    for path in sorted((REPO_ROOT / "src" / "cape" / "workflow").glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef):
                members = set()
                for item in node.body:
                    if isinstance(item, ast.FunctionDef):
                        members.add(item.name)
                    elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                        members.add(item.target.id)
                sizes[f"{path.name}:{node.name}"] = len(members)
    assert sizes and max(sizes.values()) <= 25, sizes
