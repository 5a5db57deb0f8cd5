"""Table output: CSV, Markdown and LaTeX from one DataFrame, written atomically."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from cape.storage.tables import to_latex, to_markdown, write_table


def test_markdown_and_latex_formats() -> None:
    frame = pd.DataFrame(
        {"model": ["epm", "ddm"], "rmse_vx": [1.19e-4, 8.72e-5], "layers": [8, 17]}
    )
    md = to_markdown(frame, {"rmse_vx": ".2e"})
    assert md.splitlines() == [
        "| model | rmse_vx | layers |",
        "|---|---|---|",
        "| epm | 1.19e-04 | 8 |",
        "| ddm | 8.72e-05 | 17 |",
    ]
    tex = to_latex(frame, {"rmse_vx": ".2e"}, caption="Open loop")
    assert r"model & rmse\_vx & layers \\" in tex and r"epm & 1.19e-04 & 8 \\" in tex
    assert r"\caption{Open loop}" in tex


def test_write_table_by_suffix(tmp_path: Path) -> None:
    frame = pd.DataFrame({"a": [1.5], "b": ["x"]})
    paths = [tmp_path / "t.csv", tmp_path / "t.md", tmp_path / "t.tex"]
    write_table(frame, paths, caption="Caption.")
    assert pd.read_csv(paths[0]).equals(frame)
    assert paths[1].read_text().startswith("Caption.\n\n| a | b |")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv", "t.md", "t.tex"]
    with pytest.raises(ValueError, match="unsupported table format"):
        write_table(frame, [tmp_path / "t.xlsx"])
