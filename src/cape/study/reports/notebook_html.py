"""The HTML copy of an executed notebook, made for reading: papermill's parameters in one line
each, and a page title that names the notebook.

A long parameter (a list of run files, or config sections given as JSON) is thousands of
characters on one line: papermill writes it into the cell it injects (tagged
``injected-parameters``), the right record in the executed ``.ipynb`` but a wall at the top of
the page a user opens. The HTML copy keeps that cell, as it keeps all the code, with each long
string replaced by a short line saying what it held. nbconvert runs
:class:`ShortParameters` when the workflow converts a notebook
(``--HTMLExporter.preprocessors=cape.study.reports.notebook_html.ShortParameters``).
"""

from __future__ import annotations

import ast
import json
from typing import Any

from nbconvert.preprocessors import Preprocessor
from nbformat import NotebookNode

INJECTED = "injected-parameters"
"""The tag papermill gives the cell of parameters it injects."""

LONG = 120
"""Characters beyond which a parameter's string value is summarised in the HTML copy."""

PAPERMILL_HEADER = "# Parameters"
HEADER = "# Parameters passed by the workflow (papermill): they replace the defaults above"


def _summary(value: str, record: str) -> str:
    """What a long string parameter held: the config sections of a JSON object, by name; the
    number of files of a comma-separated list of paths."""
    try:
        parsed = json.loads(value)
    except ValueError:
        parsed = None
    where = f"{len(value):,} characters, in full in {record}"
    if isinstance(parsed, dict):
        return f"JSON of the config sections {', '.join(map(str, parsed))} ({where})"
    items = value.split(",")
    if len(items) > 1 and all(item and " " not in item for item in items):
        return f"{len(items)} files, the first {items[0]} ({where})"
    return where


def short_parameters(source: str, record: str = "the executed .ipynb", limit: int = LONG) -> str:
    """``source`` (papermill's injected cell) with each assignment of a string longer than
    ``limit`` written as ``name = "…"`` and a comment naming what it held, and papermill's
    header saying where the values come from; the other lines as they are. ``record`` names
    the file that keeps the full value."""
    try:
        tree = ast.parse(source)
    except SyntaxError:  # not Python: leave it to be read as it is
        return source
    lines = source.splitlines()
    for node in reversed(tree.body):  # from the end, so that earlier line numbers still hold
        if not (
            isinstance(node, ast.Assign)
            and len(node.targets) == 1
            and isinstance(node.targets[0], ast.Name)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
            and len(node.value.value) > limit
        ):
            continue
        short = f'{node.targets[0].id} = "…"  # {_summary(node.value.value, record)}'
        lines[node.lineno - 1 : node.end_lineno or node.lineno] = [short]
    return "\n".join(HEADER if line == PAPERMILL_HEADER else line for line in lines)


def notebook_name(resources: dict[str, Any]) -> str:
    """The executed notebook's name: nbconvert's, less the workflow's temporary ``.part.ipynb``
    suffix (the notebook is converted before it is renamed)."""
    name = str(resources.get("metadata", {}).get("name", "notebook"))
    return name.removesuffix(".part").removesuffix(".ipynb")


def first_heading(nb: NotebookNode) -> str:
    """The text of the notebook's first Markdown heading, or "" if it has none."""
    for cell in nb.cells:
        if cell.cell_type != "markdown":
            continue
        for line in cell.source.splitlines():
            if line.startswith("#"):
                return line.lstrip("#").strip()
    return ""


class ShortParameters(Preprocessor):
    """nbconvert preprocessor: papermill's long parameters summarised (:func:`short_parameters`)
    and the page titled "<notebook> — <first heading>" (nbconvert's own title would be the
    temporary file's name)."""

    def preprocess(
        self, nb: NotebookNode, resources: dict[str, Any]
    ) -> tuple[NotebookNode, dict[str, Any]]:
        name = notebook_name(resources)
        for cell in nb.cells:
            if cell.cell_type == "code" and INJECTED in cell.metadata.get("tags", []):
                cell.source = short_parameters(cell.source, f"{name}.ipynb")
        heading = first_heading(nb)
        nb.metadata["title"] = f"{name} — {heading}" if heading else name
        return nb, resources
