"""``from_config`` is the only door into the config: the config dictionary is indexed only by
``cape.config`` (which loads it, fills in the schema's defaults and checks it), the typed
specifications' builders in ``cape/specs`` (each ``from_config``) and the workflow's job-file
writers (``cape/workflow/job_files.py``, which copy the sections a job reads into its file:
JSON in, JSON out). Nowhere else in src, the workflow's rules or the notebooks: the code below
them takes a spec.

The scan (``_reads``) reads each module's syntax tree for what indexes a config: a subscript of
a name that holds one (``config``, ``cfg``, or one ending in ``_config`` or ``_cfg``, or such an
attribute: ``self.config``), a ``.get`` on it, or ``section(config, ...)``. Passing the config on
(``Spec.from_config(config)``) is not indexing it. A builder elsewhere (a ``from_config`` outside
cape/specs) is no exception: it hands the config to a spec.
"""

from __future__ import annotations

import ast
import json
import re

from cape.config import REPO_ROOT

ALLOWED = ("src/cape/config.py", "src/cape/specs/", "src/cape/workflow/job_files.py")
"""Where the config may be indexed (the module docstring says why)."""


def _holds_config(name: str) -> bool:
    return name in ("config", "cfg") or name.endswith(("_config", "_cfg"))


def _is_config(node: ast.AST) -> bool:
    if isinstance(node, ast.Name):
        return _holds_config(node.id)
    return isinstance(node, ast.Attribute) and _holds_config(node.attr)


def _reads(source: str) -> list[int]:
    """The lines that index a config: a subscript, a ``.get``, ``section(config, ...)``."""
    found: list[int] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Subscript) and _is_config(node.value):
            found.append(node.lineno)
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")
            if (name in ("section", "setting") and node.args and _is_config(node.args[0])) or (
                name == "get" and isinstance(func, ast.Attribute) and _is_config(func.value)
            ):
                found.append(node.lineno)
    return sorted(found)


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
    assert _reads('def f(data_cfg):\n    return data_cfg["steps"]') == [2]
    assert _reads('def from_config(config):\n    return config["study"]') == [2]  # no exception
    assert _reads("spec = RunSpec.from_config(config, name)") == []  # handing it on
    assert _smk_reads('x = config["study"]  # a rule') == [1]
