"""Atomic output: write to a temporary file beside the target, then rename.

An interrupted job leaves either the old file or none, never a half-written one, so
Snakemake's rerun does exactly what is missing.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file in ``path``'s folder; on success rename it onto ``path``."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, mode) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary folder beside ``path`` to write a group of files into; on success it
    replaces ``path`` in one rename, so the files appear together or not at all (an
    interrupted writer leaves the old folder, or none)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        if target.exists():  # a rerun: the old files go, then the new folder takes the name
            shutil.rmtree(target)
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def save_npz(path: str | os.PathLike[str], **arrays: np.ndarray) -> None:
    """``np.savez`` written atomically (and without NumPy appending a second suffix)."""
    with atomic_open(path, "wb") as handle:
        np.savez(handle, **arrays)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes(path, text.encode("utf-8"))


def save_float_columns(path: str | os.PathLike[str], columns: dict[str, np.ndarray]) -> None:
    """Equal-length float columns as a Parquet table, written atomically.

    Built from raw buffers: ``pyarrow.array`` on a NumPy array imports pandas to check its
    type, a second's start-up in each of thousands of rollout jobs that never use pandas.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = []
    for name, values in columns.items():
        data = np.ascontiguousarray(values, dtype=np.float64)
        if data.ndim != 1:
            raise ValueError(f"column {name!r}: expected one dimension, got shape {data.shape}")
        arrays.append(pa.Array.from_buffers(pa.float64(), data.size, [None, pa.py_buffer(data)]))
    table = pa.Table.from_arrays(arrays, names=list(columns))
    with atomic_open(path, "wb") as handle:
        pq.write_table(table, handle)
