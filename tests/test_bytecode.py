"""The package's bytecode is written once for the workflow's jobs (cape/bytecode.py)."""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path

import cape
from cape.bytecode import precompile_package


def test_every_module_gets_current_bytecode_even_where_python_writes_none() -> None:
    package = Path(cape.__file__).parent
    sources = sorted(package.rglob("*.py"))
    stale = Path(importlib.util.cache_from_source(str(package / "bytecode.py")))
    stale.unlink(missing_ok=True)  # as where PYTHONDONTWRITEBYTECODE kept Python from writing it
    assert precompile_package()
    for source in sources:
        cached = Path(importlib.util.cache_from_source(str(source)))
        assert cached.exists(), source
        header = cached.read_bytes()[:16]  # magic, flags, source mtime, source size
        assert header[:4] == importlib.util.MAGIC_NUMBER
        mtime, size = struct.unpack("<II", header[8:16])
        assert (mtime, size) == (int(source.stat().st_mtime) & 0xFFFFFFFF, source.stat().st_size)
