"""The minimal Parquet writer (cape.storage.parquet) against the reference reader (pyarrow)."""

from __future__ import annotations

import io

import numpy as np
import pyarrow.parquet as pq
import pytest

from cape.storage.parquet import parquet_bytes


def test_pyarrow_reads_back_every_value_and_name() -> None:
    rng = np.random.default_rng(0)
    columns = {f"column_{i}": rng.normal(size=377) for i in range(26)}  # > 15: long list form
    columns["column_3"][5] = np.nan
    columns["column_4"][:] = np.inf
    columns["ε and ψ"] = np.arange(377.0)  # a name in UTF-8
    table = pq.read_table(io.BytesIO(parquet_bytes(columns)))
    assert table.column_names == list(columns) and table.num_rows == 377
    for name, values in columns.items():
        np.testing.assert_array_equal(table.column(name).to_numpy(), values)
    assert pq.ParquetFile(io.BytesIO(parquet_bytes(columns))).metadata.created_by == "cape"


def test_the_same_columns_give_the_same_bytes_and_bad_shapes_are_refused() -> None:
    columns = {"t": np.linspace(0, 1, 5), "x": np.ones(5, dtype=np.float32)}
    assert parquet_bytes(columns) == parquet_bytes(dict(columns))
    assert pq.read_table(io.BytesIO(parquet_bytes({"t": np.zeros(0)}))).num_rows == 0
    with pytest.raises(ValueError, match="'x': expected 5 values"):
        parquet_bytes({"t": np.zeros(5), "x": np.zeros(4)})
    with pytest.raises(ValueError, match="one dimension"):
        parquet_bytes({"t": np.zeros(5), "x": np.zeros((5, 1))})
