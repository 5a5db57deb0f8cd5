"""A published question re-derives from its data (issue 59): `cape question --from FOLDER`
re-decides every look from values.csv and looks.json alone, gives the published looks.csv,
and notices a value changed enough to flip a verdict."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from commands import cape, one_message

from cape.config import REPO_ROOT
from cape.study.question.looks import RowState, evaluate, values_frame, values_from_frame
from cape.study.question.plan import QuestionSettings
from cape.study.question.report import looks_frame
from cape.study.question.state import QuestionState

MARGINS = {"lap_time_penalised": 0.2, "mean_abs_ex_penalised": 10.0,
           "mean_abs_ey_penalised": 10.0, "mean_speed": 3.0, "failures": 1.0}  # fmt: skip
SETTINGS = QuestionSettings(("epm", "dpm"), (3, 6), 0.05, 2.0, MARGINS, "truth", ("0", "1"), 5,
                            2, 1000, 0.05, None)  # fmt: skip
PUBLISHED = REPO_ROOT / "docs" / "results" / "question"


def _values(rng: np.random.Generator) -> pd.DataFrame:
    """Per (metric, model, draw, seed): EPM laps 1 s faster than DPM with little spread (a row
    that holds), everything else alike."""
    records = []
    for row in SETTINGS.rows():
        if row.pair.a != "epm":
            continue
        for model in SETTINGS.models:
            for draw in range(6):
                for seed in range(draw * 1000, draw * 1000 + 5):
                    if row.metric == "failures":
                        value = float(rng.poisson(2.0))
                    elif row.metric == "lap_time_penalised":
                        value = (7.0 if model == "epm" else 8.0) + rng.normal(0, 0.01)
                    else:
                        value = float(np.exp(rng.normal(0, 0.3)))
                    records.append((row.name, model, draw, seed, value))
    return pd.DataFrame(records, columns=["metric", "model", "draw", "seed", "value"])


def _folder(tmp_path: Path) -> Path:
    """A question folder as `cape question --publish` writes it, looked at twice."""
    values = _values(np.random.default_rng(5))
    design = SETTINGS.design()
    states = [RowState(row) for row in SETTINGS.rows()]
    lines = []
    for k, n in enumerate(SETTINGS.stages):
        evaluate(values_from_frame(values), states, design, k, 5)
        lines.append({"stage": k + 1, "look at draws": n, "wall_s": 1.0, "most seeds": 5})
    folder = tmp_path / "published"
    folder.mkdir()
    values.to_csv(folder / "values.csv", index=False)
    looks_frame(states).to_csv(folder / "looks.csv", index=False)
    state = QuestionState(SETTINGS.identity({}), [5] * 6, lines)
    (folder / "looks.json").write_text(state.as_json())
    return folder


def test_a_published_question_rederives_exactly(tmp_path: Path) -> None:
    folder = _folder(tmp_path)
    looks = pd.read_csv(folder / "looks.csv")
    assert (looks["decision"] == "holds").any()  # the lap-time row
    result = cape("question", "--from", str(folder))
    assert result.returncode == 0, result.stderr
    assert "every decision and number identical to looks.csv" in result.stdout


def test_a_changed_value_that_flips_a_verdict_is_noticed(tmp_path: Path) -> None:
    """One EPM lap of draw 1 made 40 s slower: the lap-time row no longer holds at its first
    look, and the re-derivation says so in one line (exit 2), naming the row and both
    decisions."""
    folder = _folder(tmp_path)
    values = pd.read_csv(folder / "values.csv")
    lap = values["metric"].str.startswith("adaptive NMPC lap time")
    target = values.index[lap & (values["model"] == "epm") & (values["draw"] == 1)][0]
    values.loc[target, "value"] += 40.0
    values.to_csv(folder / "values.csv", index=False)
    refused = one_message(cape("question", "--from", str(folder)), "differs", "adaptive NMPC")
    assert "published 'holds'" in refused


def test_the_values_table_round_trips() -> None:
    values = _values(np.random.default_rng(1))
    again = values_frame(values_from_frame(values))
    key = ["metric", "model", "draw", "seed"]
    pd.testing.assert_frame_equal(
        again.sort_values(key).reset_index(drop=True),
        values.sort_values(key).reset_index(drop=True),
    )


def test_a_folder_without_its_data_is_one_line(tmp_path: Path) -> None:
    one_message(cape("question", "--from", str(tmp_path)), "looks.csv not found")


@pytest.mark.skipif(not (PUBLISHED / "looks.json").is_file(), reason="no published question")
def test_the_published_question_rederives() -> None:
    """docs/results/question/ (the real question, published) re-derives from its own data."""
    result = cape("question", "--from", str(PUBLISHED))
    assert result.returncode == 0, result.stderr
    state = json.loads((PUBLISHED / "looks.json").read_text())
    assert state["looks"], "a published question has a look"
