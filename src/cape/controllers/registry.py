"""Name → controller class. A new controller is one module that registers itself plus one
config entry (``controllers.<name>.module``)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cape.errors import CapeError

if TYPE_CHECKING:
    from cape.controllers.base import Controller

_REGISTRY: dict[str, type[Controller]] = {}

BUILTIN_MODULES = {"pid": "cape.controllers.pid", "rise": "cape.controllers.rise"}


def register_controller(name: str) -> Callable[[type[Controller]], type[Controller]]:
    def decorate(cls: type[Controller]) -> type[Controller]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"controller name {name!r} is registered twice")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return decorate


def controller_class(name: str, spec: dict[str, Any] | None = None) -> type[Controller]:
    if name not in _REGISTRY:
        module = (spec or {}).get("module") or BUILTIN_MODULES.get(name)
        if module is None:
            raise CapeError(
                f"unknown controller {name!r}: add `controllers.{name}.module: <python module>` "
                f"to the config, or use one of {sorted(BUILTIN_MODULES)}"
            )
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise CapeError(
                f"controller {name!r}: cannot import module {module!r} ({exc})"
            ) from exc
        if name not in _REGISTRY:
            raise CapeError(f"controller {name!r}: module {module!r} does not register it")
    return _REGISTRY[name]
