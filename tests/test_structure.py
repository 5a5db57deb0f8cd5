"""The house's rooms (issue 60): commands that only parse, call and print; no folder crowded
with modules; and the two documents that name every module, checked against the tree."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from cape.config import REPO_ROOT

SRC = REPO_ROOT / "src" / "cape"
MOST_MODULES = 16
"""The most modules (``.py`` files, ``__init__.py`` included) a folder of src/cape holds."""
COMMAND_LINES, QUESTION_LINES = 40, 30
"""The most lines a function of src/cape/cli/ and ``cmd_question`` run to."""


def _functions(path: Path) -> dict[str, int]:
    """Every function of ``path`` (methods and nested ones too) → its lines, decorators aside."""
    return {
        node.name: node.end_lineno - node.lineno + 1
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
    }


def test_the_commands_only_parse_call_and_print() -> None:
    sizes = {f"{path.name}:{name}": lines for path in sorted((SRC / "cli").glob("*.py"))
             for name, lines in _functions(path).items()}  # fmt: skip
    assert sizes["question.py:cmd_question"] <= QUESTION_LINES, sizes["question.py:cmd_question"]
    long = {name: lines for name, lines in sizes.items() if lines > COMMAND_LINES}
    assert not long, f"functions of src/cape/cli/ over {COMMAND_LINES} lines: {long}"


def test_no_folder_holds_more_than_16_modules() -> None:
    folders = {SRC, *(p for p in SRC.rglob("*") if p.is_dir() and p.name != "__pycache__")}
    crowded = {str(f.relative_to(SRC.parent)): n for f in folders
               if (n := len(list(f.glob("*.py")))) > MOST_MODULES}  # fmt: skip
    assert not crowded, crowded


def _modules() -> set[str]:
    """Every module of src/cape, as the docs name it: ``cape/study/grid.py``."""
    return {str(p.relative_to(SRC.parent)) for p in SRC.rglob("*.py")}


MODULE = re.compile(r"(?<![\w/])cape/[\w/]+\.py\b")


def _named(doc: str) -> set[str]:
    return set(MODULE.findall((REPO_ROOT / "docs" / doc).read_text()))


def test_the_module_list_of_architecture_md_is_the_tree() -> None:
    """docs/architecture.md's "Every module" names each module of src/cape once, and nothing
    else: a module added, moved or removed is said there in the same change."""
    text = (REPO_ROOT / "docs" / "architecture.md").read_text()
    section = text.split("## Every module", 1)[1].split("\n## ", 1)[0]
    listed = re.findall(r"^\| `(cape/[\w/]+\.py)` \|", section, re.MULTILINE)
    assert len(listed) == len(set(listed)), "a module listed twice"
    assert set(listed) == _modules(), {
        "not listed": sorted(_modules() - set(listed)),
        "no such module": sorted(set(listed) - _modules()),
    }


def test_the_docs_name_only_modules_that_exist() -> None:
    """Every ``cape/….py`` that docs/architecture.md and docs/modules.md name is a module of the
    tree, and every module has its line in the two together."""
    named = _named("architecture.md") | _named("modules.md")
    assert named <= _modules(), sorted(named - _modules())
    assert _modules() <= named, sorted(_modules() - named)
