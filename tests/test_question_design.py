"""A question's design is fixed before its first look (SPEC §10, revision 7): `cape question`
refuses a rerun whose margins, α, futility, models or seed rule differ from the design already
looked at, in one line naming the key, and changes nothing in results/question/."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from commands import cape, one_message
from conftest import workdir

from cape.config import REPO_ROOT, merged_config
from cape.specs.study import StudySpec
from cape.study.question.plan import QuestionSettings
from cape.study.question.state import FORMAT, QuestionState

ARGS = ("question", "--configfile", "config/q.yaml", "--dry-run")


def _looked_at(work: Path) -> dict[str, bytes]:
    """A results/question/ whose first look was taken under the default design (config.yaml
    and question.yaml): its looks.json, and a report beside it; returns every file's bytes."""
    config = merged_config([str(work / "config" / "config.yaml"),
                            str(REPO_ROOT / "config" / "question.yaml")])  # fmt: skip
    settings = QuestionSettings.from_config(config)
    design = settings.identity(dict(StudySpec.from_config(config).models))
    state = QuestionState(design, [5, 5, 5, 3, 3, 3], [{"stage": 1, "wall_s": 203.9}])
    shutil.copy(REPO_ROOT / "config" / "question.yaml", work / "config" / "question.yaml")
    folder = work / "results" / "question"
    folder.mkdir(parents=True)
    (folder / "looks.json").write_text(state.as_json())
    (folder / "RESULTS.md").write_text("# the report of stage 1\n")
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"scorecard": {"margins": {"lap_time_penalised": 0.1}}}, "margins.lap_time_penalised"),
        ({"question": {"alpha": 0.2}}, "alpha"),
        ({"question": {"futility": 0.2}}, "futility"),
        ({"question": {"seeds": {"least": 3}}}, "seed rule.least"),
        ({"question": {"spending": 3}}, "spending"),
        ({"models": {"ddm_tuned": {"train": {"epochs": 10}}}}, "recipes.ddm_tuned.train.epochs"),
    ],
)
def test_a_changed_design_is_refused_and_nothing_changes(
    tmp_path: Path, change: dict, key: str
) -> None:
    work = workdir(tmp_path)
    before = _looked_at(work)
    (work / "config" / "q.yaml").write_text(yaml.safe_dump(change))
    refused = cape(*ARGS, cwd=work)
    message = one_message(refused, f"`{key}` was", "fixed before the first look", "mv ")
    assert "results/question-earlier" in message
    folder = work / "results" / "question"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_the_same_design_continues(tmp_path: Path) -> None:
    work = workdir(tmp_path)
    _looked_at(work)
    (work / "config" / "q.yaml").write_text("{}\n")
    result = cape(*ARGS, cwd=work)
    assert result.returncode == 0, result.stderr
    assert "seeds:" in result.stdout


@pytest.mark.parametrize(
    "text",
    [
        "{not json",
        json.dumps({"format": FORMAT, "design": {}, "seeds": [5], "looks": [{"stage": "x"}]}),
        json.dumps({"format": FORMAT, "design": {}, "seeds": [5], "looks": [{"stage": 1}]}),
        '{"question": {}, "looks": [{"stage": 1, "wall_s": 4}]}',
    ],
    ids=["truncated", "stage not a number", "no wall time", "an earlier CAPE's"],
)
def test_a_record_that_cannot_be_read_is_refused(tmp_path: Path, text: str) -> None:
    """A hand-edited or truncated looks.json is one line, exit 2, nothing changed (it holds
    the stages' wall times and the seeds chosen, which the runs do not tell)."""
    work = workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "question.yaml", work / "config" / "question.yaml")
    folder = work / "results" / "question"
    folder.mkdir(parents=True)
    (folder / "looks.json").write_text(text)
    (work / "config" / "q.yaml").write_text("{}\n")
    one_message(cape(*ARGS, cwd=work), "looks.json")
    assert (folder / "looks.json").read_text() == text
    assert [p.name for p in folder.iterdir()] == ["looks.json"]


def test_a_record_with_no_look_takes_the_new_design() -> None:
    state = QuestionState.read({"alpha": 0.1}, path="/nonexistent/looks.json")
    assert state.design == {"alpha": 0.1} and not state.looks
    assert json.loads(state.as_json())["format"] == FORMAT


def test_a_resumed_trainings_cpu_counts_every_part(tmp_path: Path, monkeypatch) -> None:
    """A training's CPU is what its meta.json records over every resume; a training recorded
    before that is scaled up from its benchmark's last part by its whole wall time, never
    counted as that last part alone (the first stage's DDM trainings read ~30 % low so)."""
    from cape.layout import paths
    from cape.study.question.report import training_cpu

    monkeypatch.chdir(tmp_path)
    tsv = Path(paths.benchmark("train", "ddm", "seed0.tsv"))
    tsv.parent.mkdir(parents=True)
    tsv.write_text("s\th:m:s\tcpu_time\n1000.0\t0:16:40\t400.0\n")  # the last part only
    assert training_cpu("ddm", 0, tsv) == 400.0  # no meta.json: the benchmark alone
    meta = Path(paths.training_dir("ddm", 0)) / "meta.json"
    meta.parent.mkdir(parents=True)
    meta.write_text(json.dumps({"wall_seconds": 2500.0}))  # resumed: 2.5 × the last part
    assert training_cpu("ddm", 0, tsv) == pytest.approx(1000.0)
    meta.write_text(json.dumps({"wall_seconds": 2500.0, "cpu_seconds": 1234.5}))
    assert training_cpu("ddm", 0, tsv) == 1234.5  # recorded over every part: taken as is
    meta.write_text(json.dumps({"wall_seconds": 900.0, "cpu_seconds": None}))
    assert training_cpu("ddm", 0, tsv) == 400.0  # not resumed: the benchmark's own
    assert training_cpu("ddm", 1, tsv.with_name("seed1.tsv")) is None  # neither file
