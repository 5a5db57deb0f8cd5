"""A published study re-derives (docs/study.md, "A published study, re-derivable"): `cape
replicates --from` recomputes tables 8 and 9 from a published folder's evidence alone and
finds them equal to its tables, and notices one run's value changed enough to flip a verdict."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from commands import cape, one_message

from cape.config import REPO_ROOT

PUBLISHED = REPO_ROOT / "docs" / "results" / "replicates"


def _flip(folder: Path) -> str:
    """Change one run of ``folder``'s evidence so that a table-8 verdict over the draws must
    change: a run of the first model of a row that holds on the adaptive NMPC's lap time gets
    1000 s added (its draw's effect turns around). Returns the row's comparison."""
    table = pd.read_csv(folder / "tables" / "table08_scorecard.csv")
    pooled = "verdict (draws that trained)"
    rows = table[
        table["claim"].str.startswith("adaptive NMPC lap time")
        & table[pooled].eq("holds")
        & table["setting"].eq("paper")
    ]
    assert len(rows), "no row holds on the lap time: choose another value to change"
    comparison = str(rows.iloc[0]["comparison"])
    first = comparison.split(" ")[0].lower()
    values = pd.read_csv(folder / "evidence" / "values.csv", dtype={"eta_label": str})
    chosen = values.index[
        values["study"].eq("learned") & values["model"].eq(first) & values["controller"].eq("anmpc")
    ][0]
    values.loc[chosen, "lap_time_penalised"] += 1000.0
    values.to_csv(folder / "evidence" / "values.csv", index=False)
    return comparison


def test_the_published_replicated_study_rederives() -> None:
    result = cape("replicates", "--from", str(PUBLISHED), cwd=REPO_ROOT)
    assert result.returncode == 0, result.stderr
    assert "table08_scorecard" in result.stdout and "every verdict equal" in result.stdout


def test_a_changed_run_of_the_published_study_is_noticed(tmp_path: Path) -> None:
    copy = tmp_path / "replicates"
    shutil.copytree(PUBLISHED, copy)
    comparison = _flip(copy)
    result = cape("replicates", "--from", str(copy), cwd=REPO_ROOT)
    message = one_message(result)
    assert result.returncode == 2
    assert "verdict (draws that trained): published 'holds'" in message, message
    assert comparison in message or "table08_scorecard" in message


@pytest.mark.slow
def test_a_smoke_study_publishes_and_rederives(smoke_study: Path, tmp_path: Path) -> None:
    """Through the real commands on the smoke study: publish, re-derive, publish again over
    its own files; a user's file in the way is refused and left as it was."""
    folder = tmp_path / "published"
    args = ("replicates", "--publish", str(folder), "--configfile", "config/smoke.yaml")
    first = cape(*args, cwd=smoke_study)
    assert first.returncode == 0, first.stderr
    scope = smoke_study / "results" / "replicates"
    for name in ("table08_scorecard.csv", "table09_leaderboard.csv"):
        assert (folder / "tables" / name).read_bytes() == (scope / "tables" / name).read_bytes()
    again = cape("replicates", "--from", str(folder), cwd=smoke_study)
    assert again.returncode == 0, again.stderr
    assert cape(*args, cwd=smoke_study).returncode == 0  # its own earlier output: replaced
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "RESULTS.md").write_text("my notes\n")
    refused = cape("replicates", "--publish", str(mine), cwd=smoke_study)
    assert refused.returncode == 2 and "RESULTS.md" in one_message(refused)
    assert (mine / "RESULTS.md").read_text() == "my notes\n"
    assert cape("replicates", "--from", str(mine), cwd=smoke_study).returncode == 2
