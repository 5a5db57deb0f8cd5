"""The code base's floors: no module imports a package above its own (docs/architecture.md).

cli, workflow → study → plots → closedloop → controllers → training → models → data → tracks →
vehicle → specs (what a job reads) → config, registry, numerics → layout (every name and path) → the
bottom floor: errors, storage (the write policy), schemas, processes, …: the order in which a
run is built, each floor using only the ones below.
"""

from __future__ import annotations

import ast
from pathlib import Path

from cape.config import REPO_ROOT

FLOORS = [
    ("errors", "storage", "paper", "bytecode", "schemas", "processes"),
    ("layout",), ("config", "registry", "numerics"), ("specs",), ("vehicle",), ("tracks",),
    ("data",), ("models",), ("training",), ("controllers",), ("closedloop",), ("plots",),
    ("study",), ("cli", "workflow"),
]  # fmt: skip
LEVEL = {name: level for level, names in enumerate(FLOORS) for name in names}


def _imports(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.append(node.module)
        elif isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
    return [n for n in names if n.startswith("cape.")]


def test_no_module_imports_a_package_above_it() -> None:
    root = REPO_ROOT / "src" / "cape"
    upward = []
    for path in sorted(root.rglob("*.py")):
        own = path.relative_to(root).with_suffix("").parts[0]
        if own == "__init__":
            continue
        assert own in LEVEL, f"{path}: add package {own!r} to a floor of this test"
        for name in _imports(path):
            other = name.split(".")[1]
            if LEVEL.get(other, -1) > LEVEL[own]:
                upward.append(f"{path.relative_to(REPO_ROOT)} imports {name}")
    assert not upward, "\n".join(upward)
