"""Issue 53's smaller findings, each through the real command: a run given twice to
`cape aggregate`, an overflowing lap time in table 9, a bad config value under Snakemake."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml
from commands import cape, one_message, rollout, snakemake
from conftest import workdir
from test_leaderboard import LAPS, _runs

from cape.study.claims.leaderboard import leaderboard

RUN = Path("runs/truth/rep0/truth/truth/pid/eta0/seed0")


# --- 1. `cape aggregate` counts each run once ----------------------------------------------
def test_aggregate_refuses_a_run_given_twice(setup: dict, tmp_path: Path) -> None:
    """The same metrics.json twice (as two spellings of one path, or twice in --runs-from), or
    a copy of the same run in another folder, is refused in one line naming it, and no table
    is written; given once, the run is one row."""
    made = rollout(setup, tmp_path / RUN)
    assert made.returncode == 0, made.stderr
    metrics = RUN / "metrics.json"

    def aggregate(name: str, *runs: str) -> tuple:
        tables = tmp_path / name
        out, summary = tables / "runs.parquet", tables / "summary.parquet"
        args = ["aggregate", *runs, "--out", str(out), "--summary", str(summary),
                "--config", str(setup["config"])]  # fmt: skip
        return cape(*args, cwd=tmp_path), tables

    once, tables = aggregate("once", str(metrics))
    assert once.returncode == 0, once.stderr
    assert len(pd.read_parquet(tables / "runs.parquet")) == 1
    twice, tables = aggregate("twice", str(metrics), str(tmp_path / metrics))
    one_message(twice, f"{tmp_path / metrics}: given twice", "seed 0", "list it once")
    assert not tables.exists()
    listed = tmp_path / "runs.txt"
    listed.write_text(f"{metrics}\n{metrics}\n")
    from_file, tables = aggregate("listed", "--runs-from", str(listed))
    one_message(from_file, f"{metrics}: given twice")
    assert not tables.exists()
    shutil.copytree(tmp_path / RUN, tmp_path / "copy" / RUN)
    copied, tables = aggregate("copied", str(metrics), str(Path("copy") / metrics))
    one_message(copied, f"copy/{metrics}: the same run as {metrics}")
    assert not tables.exists()


# --- 2. table 9: an overflowing lap time is said for what it is ------------------------------
@pytest.mark.parametrize(
    ("lap", "said"),
    [(1e308, "1e+308 in draw 0, seed 0 is not a usable value (its mean and spread over the "
      "seeds and draws overflow)"),
     (math.inf, "inf in draw 0, seed 0 is not a usable value (not a finite number)")],
)  # fmt: skip
def test_an_overflowing_lap_time_is_not_a_missing_value(lap: float, said: str) -> None:
    """DDM's every lap time 1e308 (five seeds' mean overflows) or inf: its row is unranked and
    says which value is unusable, not "no value of the primary metric" (inf) nor an effect of
    inf with a verdict `higher` (1e308); with the reference's broken, every row says so."""
    runs = _runs()
    runs.loc[runs["model"] == "ddm", "lap_time_penalised"] = lap
    table = leaderboard(runs, list(LAPS), "epm", "anmpc_lap_time").set_index("model")
    ddm = table.loc["ddm"]
    assert pd.isna(ddm["rank"]) and ddm["verdict vs reference"] == "not evaluated"
    assert said in ddm["why"] and "no value" not in ddm["why"], ddm["why"]
    assert list(table["rank"].dropna()) == [1, 2, 3]  # the others ranked as before
    runs = _runs()
    runs.loc[runs["model"] == "epm", "lap_time_penalised"] = lap
    table = leaderboard(runs, list(LAPS), "epm", "anmpc_lap_time").set_index("model")
    assert said in table.loc["epm", "why"]
    others = table.drop(index="epm")
    assert set(others["verdict vs reference"]) == {"no reference runs"}
    assert others["why"].str.contains("EPM \\(study.reference_model\\): adaptive NMPC").all()


# --- 3. a config refused inside Snakemake: its reason, no traceback ---------------------------
def test_a_bad_config_value_under_snakemake_is_one_line_without_traceback(
    tmp_path: Path,
) -> None:
    """A value the config's validation refuses (cape.config, raised while Snakemake reads
    common.smk), given on the command line or in config/config.yaml: the one-line reason on
    stderr, exit status 1, none of Snakemake's `File "…"` lines."""
    work = workdir(tmp_path)
    given = snakemake("-n", "-d", str(work), "--config", 'training={"threads": "x"}')
    config = work / "config" / "config.yaml"
    cfg = yaml.safe_load(config.read_text())
    cfg["training"]["threads"] = 0
    config.write_text(yaml.safe_dump(cfg))
    for result in (given, snakemake("-n", "-d", str(work))):
        out = result.stdout + result.stderr
        assert result.returncode == 1, out
        reason = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
        assert len(reason) == 1 and "field `training.threads`" in reason[0], out
        assert "Fix the value" in result.stderr, out
        assert not [line for line in out.splitlines() if line.startswith('  File "')], out
        assert "Traceback" not in out and "CapeError" not in out, out
