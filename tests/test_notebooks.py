"""What a user reads in the executed notebooks: the HTML copy's short parameters, tables shown as
saved, and each figure under the heading its declaration gives it."""

from __future__ import annotations

import ast
import json

import nbformat
import pandas as pd
import pytest

from cape.config import REPO_ROOT
from cape.storage.tables import to_html, to_markdown
from cape.study.reports.notebook import show_table
from cape.study.reports.notebook_html import HEADER, ShortParameters, short_parameters
from cape.study.reports.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS, figure_heading


def _injected(config: dict) -> str:
    """An injected-parameters cell as papermill writes it."""
    return "\n".join(
        [
            "# Parameters",
            'study = "learned"',
            f"config_json = {json.dumps(json.dumps(config))}",
            'figure_dir = "results/figures/learned"',
            "",
        ]
    )


def test_the_html_copy_names_the_config_sections_instead_of_printing_their_json() -> None:
    config = {"controllers": {"pid": {"kp": list(range(200))}}, "models": {}, "study": {}}
    short = short_parameters(_injected(config), "learned.ipynb")
    lines = short.splitlines()
    assert lines[0] == HEADER
    assert lines[1] == 'study = "learned"'
    assert lines[2].startswith('config_json = "…"  # JSON of the config sections ')
    assert "controllers, models, study" in lines[2] and "learned.ipynb" in lines[2]
    assert lines[3] == 'figure_dir = "results/figures/learned"'
    assert max(map(len, lines)) < 120
    ast.parse(short)  # still code, as the page shows it


def test_a_long_list_of_paths_is_summarised_by_its_count() -> None:
    paths = ",".join(f"results/runs/learned/rep0/epm/epm/pid/eta0/seed{s}/timeseries.parquet"
                     for s in range(5))  # fmt: skip
    short = short_parameters(f'# Parameters\nseries_paths = "{paths}"\n', "learned.ipynb")
    assert short.splitlines()[1].startswith('series_paths = "…"  # 5 files, the first results/')


def test_short_parameters_leave_short_values_and_other_code_alone() -> None:
    source = '# Parameters\nstudy = "bicycle"\neta_table = 1.0\nnote = "' + "x" * 50 + '"'
    assert short_parameters(source).splitlines()[1:] == source.splitlines()[1:]
    assert short_parameters("not python (") == "not python ("


def test_the_preprocessor_rewrites_only_the_injected_cell_and_titles_the_page() -> None:
    nb = nbformat.v4.new_notebook()
    long = _injected({"models": {"x": "y" * 300}})
    nb.cells = [
        nbformat.v4.new_markdown_cell("# Closed-loop results of one study\n\ntext"),
        nbformat.v4.new_code_cell(long, metadata={"tags": ["parameters"]}),
        nbformat.v4.new_code_cell(long, metadata={"tags": ["injected-parameters"]}),
    ]
    out, _ = ShortParameters().preprocess(nb, {"metadata": {"name": "learned.ipynb.part"}})
    assert out.cells[1].source == long
    assert "JSON of the config sections models" in out.cells[2].source
    assert "in full in learned.ipynb" in out.cells[2].source
    assert out.metadata["title"] == "learned — Closed-loop results of one study"


def test_a_table_shows_the_cells_of_its_saved_markdown() -> None:
    frame = pd.DataFrame(
        {"model": ["dpm", "epm"], "lap time (s)": [7.04123, float("nan")], "n": [1, 2]}
    )
    formats = {"lap time (s)": lambda v: "–" if v != v else f"{v:.4g}"}
    html = to_html(frame, formats)
    assert "NaN" not in html and "nan" not in html
    assert '<td style="text-align: right">–</td>' in html
    assert '<td style="text-align: right">7.041</td>' in html
    assert '<td style="text-align: left">dpm</td>' in html
    assert "| epm | – | 2 |" in to_markdown(frame, formats)


def test_outside_ipython_showing_a_table_is_silent(capsys: pytest.CaptureFixture[str]) -> None:
    show_table(pd.DataFrame({"a": [1.0]}))
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("notebook", [*STUDY_NOTEBOOKS, *WHOLE_STUDY_NOTEBOOKS])
def test_each_figure_is_drawn_under_the_heading_its_declaration_gives(notebook: str) -> None:
    """The report labels a figure with its declared title; the notebook shows it under the
    same heading, in the declared order."""
    declared = {**STUDY_NOTEBOOKS, **WHOLE_STUDY_NOTEBOOKS}[notebook]
    nb = nbformat.read(REPO_ROOT / "notebooks" / f"{notebook}.ipynb", as_version=4)
    headings = [
        line.removeprefix("## ")
        for cell in nb.cells
        if cell.cell_type == "markdown"
        for line in cell.source.splitlines()
        if line.startswith("## Figure")
    ]
    assert headings == [figure_heading(n, t) for n, t in declared.figures.items()]
