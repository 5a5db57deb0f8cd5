"""The compiled projection kernel (``geometry_kernel.c``), loaded with ctypes.

``ClosedPath.project`` runs four times a closed-loop step. On NumPy it costs some 25 array
operations on ~100 candidate segments, each paying NumPy's per-call overhead: most of the loop
around the controller and the plant. The kernel does the same candidate window, arithmetic and
tie rule in C (a test holds the two to the same bits on thousands of points, wraps and vertex
ties included), compiled once into the cache of ``rollout.compile`` like the networks' GRU.

``enable(settings)`` compiles or loads it and makes every ``ClosedPath`` use it; without a
compiler, or with compilation disabled, the NumPy path stays (the same numbers, slower).
"""

from __future__ import annotations

import ctypes
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cape.layout.paths import SOLVERS
from cape.tracks import geometry
from cape.tracks.geometry import ClosedPath, Projection

SOURCE = Path(__file__).with_name("geometry_kernel.c")
EXACT_FLAGS = ["-ffp-contract=off"]
"""Always added: a fused multiply-add would round differently from NumPy."""


class ProjectionKernel:
    """``ClosedPath.project`` in C, through ctypes."""

    def __init__(self, library: Path) -> None:
        self.library = library
        function = ctypes.CDLL(str(library)).cape_project
        function.restype = ctypes.c_long
        function.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_double,
                             ctypes.c_double, ctypes.c_double, ctypes.c_int, ctypes.c_double,
                             ctypes.c_double, ctypes.c_void_p]  # fmt: skip
        self._function = function
        self._out = (ctypes.c_double * 4)()
        self._out_address = ctypes.addressof(self._out)

    def project(
        self, path: ClosedPath, px: float, py: float, s_hint: float | None, window: float | None
    ) -> Projection:
        arrays = path._kernel_arrays
        windowed = s_hint is not None and window is not None
        i = self._function(*arrays, px, py, windowed, s_hint if windowed else 0.0,
                           window if windowed else 0.0, self._out_address)  # fmt: skip
        out = self._out
        return Projection(s=out[0], offset=out[1], segment=i, x=out[2], y=out[3])


def compile_kernel(settings: Mapping[str, Any]) -> Path | None:
    """The kernel's library in the cache (compiled when missing), or None without a compiler."""
    from cape.numerics.compiled import _compiled

    compiler = str(settings.get("compiler", "gcc"))
    if shutil.which(compiler) is None:
        return None
    flags = [*(str(f) for f in settings.get("flags", ["-O1"])), *EXACT_FLAGS]
    cache = Path(str(settings.get("cache", SOLVERS)))

    def generate(folder: Path) -> Path:
        target = folder / SOURCE.name
        target.write_bytes(SOURCE.read_bytes())
        return target

    return _compiled(generate, "geometry", cache, compiler, flags)


def enable(settings: Mapping[str, Any] | None) -> ProjectionKernel | None:
    """Make every ``ClosedPath.project`` run in the compiled kernel (``rollout.compile``:
    ``enabled``, ``cache``, ``compiler``, ``flags``); the NumPy path stays where it cannot."""
    if not settings or not settings.get("enabled", False):
        return None
    library = compile_kernel(settings)
    if library is None:
        return None
    geometry._kernel = ProjectionKernel(library)
    return geometry._kernel


def disable() -> None:
    """Back to the NumPy path (tests compare the two)."""
    geometry._kernel = None
