"""The one reference generator every controller shares (SPEC §5.2).

From the car's projected progress s0 on the closed reference path, point k lies at
``s_k = s_{k−1} + v_ref(s_{k−1})·Ts`` with ``v_ref(s) = clip(scale·v_path(s), v_min, v_max)``.
Each point carries position, heading, curvature and speed. Projection searches a window
around the previous progress, so a path that passes near itself is not confused.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cape.errors import CapeError
from cape.specs.tracks import ReferenceSettings
from cape.tracks.geometry import ClosedPath, Projection


@dataclass(frozen=True)
class ReferencePoints:
    """Points k = 0 … N of the reference: arrays of length N+1. Positions, heading and
    curvature are evaluated on the path when first asked for: an NMPC reads every point's
    position, PID and RISE none, the loop one point (``at``), and each array costs spline
    evaluations per step."""

    s: np.ndarray
    speed: np.ndarray
    path: ClosedPath

    @cached_property
    def _xy(self) -> np.ndarray:
        return self.path.position(self.s)

    @property
    def x(self) -> np.ndarray:
        return self._xy[0]

    @property
    def y(self) -> np.ndarray:
        return self._xy[1]

    @cached_property
    def heading(self) -> np.ndarray:
        return self.path.heading(self.s)

    def at(self, k: int) -> tuple[float, float, float]:
        """Point k's position and heading: the same numbers as ``x[k]``, ``y[k]``,
        ``heading[k]``, from the path's scalar evaluations (a test holds them equal), without
        evaluating the other points."""
        s = float(self.s[k])
        x, y = self.path.position_at(s)
        return x, y, self.path.heading_at(s)

    @cached_property
    def curvature(self) -> np.ndarray:
        return self.path.curvature(self.s)


def ideal_lap_time(path: ClosedPath, v_path: np.ndarray, settings: ReferenceSettings) -> float:
    """One lap at exactly the reference speed (the scaled, clipped path speed, SPEC §5.2):
    each segment's length over the speed at its start."""
    speed = np.clip(float(settings.scale) * np.asarray(v_path, dtype=float),
                    float(settings.v_min), float(settings.v_max))  # fmt: skip
    return float(np.sum(path.segment_lengths / speed[: len(path)]))


def check_time_limit(time_limit: float, ideal: float) -> None:
    """Refuse a run time limit no lap could meet: shorter than the reference's ideal lap."""
    if time_limit < ideal:
        raise CapeError(
            f"field `rollout.time_limit` is {time_limit:g} s, shorter than the reference's "
            f"ideal lap ({ideal:.2f} s at the reference speed): every run would time out. "
            f"Give at least {math.ceil(ideal)} s (SPEC §5.3 uses 15 s)"
        )


class ReferenceLine:
    """A closed reference path with its speed rule."""

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        v_path: np.ndarray,
        settings: ReferenceSettings,
        ts: float,
    ) -> None:
        self.path = ClosedPath(x, y)
        if len(self.path) != np.asarray(x).size:
            v_path = np.asarray(v_path)[: len(self.path)]
        self.v_path = np.asarray(v_path, dtype=float)
        self.settings = settings
        self.scale = float(settings.scale)
        self.v_min, self.v_max = float(settings.v_min), float(settings.v_max)
        self.ts = ts
        self.window = float(settings.projection_window)
        self.length = self.path.length
        # the speed profile as Python lists closed at s = length, for the scalar lookups of
        # ``points`` (np.interp with a period sorts its table on every call)
        self._knots = [*self.path.s_points.tolist(), self.length]
        self._speeds = [*self.v_path.tolist(), float(self.v_path[0])]

    def ideal_lap_time(self) -> float:
        """One lap at exactly the reference speed (``ideal_lap_time``)."""
        return ideal_lap_time(self.path, self.v_path, self.settings)

    def v_ref(self, s: np.ndarray | float) -> np.ndarray:
        """Reference speed at arc length ``s``: the scaled, clipped path speed."""
        v = np.interp(np.mod(s, self.length), self.path.s_points, self.v_path, period=self.length)
        return np.clip(self.scale * v, self.v_min, self.v_max)

    def _v_ref_scalar(self, s: float) -> float:
        """``v_ref`` at one arc length: the same linear interpolation as ``np.interp``'s (the
        same expression, so the same bits), without NumPy's per-call cost."""
        s = s % self.length
        knots, speeds = self._knots, self._speeds
        i = min(bisect_right(knots, s) - 1, len(knots) - 2)
        slope = (speeds[i + 1] - speeds[i]) / (knots[i + 1] - knots[i])
        v = self.scale * (slope * (s - knots[i]) + speeds[i])
        return min(max(v, self.v_min), self.v_max)

    def project(self, px: float, py: float, s_hint: float | None) -> Projection:
        """Projection near ``s_hint`` (global search when there is none)."""
        if s_hint is None:
            return self.path.project(px, py)
        # Python's % on floats is NumPy's mod, bit for bit, without NumPy's per-call cost
        return self.path.project(px, py, s_hint=float(s_hint) % self.length, window=self.window)

    def points(self, s0: float, n: int) -> ReferencePoints:
        """Reference points k = 0 … n starting at progress ``s0``."""
        v_ref, ts = self._v_ref_scalar, self.ts
        s, speed = [float(s0)], []
        for _ in range(n):
            v = v_ref(s[-1])
            speed.append(v)
            s.append(s[-1] + v * ts)
        speed.append(v_ref(s[-1]))
        return ReferencePoints(s=np.array(s), speed=np.array(speed), path=self.path)


class ProgressTracker:
    """Unwrapped progress of one body (the car, or a controller's estimate) along the line."""

    def __init__(self, line: ReferenceLine) -> None:
        self.line = line
        self.s_wrapped: float | None = None
        self.total = 0.0

    def reset(self, px: float, py: float) -> Projection:
        proj = self.line.project(px, py, None)
        self.s_wrapped, self.total = proj.s, 0.0
        return proj

    def update(self, px: float, py: float) -> Projection:
        """Project near the last progress and accumulate the signed advance."""
        proj = self.line.project(px, py, self.s_wrapped)
        length = self.line.length
        step = (proj.s - (self.s_wrapped or 0.0) + length / 2) % length - length / 2
        self.total += step
        self.s_wrapped = proj.s
        return proj
