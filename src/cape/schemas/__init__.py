"""The JSON schemas CAPE validates against, shipped inside the package.

``config.schema.yaml`` describes ``config/config.yaml``; ``metrics.schema.yaml`` a run's
``metrics.json``. They are package data, so ``cape`` validates the same way from a checkout,
an editable install or a plain ``pip install .``.
"""

from __future__ import annotations

import sys
from functools import cache
from importlib import resources
from typing import Any

CONFIG = "config.schema.yaml"
METRICS = "metrics.schema.yaml"
SHOWN_AS = "cape/schemas/{name}"
"""How a message names a schema: its place in the package (src/cape/schemas/ in a checkout)."""


def shown(name: str) -> str:
    """The schema ``name`` as an error message names it."""
    return SHOWN_AS.format(name=name)


@cache
def load_schema(name: str) -> dict[str, Any]:
    """The schema ``name`` (``CONFIG`` or ``METRICS``), parsed; callers must not modify it."""
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's: a tenth of the time
    return yaml.load(schema_bytes(name).decode("utf-8"), Loader=loader)


def schema_bytes(name: str) -> bytes:
    """The text of the schema ``name`` as shipped."""
    return resources.files(__name__).joinpath(name).read_bytes()


def jsonschema_module() -> Any:
    """``jsonschema``, imported without its optional IRI format checker.

    That checker (``rfc3987_syntax``, which Jupyter's dependencies install) compiles its
    grammars on import; CAPE's schemas check no IRI format, so the import is skipped
    (docs/design.md). A process that imported ``jsonschema`` first keeps what it loaded.
    """
    if "jsonschema" not in sys.modules and "rfc3987_syntax" not in sys.modules:
        sys.modules["rfc3987_syntax"] = None  # type: ignore[assignment]  # import → ImportError
        try:
            import jsonschema
        finally:
            del sys.modules["rfc3987_syntax"]
    import jsonschema

    return jsonschema


def validator(schema: dict[str, Any]) -> Any:
    """A Draft 2020-12 validator of ``schema``."""
    return jsonschema_module().Draft202012Validator(schema)
