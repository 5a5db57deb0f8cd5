"""Typed, frozen specifications of what a job reads, each built from a validated config in one
place (``from_config``); the code below the commands takes the spec, never the dict.

Every field is a frozen dataclass or a plain value, with one exception: a registered class's
own entry (``Entry``: a model's, a controller's, a disturbance source's), whose keys that class
declares and validates (its settings schema) and reads itself; a spec hands it on unread. Every
default is the packaged schema's (``cape.config.schema_default``), never restated here.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import fields, is_dataclass
from types import MappingProxyType
from typing import Any, TypeAlias, TypeVar

from cape.errors import CapeError

JSON: TypeAlias = bool | int | float | str | Sequence["JSON"] | Mapping[str, "JSON"] | None
"""A value of the config: YAML or a job file, both JSON's values."""

Entry: TypeAlias = Mapping[str, JSON]
"""A registered class's entry (``models.<name>``, ``controllers.<name>``, a disturbance source):
its own settings, which its class declares, validates and reads."""


T = TypeVar("T")


def entries(section: Mapping[str, Entry]) -> Mapping[str, Entry]:
    """A section of named entries, read-only."""
    return MappingProxyType(dict(section))


def entry_of(section: Mapping[str, T], name: str, option: str, where: str) -> T:
    """Entry ``name`` of the config's section ``where`` (``models``, ``controllers``,
    ``tracks.catalogue``, ...), or one ``CapeError`` naming the command's ``option`` and the
    entries there are: the one check of a name that is not in the config."""
    if name not in section:
        known = ", ".join(sorted(section))
        raise CapeError(f"{option} {name}: not in the config's `{where}` ({known})")
    return section[name]


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


def as_record(spec: Any) -> Any:
    """A specification's content as plain JSON values, for a record that writes the settings it
    was made with: a dataclass as the mapping of its fields, as the config spells them (a
    field the config left out, None, left out)."""
    if is_dataclass(spec) and not isinstance(spec, type):
        values = {f.name: getattr(spec, f.name) for f in fields(spec)}
        return {k: as_record(v) for k, v in values.items() if v is not None}
    if isinstance(spec, Mapping):
        return {str(k): as_record(v) for k, v in spec.items()}
    if isinstance(spec, tuple):
        return [as_record(v) for v in spec]
    return spec
