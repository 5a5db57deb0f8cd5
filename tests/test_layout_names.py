"""The file names inside a run, model, training or study folder are spelled once, in
cape/layout: a rule, command, loader, notebook or benchmark that joins one to a folder reads it
from there (prose that names a file, in a message or a help text, may say it)."""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

from cape.config import REPO_ROOT
from cape.layout import paths

NAMES = (*paths.MODEL_FILES, *paths.BESIDE_A_MODEL, paths.METRICS, paths.TIMING, paths.SERIES,
         paths.RUNS_TABLE, paths.SUMMARY_TABLE)  # fmt: skip
JOINED = re.compile(r"(^|/)({})$".format("|".join(map(re.escape, NAMES))))


def _docstrings(tree: ast.AST) -> set[int]:
    return {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
    }


def _python_spellings(source: str) -> list[str]:
    """String constants (not docstrings) that are a file name or end in ``/<name>``."""
    tree = ast.parse(source)
    skip = _docstrings(tree)
    return [
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in skip
        and JOINED.search(node.value.strip())
    ]


def _spellings(path: Path) -> list[str]:
    if path.suffix == ".py":
        return _python_spellings(path.read_text())
    if path.suffix == ".ipynb":
        cells = json.loads(path.read_text())["cells"]
        code = ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]
        return [s for source in code for s in _python_spellings(source)]
    prose = re.sub(r'"""[\s\S]*?"""', "", path.read_text())  # a .smk file, less its docstrings
    lines = (line.split("#")[0] for line in prose.splitlines())
    return [w for line in lines for w in re.findall(r"[\w{}./]*\.\w+", line) if JOINED.search(w)]


def test_no_file_name_of_the_layout_is_spelled_outside_it() -> None:
    roots = [REPO_ROOT / d for d in ("src", "workflow", "notebooks", "benchmarks")]
    layout = REPO_ROOT / "src" / "cape" / "layout"
    files = [
        p
        for root in roots
        for p in root.rglob("*")
        if p.suffix in (".py", ".ipynb", ".smk") and layout not in p.parents
    ]
    assert len(files) > 50  # the scan sees the tree
    found = {str(p.relative_to(REPO_ROOT)): s for p in files if (s := _spellings(p))}
    assert found == {}


def test_the_scan_finds_a_spelling() -> None:
    assert _python_spellings('x = folder / "meta.json"') == ["meta.json"]
    assert _python_spellings('x = f"{folder}/loss.csv"') == ["/loss.csv"]
    assert _python_spellings('"""Reads meta.json."""\nhelp = "its meta.json, loss.csv"') == []
