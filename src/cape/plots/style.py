"""Shared figure conventions: a headless backend and saving PDF + PNG atomically."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from cape.io import write_bytes


def save_figure(fig: plt.Figure, *paths: str | Path, dpi: int = 200) -> None:
    """Save ``fig`` to each path (format from the suffix), each file written atomically."""
    for path in paths:
        buffer = io.BytesIO()
        fig.savefig(buffer, format=Path(path).suffix.lstrip("."), dpi=dpi, bbox_inches="tight")
        write_bytes(path, buffer.getvalue())
    plt.close(fig)
