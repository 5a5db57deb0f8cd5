"""Checksums of what the workflow writes, checked by whatever reads it.

Each file below carries the SHA-256 of its content, written by the rule that made it and compared
by the reader before use: ``.npz`` arrays (network, raceline) an array ``sha256`` over the
others; JSON records (frozen Φ) a ``sha256`` field over the rest; ``model.pt`` its digest in
``meta.json``; native libraries (compiled solvers and networks) a ``.sha256`` file beside each.
A mismatch raises ``CapeError`` naming the file and the fix (delete it and rebuild it). Why:
docs/modules.md.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cape.errors import CapeError

KEY = "sha256"


def digest_arrays(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over every array but ``sha256``: names, dtypes, shapes and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(k for k in arrays if k != KEY):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def sealed_arrays(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays plus their digest, ready for ``np.savez``."""
    out = {k: np.asarray(v) for k, v in arrays.items() if k != KEY}
    out[KEY] = np.array(digest_arrays(out))
    return out


def check_arrays(arrays: Mapping[str, np.ndarray], path: str | Path, fix: str) -> None:
    """Raise unless ``arrays`` (read from ``path``) match the digest they carry."""
    if KEY not in arrays:
        raise CapeError(f"{path}: carries no checksum (written by an older version?); {fix}")
    if str(arrays[KEY]) != digest_arrays(arrays):
        raise CapeError(
            f"{path}: its content does not match the checksum written with it (the file was "
            f"damaged or changed since); {fix}"
        )


def sealed_record(record: Mapping[str, Any]) -> dict[str, Any]:
    """A JSON record plus the digest of its canonical form."""
    body = {k: v for k, v in record.items() if k != KEY}
    return {**body, KEY: _digest_json(body)}


def check_record(record: Mapping[str, Any], path: str | Path, fix: str) -> None:
    """Raise unless a JSON record (read from ``path``) matches the digest it carries."""
    if not isinstance(record, Mapping) or KEY not in record:
        raise CapeError(f"{path}: carries no checksum (written by an older version?); {fix}")
    if record[KEY] != _digest_json({k: v for k, v in record.items() if k != KEY}):
        raise CapeError(
            f"{path}: its content does not match the checksum written with it (the file was "
            f"damaged or changed since); {fix}"
        )


def _digest_json(body: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def sidecar(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".sha256")


def check_sidecar(path: str | Path, fix: str) -> None:
    """Raise unless ``path`` matches the digest recorded beside it."""
    recorded = sidecar(path)
    if not recorded.is_file():
        raise CapeError(f"{path}: no checksum recorded beside it ({recorded.name}); {fix}")
    if recorded.read_text().strip() != file_digest(path):
        raise CapeError(
            f"{path}: its content does not match the checksum recorded when it was written "
            f"({recorded.name}); it was damaged or changed since; {fix}"
        )
