"""Tracks and racelines loaded from the verified BayesRace files (SPEC §2)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cape.errors import CapeError
from cape.tracks.fetch import verify_file
from cape.tracks.geometry import ClosedPath


@dataclass(frozen=True)
class Raceline:
    """A BayesRace raceline: the closed path plus its time and speed profile."""

    name: str
    path: ClosedPath
    x: np.ndarray
    y: np.ndarray
    time: np.ndarray
    speed: np.ndarray
    inputs: np.ndarray


@dataclass(frozen=True)
class Track:
    """A track: centre line, boundaries and width; ``inside`` is the on-track test."""

    name: str
    width: float
    center: ClosedPath
    inner: np.ndarray  # (2, n) boundary points
    outer: np.ndarray

    def inside(
        self, px: float, py: float, s_hint: float | None = None, window: float | None = None
    ) -> bool:
        """|offset from the centre line| ≤ width/2."""
        return abs(self.center.project(px, py, s_hint, window).offset) <= self.width / 2


def _load_xy(path: Path) -> np.ndarray:
    verify_file(path)
    data = np.loadtxt(path, delimiter=",")
    if data.ndim != 2 or data.shape[0] != 2:
        raise CapeError(f"{path}: expected two comma-separated rows (x, y), got shape {data.shape}")
    return data


def load_track(track_dir: str | Path, name: str, prefix: str, width: float) -> Track:
    """Load ``{prefix}_center|inner|outer.txt`` from ``track_dir`` (verifying each file)."""
    track_dir = Path(track_dir)
    center = _load_xy(track_dir / f"{prefix}_center.txt")
    inner = _load_xy(track_dir / f"{prefix}_inner.txt")
    outer = _load_xy(track_dir / f"{prefix}_outer.txt")
    return Track(
        name=name, width=width, center=ClosedPath(center[0], center[1]), inner=inner, outer=outer
    )


def load_raceline(track_dir: str | Path, filename: str) -> Raceline:
    """Load a BayesRace ``*_raceline*.npz`` (verifying it)."""
    path = Path(track_dir) / filename
    verify_file(path)
    with np.load(path) as data:
        missing = {"x", "y", "time", "speed", "inputs"} - set(data.files)
        if missing:
            raise CapeError(f"{path}: raceline file lacks keys {sorted(missing)}")
        x, y = data["x"].astype(float), data["y"].astype(float)
        return Raceline(
            name=filename,
            path=ClosedPath(x, y),
            x=x,
            y=y,
            time=data["time"].astype(float),
            speed=data["speed"].astype(float),
            inputs=data["inputs"].astype(float),
        )
