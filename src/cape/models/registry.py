"""Name → learned-model class. A new model is one module that registers itself plus one
config entry (``models.<name>.module``) naming that module, so nothing else changes."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cape.errors import CapeError

if TYPE_CHECKING:
    from cape.models.base import LearnedModel

_REGISTRY: dict[str, type[LearnedModel]] = {}

BUILTIN_MODULES = {"dpm": "cape.models.dpm", "ddm": "cape.models.ddm", "epm": "cape.models.epm"}


def register_model(name: str) -> Callable[[type[LearnedModel]], type[LearnedModel]]:
    """Class decorator: make a model available under ``name``."""

    def decorate(cls: type[LearnedModel]) -> type[LearnedModel]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"model name {name!r} is registered twice")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return decorate


def model_class(name: str, spec: dict[str, Any] | None = None) -> type[LearnedModel]:
    """The class registered as ``name``, importing its module (``spec['module']`` or built-in)."""
    if name not in _REGISTRY:
        module = (spec or {}).get("module") or BUILTIN_MODULES.get(name)
        if module is None:
            raise CapeError(
                f"unknown model {name!r}: add `models.{name}.module: <python module>` to the "
                f"config, or use one of {sorted(BUILTIN_MODULES)}"
            )
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise CapeError(f"model {name!r}: cannot import module {module!r} ({exc})") from exc
        if name not in _REGISTRY:
            raise CapeError(
                f"model {name!r}: module {module!r} does not register it; decorate the class "
                f"with @register_model({name!r})"
            )
    return _REGISTRY[name]
