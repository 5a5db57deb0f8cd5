"""Writing result tables: CSV for machines, Markdown for people (LaTeX where the paper has one).

All files are written atomically. Numbers keep full precision in CSV; Markdown and LaTeX use
a per-column format so that a table reads like the paper's.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cape.storage.io import write_files

Formatter = Callable[[Any], str]


def _formatted(
    frame: pd.DataFrame, formats: Mapping[str, str | Formatter] | None
) -> list[list[str]]:
    formats = formats or {}
    rows = []
    for _, record in frame.iterrows():
        cells = []
        for column in frame.columns:
            value, fmt = record[column], formats.get(column)
            if callable(fmt):
                cells.append(fmt(value))
            elif fmt is not None and isinstance(value, int | float):
                cells.append(format(value, fmt))
            else:
                cells.append(str(value))
        rows.append(cells)
    return rows


def number(value: Any) -> str:
    """Four significant digits; a missing value (no CI from one seed, no lap) as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def number_formats(frame: pd.DataFrame) -> dict[str, Formatter]:
    """Per column, how a table's Markdown and LaTeX copies print it: numbers by ``number``."""
    return dict.fromkeys(frame.select_dtypes("number").columns, number)


def to_markdown(frame: pd.DataFrame, formats: Mapping[str, str | Formatter] | None = None) -> str:
    header = "| " + " | ".join(map(str, frame.columns)) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    body = ["| " + " | ".join(cells) + " |" for cells in _formatted(frame, formats)]
    return "\n".join([header, rule, *body]) + "\n"


def to_html(frame: pd.DataFrame, formats: Mapping[str, str | Formatter] | None = None) -> str:
    """An HTML table of the cells the Markdown copy prints, for a notebook to show a table as it
    was saved (pandas would print NaN, six decimals and its row index). Number columns are
    right-aligned, text columns left-aligned: a long claim reads from its start."""
    numbers = set(frame.select_dtypes("number").columns)
    align = [f' style="text-align: {"right" if c in numbers else "left"}"' for c in frame.columns]

    def row(tag: str, cells: Sequence[str]) -> str:
        pairs = zip(cells, align, strict=True)
        return "<tr>" + "".join(f"<{tag}{a}>{html.escape(v)}</{tag}>" for v, a in pairs) + "</tr>"

    head = row("th", [str(c) for c in frame.columns])
    body = "".join(row("td", cells) for cells in _formatted(frame, formats))
    return f'<table class="dataframe"><thead>{head}</thead><tbody>{body}</tbody></table>'


def to_latex(
    frame: pd.DataFrame, formats: Mapping[str, str | Formatter] | None = None, caption: str = ""
) -> str:
    escape = lambda s: str(s).replace("_", r"\_").replace("%", r"\%")  # noqa: E731
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\begin{tabular}{" + "l" * len(frame.columns) + "}",
        r"\hline",
        " & ".join(escape(c) for c in frame.columns) + r" \\",
        r"\hline",
        *(" & ".join(escape(c) for c in cells) + r" \\" for cells in _formatted(frame, formats)),
        r"\hline",
        r"\end{tabular}",
    ]
    if caption:
        lines.append(r"\caption{" + escape(caption) + "}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def write_table(
    frame: pd.DataFrame,
    paths: Sequence[str | Path],
    formats: Mapping[str, str | Formatter] | None = None,
    caption: str = "",
    csv_only: Sequence[str] = (),
) -> None:
    """Write ``frame`` to each path, the format chosen by its suffix (.csv, .md, .tex): all
    or none (``cape.storage.io.write_files``). ``csv_only``: columns for programs, not for readers
    (e.g. a model's weights digest), left out of the .md and .tex copies."""
    texts: dict[str | Path, bytes] = {}
    shown = frame.drop(columns=[c for c in csv_only if c in frame.columns])
    for path in paths:
        suffix = Path(path).suffix
        if suffix == ".csv":
            text = frame.to_csv(index=False, float_format="%.10g")
        elif suffix == ".md":
            text = (f"{caption}\n\n" if caption else "") + to_markdown(shown, formats)
        elif suffix == ".tex":
            text = to_latex(shown, formats, caption)
        else:
            raise ValueError(f"{path}: unsupported table format {suffix!r} (use .csv, .md or .tex)")
        texts[path] = text.encode("utf-8")
    write_files(texts)
