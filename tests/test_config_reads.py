"""The config dictionary is read in one place: cape.config (loading and validating it), the
typed specifications' builders (cape/specs, cape/workflow/job_files.py, any ``from_config``) and
nowhere else in src, the workflow's rules or the notebooks; the code below them takes a spec."""

from __future__ import annotations

import ast
import json
import re

from cape.config import REPO_ROOT

CONFIG_NAMES = {"config", "cfg"}
BUILDERS = {"from_config"}
ALLOWED = ("src/cape/config.py", "src/cape/specs/", "src/cape/workflow/job_files.py")


def _is_config(node: ast.AST) -> bool:
    if isinstance(node, ast.Name):
        return node.id in CONFIG_NAMES
    return isinstance(node, ast.Attribute) and node.attr in CONFIG_NAMES


def _reads(source: str) -> list[int]:
    """Lines that index the config or ask `section` for one of it, outside a builder."""
    found: list[int] = []

    def visit(node: ast.AST, builder: bool) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            builder = builder or node.name in BUILDERS
        if not builder:
            if isinstance(node, ast.Subscript) and _is_config(node.value):
                found.append(node.lineno)
            elif isinstance(node, ast.Call):
                func = node.func
                name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")
                if (name == "section" and node.args and _is_config(node.args[0])) or (
                    name == "get" and isinstance(func, ast.Attribute) and _is_config(func.value)
                ):
                    found.append(node.lineno)
        for child in ast.iter_child_nodes(node):
            visit(child, builder)

    visit(ast.parse(source), False)
    return found


def _smk_reads(text: str) -> list[int]:
    code = [line.split("#")[0] for line in text.splitlines()]
    return [n for n, line in enumerate(code, 1) if re.search(r"\bconfig(\[|\.get\()", line)]


def test_the_config_is_read_only_by_its_builders() -> None:
    found: dict[str, list[int]] = {}
    for path in sorted((REPO_ROOT / "src").rglob("*.py")):
        rel = str(path.relative_to(REPO_ROOT))
        if not rel.startswith(ALLOWED) and (lines := _reads(path.read_text())):
            found[rel] = lines
    for path in sorted((REPO_ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        source = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        if lines := _reads(source):
            found[str(path.relative_to(REPO_ROOT))] = lines
    for path in [REPO_ROOT / "Snakefile", *sorted((REPO_ROOT / "workflow").rglob("*.smk"))]:
        if lines := _smk_reads(path.read_text()):
            found[str(path.relative_to(REPO_ROOT))] = lines
    assert found == {}


def test_the_scan_finds_a_read() -> None:
    assert _reads('x = config["study"]') == [1]
    assert _reads('x = section(config, "study")') == [1]
    assert _reads("x = self.config.get('plan')") == [1]
    assert _reads('def from_config(config):\n    return config["study"]') == []
