"""A minimal Parquet writer: equal-length float64 columns, one row group, plain encoding.

It writes a standard Apache Parquet file that every reader (pandas, pyarrow, DuckDB, …) reads.
Why it exists, and the file's layout: docs/modules.md.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

import numpy as np

MAGIC = b"PAR1"
# Thrift compact protocol field types
_I32, _I64, _BINARY, _LIST, _STRUCT = 5, 6, 8, 9, 12
# Parquet enums
_DOUBLE, _REQUIRED, _PLAIN, _RLE, _UNCOMPRESSED, _DATA_PAGE = 5, 0, 0, 3, 0, 0


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _zigzag(value: int) -> bytes:
    return _varint((value << 1) ^ (value >> 63))


class _Struct:
    """A Thrift struct in the compact protocol: fields in increasing id order, then a stop."""

    def __init__(self) -> None:
        self.out = bytearray()
        self.last = 0

    def _header(self, field: int, kind: int) -> None:
        delta = field - self.last
        if 0 < delta <= 15:
            self.out.append((delta << 4) | kind)
        else:
            self.out.append(kind)
            self.out += _zigzag(field)
        self.last = field

    def i32(self, field: int, value: int) -> _Struct:
        self._header(field, _I32)
        self.out += _zigzag(value)
        return self

    def i64(self, field: int, value: int) -> _Struct:
        self._header(field, _I64)
        self.out += _zigzag(value)
        return self

    def string(self, field: int, value: str) -> _Struct:
        self._header(field, _BINARY)
        data = value.encode("utf-8")
        self.out += _varint(len(data)) + data
        return self

    def struct(self, field: int, value: _Struct) -> _Struct:
        self._header(field, _STRUCT)
        self.out += value.done()
        return self

    def list(self, field: int, kind: int, items: list[bytes]) -> _Struct:
        """A list of already-encoded items of one compact type (i32s as zigzag varints,
        strings with their length, structs with their stop byte)."""
        self._header(field, _LIST)
        size = len(items)
        self.out += (
            bytes([(size << 4) | kind]) if size < 15 else bytes([0xF0 | kind]) + _varint(size)
        )
        for item in items:
            self.out += item
        return self

    def done(self) -> bytes:
        return bytes(self.out) + b"\x00"


def _string_item(value: str) -> bytes:
    data = value.encode("utf-8")
    return _varint(len(data)) + data


def parquet_bytes(columns: Mapping[str, np.ndarray], created_by: str = "cape") -> bytes:
    """The columns (1-D, equal length, converted to float64) as the bytes of a Parquet file."""
    names = list(columns)
    arrays = [np.ascontiguousarray(columns[name], dtype="<f8") for name in names]
    rows = arrays[0].size if arrays else 0
    for name, data in zip(names, arrays, strict=True):
        if data.ndim != 1 or data.size != rows:
            raise ValueError(f"column {name!r}: expected {rows} values in one dimension, got "
                             f"shape {data.shape}")  # fmt: skip
    out = bytearray(MAGIC)
    chunks = []
    for name, data in zip(names, arrays, strict=True):
        payload = data.tobytes()
        page = _Struct().i32(1, rows).i32(2, _PLAIN).i32(3, _RLE).i32(4, _RLE)
        header = (
            _Struct()
            .i32(1, _DATA_PAGE)
            .i32(2, len(payload))
            .i32(3, len(payload))
            .struct(5, page)
            .done()
        )
        offset = len(out)
        out += header + payload
        size = len(header) + len(payload)
        meta = (
            _Struct()
            .i32(1, _DOUBLE)
            .list(2, _I32, [_zigzag(_PLAIN), _zigzag(_RLE)])
            .list(3, _BINARY, [_string_item(name)])
            .i32(4, _UNCOMPRESSED)
            .i64(5, rows)
            .i64(6, size)
            .i64(7, size)
            .i64(9, offset)
        )
        chunks.append((offset, size, meta))
    schema = [_Struct().string(4, "schema").i32(5, len(names)).done()]
    schema += [_Struct().i32(1, _DOUBLE).i32(3, _REQUIRED).string(4, n).done() for n in names]
    columns_meta = [_Struct().i64(2, offset).struct(3, meta).done() for offset, _, meta in chunks]
    group = (
        _Struct()
        .list(1, _STRUCT, columns_meta)
        .i64(2, sum(size for _, size, _ in chunks))
        .i64(3, rows)
        .done()
    )
    footer = (
        _Struct()
        .i32(1, 1)
        .list(2, _STRUCT, schema)
        .i64(3, rows)
        .list(4, _STRUCT, [group])
        .string(6, created_by)
        .done()
    )
    out += footer + struct.pack("<I", len(footer)) + MAGIC
    return bytes(out)
