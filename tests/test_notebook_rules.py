"""Every file a notebook rule declares as input reaches the notebook as a papermill parameter:
a notebook reads only what its rule passed, never a default path (issue 42). Checked on the
real `snakemake` dry run of every notebook job of the smoke study."""

from __future__ import annotations

import json
import shlex
import subprocess
from pathlib import Path

import pytest
import yaml

from cape.config import REPO_ROOT


def notebook_jobs(dry_run: str, work: Path = Path()) -> dict[str, tuple[list[str], dict[str, str]]]:
    """Each notebook job of a `snakemake -n -p` listing → (its inputs other than the notebook
    itself, its papermill parameters: ``-r NAME VALUE`` and those of a ``-f FILE``, the job's
    specification the dry run wrote under ``work``), keyed by the executed notebook."""
    jobs = {}
    for block in dry_run.split("\nrule notebook_")[1:]:
        lines = block.splitlines()
        inputs = next(line for line in lines if line.strip().startswith("input:"))
        files = [f.strip() for f in inputs.split(":", 1)[1].split(",")]
        command = next(line for line in lines if line.startswith("Shell command:"))
        words = shlex.split(command.split("papermill", 1)[1].split(" > ", 1)[0])
        notebook, executed = words[0], words[1].removesuffix(".part.ipynb")
        parameters = {words[i + 1]: words[i + 2] for i, w in enumerate(words) if w == "-r"}
        for i in (i for i, w in enumerate(words) if w == "-f"):
            parameters.update(json.loads((work / words[i + 1]).read_text()))
        jobs[executed] = ([f for f in files if f != notebook], parameters)
    return jobs


def unpassed(inputs: list[str], parameters: dict[str, str]) -> list[str]:
    """The inputs no parameter names: neither a value, nor an item of a comma-separated value,
    nor a file under a folder a value names."""
    values = [v for value in parameters.values() for v in value.split(",") if v]
    return [
        path
        for path in inputs
        if not any(path == v or path.startswith(v.rstrip("/") + "/") for v in values)
    ]


def test_a_missing_parameter_is_found() -> None:
    listing = (
        "\nrule notebook_x:\n    input: /nb/x.ipynb, results/study/runs.parquet,"
        " results/raceline/T.npz\n    output: results/notebooks/x.ipynb\n"
        "Shell command: (papermill /nb/x.ipynb "
        "results/notebooks/x.ipynb.part.ipynb --cwd . -r runs_path results/study/runs.parquet"
        " > log 2>&1)\n"
    )
    jobs = notebook_jobs(listing)
    inputs, parameters = jobs["results/notebooks/x.ipynb"]
    assert parameters == {"runs_path": "results/study/runs.parquet"}
    assert unpassed(inputs, parameters) == ["results/raceline/T.npz"]
    assert unpassed(["results/models/rep0/dpm/meta.json"], {"model_root": "results/models"}) == []
    assert unpassed(["results/models2/x"], {"model_root": "results/models"}) == [
        "results/models2/x"
    ]


@pytest.fixture(scope="module")
def dry_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """`snakemake -n -p` of both targets' notebooks in an empty folder (every job planned)."""
    work = tmp_path_factory.mktemp("plan")
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    (work / "config.yaml").write_text(yaml.safe_dump(config))
    result = subprocess.run(
        ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), "-n", "-p", "--cores", "1",
         "study", "replicates", "--configfile", str(work / "config.yaml"),
         str(REPO_ROOT / "config" / "smoke.yaml")],
        cwd=work, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout, work


def test_every_notebook_rule_passes_every_input(dry_run: tuple[str, Path]) -> None:
    jobs = notebook_jobs(*dry_run)
    executed = {Path(p).name for p in jobs}
    # every notebook of both targets is planned: setup, each study's, failures, both scorecards
    assert {"setup.ipynb", "learned.ipynb", "truth.ipynb", "bicycle.ipynb", "ablation.ipynb",
            "failures_learned.ipynb", "scorecard.ipynb"} <= executed  # fmt: skip
    assert sum(p.endswith("scorecard.ipynb") for p in jobs) == 2
    missing = {job: unpassed(*jobs[job]) for job in jobs}
    assert not any(missing.values()), {job: m for job, m in missing.items() if m}
