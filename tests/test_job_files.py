"""Each job's file (cape.workflow.job_files): exactly the settings it reads, in a small file
named by their digest, read by the command's --spec."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cape.config import config_from_args, load_config
from cape.errors import CapeError
from cape.workflow.job_files import RUN_ONLY_KEYS, JobFiles, write_job_file


@pytest.fixture(scope="module")
def config() -> dict:
    return load_config("config/config.yaml")


def test_a_spec_file_is_named_by_its_content_and_written_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    first = write_job_file("train", '{"a": 1}')
    assert Path(first).parent == Path("results/specs/train")
    assert Path(first).read_text() == '{"a": 1}'
    written = Path(first).stat().st_mtime_ns
    assert write_job_file("train", '{"a": 1}') == first  # the same text: the same file ...
    assert Path(first).stat().st_mtime_ns == written  # ... not written again
    assert write_job_file("train", '{"a": 2}') != first  # another setting: another file


def _written(path: str) -> dict:
    return json.loads(Path(path).read_text())


@pytest.fixture
def jobs(config: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> JobFiles:
    """The job files of config/config.yaml, written under a temporary folder."""
    monkeypatch.chdir(tmp_path)
    return JobFiles(config)


def test_a_command_reads_its_spec_as_it_read_the_json(jobs: JobFiles, tmp_path: Path) -> None:
    path = tmp_path / "spec.json"
    text = Path(jobs.write_sections("dataset", "tracks", "data")).read_text()
    path.write_text(text)
    assert config_from_args(None, None, str(path)) == config_from_args(None, text)
    with pytest.raises(CapeError, match=r"--spec .*missing\.json: cannot read"):
        config_from_args(None, None, str(tmp_path / "missing.json"))
    path.write_text("[1, 2]")
    with pytest.raises(CapeError, match=r"--spec .*spec\.json must be a JSON object"):
        config_from_args(None, None, str(path))


def test_sections_leave_out_the_grids_keys(jobs: JobFiles) -> None:
    chosen = _written(jobs.write_sections("openloop_table", "training", "data"))
    assert sorted(chosen) == ["data", "training"]
    assert not {"replicates", "max_trainings"} & set(chosen["training"])


def test_a_training_reads_its_models_entry_and_seed_not_its_label(
    jobs: JobFiles, config: dict
) -> None:
    spec = _written(jobs.write_training("epm", 7))
    assert list(spec["models"]) == ["epm"]
    assert "label" not in spec["models"]["epm"] and "color" not in spec["models"]["epm"]
    assert spec["training"]["seed"] == 7
    epm = {**config["models"]["epm"], "label": "mine"}
    relabelled = JobFiles({**config, "models": {**config["models"], "epm": epm}})
    assert relabelled.write_training("epm", 7) == jobs.write_training("epm", 7)
    assert jobs.write_training("epm", 8) != jobs.write_training("epm", 7)


def test_a_run_reads_only_the_models_its_plant_and_internal_model_read(jobs: JobFiles) -> None:
    spec = _written(jobs.write_rollout("nmpc", "epm", "epm"))
    assert list(spec["controllers"]) == ["nmpc"]
    assert sorted(spec["models"]) == ["epm"]
    truth = _written(jobs.write_rollout("nmpc", "truth", "epm"))
    assert sorted(truth["models"]) == ["ddm", "epm"]  # the true model has DDM's structure
    solver = _written(jobs.write_solver("nmpc", "epm"))
    assert not set(RUN_ONLY_KEYS) & set(solver["rollout"])
    assert Path(jobs.write_solver("nmpc", "epm")).parent.name == "solver"


def test_a_notebooks_parameters_are_strings_as_papermill_r_passes_them(jobs: JobFiles) -> None:
    path = jobs.write_parameters("notebook_x", study="learned", replicates=[0, 1], eta=1.0)
    assert _written(path) == {"study": "learned", "replicates": "0,1", "eta": "1.0"}
    assert list(_written(path)) == ["study", "replicates", "eta"]


def test_a_notebook_reads_the_sections_it_declares(jobs: JobFiles) -> None:
    from cape.study.reports.outputs import STUDY_NOTEBOOKS

    path = jobs.write_notebook("bicycle")
    assert Path(path).parent.name == "notebook_bicycle"
    assert sorted(_written(path)) == sorted(STUDY_NOTEBOOKS["bicycle"].reads)


def test_an_unwritable_spec_folder_is_one_line(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "specs").write_text("a file where the folder belongs")
    with pytest.raises(CapeError, match=r"results/specs.*cannot write the job's specification"):
        write_job_file("train", '{"a": 1}')


def test_a_file_of_yours_at_a_specs_name_is_never_replaced(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    path = Path(write_job_file("train", '{"a": 1}'))
    path.write_text("my notes")
    with pytest.raises(CapeError, match="did not write; move it away"):
        write_job_file("train", '{"a": 1}')
    assert path.read_text() == "my notes"
