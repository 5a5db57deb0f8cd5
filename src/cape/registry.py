"""A name → class registry, the one mechanism behind models and controllers.

A new model or controller is one module whose class is decorated with the registry's
``register(name)``, plus one config entry naming that module (``<kind>s.<name>.module``);
the registry imports the module the first time the name is asked for. The module is an
importable dotted name (``mypackage.mymodel``) or a ``.py`` file path, relative to the working
directory or else to the repository (``examples/velocity_mlp.py``), so a new model needs no
package and no install (docs/extending.md).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Generic, TypeVar

from cape.errors import CapeError

T = TypeVar("T", bound=type)


class Registry(Generic[T]):
    """Classes of one kind (``"model"``, ``"controller"``) by name."""

    def __init__(
        self, kind: str, builtin_modules: Mapping[str, str], section: str | None = None
    ) -> None:
        self.kind = kind
        self.section = section or f"{kind}s"  # the config section of its entries
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
        """The class of config entry ``name``: the class registered as ``spec['type']`` (an
        entry that reuses another's class under new settings, e.g. ``pid_paper``) or else as
        ``name``, importing ``spec['module']`` (or the built-in module) the first time."""
        name = str((spec or {}).get("type") or name)
        if name not in self._classes:
            module = (spec or {}).get("module") or self.builtin_modules.get(name)
            if module is None:
                entry = f"{self.section}.{name}.module"
                raise CapeError(
                    f"unknown {self.kind} {name!r}: add `{entry}: <python module>` to the config, "
                    f"or use one of {sorted(self.builtin_modules)}"
                )
            try:
                _import(module)
            except Exception as exc:  # ImportError, or the module's own error (SyntaxError…)
                raise CapeError(
                    f"field `{self.section}.{name}.module`: cannot import {module!r} "
                    f"({type(exc).__name__}: {exc}); give an importable module or a .py file "
                    "(docs/extending.md)"
                ) from exc
            if name not in self._classes:
                raise CapeError(
                    f"{self.kind} {name!r}: module {module!r} does not register it; decorate the "
                    f"class with @register_{self.kind}({name!r})"
                )
        return self._classes[name]


def _import(module: str) -> None:
    """Import a dotted module name, or execute a ``.py`` file as a module (once)."""
    if not module.endswith(".py"):
        importlib.import_module(module)
        return
    from cape.config import REPO_ROOT

    path = Path(module)
    if not path.is_absolute() and not path.is_file():
        path = REPO_ROOT / path
    if not path.is_file():
        raise ImportError(f"no file {module} (looked in {Path.cwd()} and {REPO_ROOT})")
    digest = hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
    key = f"cape_extension_{path.stem}_{digest}"
    if key in sys.modules:
        return
    spec = importlib.util.spec_from_file_location(key, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{module}: not a Python module")
    loaded = importlib.util.module_from_spec(spec)
    sys.modules[key] = loaded
    try:
        spec.loader.exec_module(loaded)
    except BaseException:
        del sys.modules[key]
        raise
