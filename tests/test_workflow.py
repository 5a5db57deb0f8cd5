"""The Snakemake workflow: lint-clean, plans the targets, and fails clearly without data."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from cape.config import REPO_ROOT

SNAKEFILE = REPO_ROOT / "Snakefile"


def _snakemake(
    *args: str, cwd: Path = REPO_ROOT, timeout: float = 600
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["snakemake", "-s", str(SNAKEFILE), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _workdir(tmp_path: Path, **track_overrides: object) -> Path:
    """A scratch working directory with its own config (absolute mirror path)."""
    work = tmp_path / "work"
    (work / "config").mkdir(parents=True)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    mirror = cfg["tracks"]["mirror"]
    cfg["tracks"]["mirror"] = str((REPO_ROOT / mirror).resolve()) if mirror else None
    cfg["tracks"].update(track_overrides)
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    return work


def test_lint_is_clean() -> None:
    result = _snakemake("--lint")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Congratulations" in result.stdout + result.stderr


def test_dry_run_plans_every_target() -> None:
    result = _snakemake("-n", "--cores", "2", "--forceall")
    assert result.returncode == 0, result.stderr
    out = result.stdout + result.stderr
    for rule in ("tracks", "dataset", "figure_tracks", "all"):
        assert rule in out


def test_data_targets_build_and_match_fingerprints(tmp_path: Path) -> None:
    import numpy as np

    work = _workdir(tmp_path)
    targets = ["results/data/DYN-PP-ETHZ.npz", "results/data/DYN-PP-ETHZMobil.npz"]
    result = _snakemake("--cores", "2", "-d", str(work), *targets)
    assert result.returncode == 0, result.stdout + result.stderr
    with np.load(work / targets[0]) as ethz:
        np.testing.assert_allclose(ethz["inputs"][:, 999], [-0.0054280906, -0.1095121], atol=1e-9)
    # a second run has nothing to do
    again = _snakemake("--cores", "2", "-d", str(work), *targets)
    assert "Nothing to be done" in again.stdout + again.stderr


def test_no_mirror_and_no_network_fails_with_the_clear_message(tmp_path: Path) -> None:
    work = _workdir(
        tmp_path, mirror=str(tmp_path / "absent"), upstream_url="http://127.0.0.1:9/{file}"
    )
    result = _snakemake("--cores", "1", "-d", str(work), "results/data/DYN-PP-ETHZ.npz")
    out = result.stdout + result.stderr
    assert result.returncode != 0
    assert "cannot obtain track file" in out
    assert "tracks.mirror" in out and "upstream commit" in out
    assert not (work / "results" / "data" / "DYN-PP-ETHZ.npz").exists()


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff is installed by requirements.txt")
def test_code_is_ruff_clean() -> None:
    result = subprocess.run(
        ["ruff", "check", "src", "tests", "benchmarks"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout


def test_smoke_config_builds_the_model_tables(tmp_path: Path) -> None:
    """Two-epoch training of every model through the real rules, then both model tables."""
    import pandas as pd

    work = _workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    targets = [
        "results/tables/table01_model_complexity.csv",
        "results/tables/table04_openloop_rmse.csv",
    ]
    result = _snakemake(
        "--cores", "2", "-d", str(work), *targets, "--configfile", "config/smoke.yaml"
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    complexity = pd.read_csv(work / targets[0])
    assert list(complexity["model"]) == ["dpm", "ddm", "epm"]
    assert complexity["params_M"].tolist() == pytest.approx(
        [0.028851, 2.878035, 0.917828], abs=1e-6
    )
    openloop = pd.read_csv(work / targets[1])
    assert (
        (openloop.filter(like="rmse").drop(columns=openloop.filter(like="paper").columns) > 0)
        .all()
        .all()
    )


@pytest.mark.slow
def test_the_smoke_study_builds_every_table_figure_and_notebook(tmp_path: Path) -> None:
    """The whole workflow on the smoke slice, from nothing: every output of `snakemake` exists,
    every notebook ran, and every run of the grid is in the aggregated table. CI runs this."""
    import pandas as pd

    work = _workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    # about 4 minutes on 2 idle cores; the timeout only guards against a hang
    result = _snakemake(
        "--cores", "2", "-d", str(work), "--configfile", "config/smoke.yaml", timeout=1800
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    runs = pd.read_parquet(work / "results/study/runs.parquet")
    assert set(runs["study"]) == {"learned", "bicycle", "ablation", "truth"}
    # the smoke grid by hand (config/smoke.yaml; one seed; PID and RISE have no internal model):
    # learned 3 plants × 5 controllers × 2 η; bicycle 3 × 2 × 2; ablation 3 plants × 3 internal
    # × nominal NMPC × η 0; truth (PID + 2 NMPCs × 2 internal models) × 2 η
    expected = 3 * 5 * 2 + 3 * 2 * 2 + 3 * 3 * 1 * 1 + (1 + 2 * 2) * 2
    assert len(runs) == expected == 61 and runs["seed"].eq(0).all()
    # the ablation's diagonal (internal = plant: 3 runs) is the learned study's, computed once
    assert len(list((work / "results/runs").rglob("metrics.json"))) == expected - 3
    assert "# CAPE results at a glance" in (work / "results/RESULTS.md").read_text()
    assert set(runs["eta_label"]) == {"0", "1"}
    figures = sorted((work / "results/figures").rglob("fig*.png"))
    numbers = {p.name[3:5] for p in figures}
    assert numbers == {f"{n:02d}" for n in range(1, 13)}, numbers
    assert all(p.stat().st_size > 10_000 for p in figures)
    tables = {p.name[5:7] for p in (work / "results/tables").rglob("table*.md")}
    assert tables == {f"{n:02d}" for n in range(1, 9)}, tables
    studies = ("learned", "truth", "bicycle", "ablation")
    for name in ("setup", "scorecard", *studies, *(f"failures_{s}" for s in studies)):
        assert (work / "results/notebooks" / f"{name}.ipynb").is_file()
        assert (work / "results/notebooks" / f"{name}.html").stat().st_size > 10_000
    scorecard = pd.read_csv(work / "results/tables/table08_scorecard.csv")
    assert {"paper", "ours", "ci95", "holds"} <= set(scorecard.columns)
