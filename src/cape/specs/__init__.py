"""Typed, frozen specifications of what a job reads, each built from a validated config in one
place (``from_config``); the code below the commands takes the spec, never the dict."""

import hashlib
import json
from collections.abc import Mapping
from dataclasses import fields, is_dataclass
from typing import Any


def _plain(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return repr(value)  # NaN and ±inf as text: JSON has none
    return value


def digest(spec: Any) -> str:
    """The SHA-256 of a specification's content (fields, nested mappings and sequences; key
    order ignored): two specifications with the same digest are the same settings."""
    text = json.dumps(_plain(spec), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()
