"""Shared figure conventions: a headless backend and saving PDF + PNG atomically."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from cape.io import write_files


def save_figure(fig: plt.Figure, *paths: str | Path, dpi: int = 200) -> None:
    """Save ``fig`` to each path (format from the suffix), all files or none
    (``cape.io.write_files``)."""
    rendered = {}
    for path in paths:
        buffer = io.BytesIO()
        fig.savefig(buffer, format=Path(path).suffix.lstrip("."), dpi=dpi, bbox_inches="tight")
        rendered[path] = buffer.getvalue()
    write_files(rendered)
    plt.close(fig)
