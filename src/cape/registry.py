"""A name → class registry, the one mechanism behind models and controllers.

A new model or controller is one module whose class is decorated with the registry's
``register(name)``, plus one config entry naming that module (``<kind>s.<name>.module``);
the registry imports the module the first time the name is asked for.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

from cape.errors import CapeError

T = TypeVar("T", bound=type)


class Registry(Generic[T]):
    """Classes of one kind (``"model"``, ``"controller"``) by name."""

    def __init__(self, kind: str, builtin_modules: Mapping[str, str]) -> None:
        self.kind = kind
        self.builtin_modules = dict(builtin_modules)
        self._classes: dict[str, T] = {}

    def register(self, name: str) -> Callable[[T], T]:
        """Class decorator: make a class available under ``name`` (and set its ``name``)."""

        def decorate(cls: T) -> T:
            if name in self._classes and self._classes[name] is not cls:
                raise ValueError(f"{self.kind} name {name!r} is registered twice")
            cls.name = name
            self._classes[name] = cls
            return cls

        return decorate

    def get(self, name: str, spec: Mapping[str, Any] | None = None) -> T:
        """The class registered as ``name``, importing ``spec['module']`` (or the built-in)."""
        if name not in self._classes:
            module = (spec or {}).get("module") or self.builtin_modules.get(name)
            if module is None:
                entry = f"{self.kind}s.{name}.module"
                raise CapeError(
                    f"unknown {self.kind} {name!r}: add `{entry}: <python module>` to the config, "
                    f"or use one of {sorted(self.builtin_modules)}"
                )
            try:
                importlib.import_module(module)
            except ImportError as exc:
                raise CapeError(
                    f"{self.kind} {name!r}: cannot import module {module!r} ({exc})"
                ) from exc
            if name not in self._classes:
                raise CapeError(
                    f"{self.kind} {name!r}: module {module!r} does not register it; decorate the "
                    f"class with @register_{self.kind}({name!r})"
                )
        return self._classes[name]
