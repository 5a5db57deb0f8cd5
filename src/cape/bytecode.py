"""Compile the package's modules to bytecode once, before the workflow's jobs start.

Each job is a fresh interpreter that imports some 40 of CAPE's modules. Where
``PYTHONDONTWRITEBYTECODE`` is set (many containers and CI images) Python caches no bytecode, and
every job would compile them from source again. Python still *reads* bytecode when that
variable is set, so writing it once from the main Snakemake process (``compileall``, which
skips what is current) lets every job load it. Editing a module invalidates its bytecode as
usual. What it saves: docs/design.md."""

from __future__ import annotations

import compileall
import io
from contextlib import redirect_stdout
from pathlib import Path


def precompile_package() -> bool:
    """Write current bytecode for every module of ``cape``; False where the package's folder
    is not writable (an installed, read-only copy: then Python's own caching applies)."""
    folder = Path(__file__).resolve().parent
    try:
        with redirect_stdout(io.StringIO()):  # compileall lists what it compiles
            return bool(compileall.compile_dir(folder, quiet=1))
    except OSError:
        return False
