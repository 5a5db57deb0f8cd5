"""Shared figure conventions: a headless backend and saving PDF + PNG atomically.

The backend is Agg everywhere, in the notebooks too: a figure is drawn the same way whether a
rule's command, a test or a notebook makes it, so the saved files never depend on where they
were drawn. Agg leaves IPython without its inline image formatter, so the notebooks do not
``display(fig)``: their ``save`` (cape.study.reports.notebook) shows the PNG it has just written.
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from cape.storage.io import write_files

PNG_DPI = 200
"""Resolution of every saved figure's raster copy (the PDF is vector)."""


def save_figure(fig: plt.Figure, *paths: str | Path, dpi: int = PNG_DPI) -> None:
    """Save ``fig`` to each path (format from the suffix), all files or none
    (``cape.storage.io.write_files``)."""
    rendered = {}
    for path in paths:
        buffer = io.BytesIO()
        fig.savefig(buffer, format=Path(path).suffix.lstrip("."), dpi=dpi, bbox_inches="tight")
        rendered[path] = buffer.getvalue()
    write_files(rendered)
    plt.close(fig)


def nothing_to_draw(why: str) -> plt.Figure:
    """A figure that says why it is empty (a study with no runs to draw, no claim evaluated):
    the notebook still writes every output it declares, instead of failing inside Matplotlib."""
    fig, ax = plt.subplots(figsize=(6, 1.6))
    ax.text(0.5, 0.5, f"Nothing to draw: {why}", ha="center", va="center", wrap=True)
    ax.set_axis_off()
    return fig
