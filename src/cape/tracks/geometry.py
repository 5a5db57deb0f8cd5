"""Geometry of a closed planar path: arc length, projection, heading and curvature (SPEC §2).

A path is a closed polyline: the segment from the last point back to the first belongs to it.
Projection works on the polyline (exact and cheap); heading, curvature and positions at an
arbitrary arc length come from a periodic cubic spline through the same points, so they are
smooth where a controller needs derivatives.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

_kernel: Any = None
"""The compiled projection (``cape.tracks.native.enable``), or None: NumPy."""
PROJECT_BLOCK = 64
"""Points per block of ``ClosedPath.project_many`` (speed only: any size gives the same numbers)."""


def wrap_angle(a: float) -> float:
    """Angle folded into [−π, π)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def cross_track_error(x: float, y: float, x_ref: float, y_ref: float, psi_ref: float) -> float:
    """The paper's e_cte: positive when the car is left of the line (SPEC §5.3)."""
    return (y - y_ref) * math.cos(psi_ref) - (x - x_ref) * math.sin(psi_ref)


@dataclass(frozen=True)
class Projection:
    """Where a point lies relative to a path.

    ``s`` is the arc length of the nearest path point (in [0, length)), ``offset`` the signed
    distance to it (positive to the left of the direction of travel), ``segment`` the index of
    the segment it lies on (segment i runs from point i to point i+1, the last one closes the
    loop), ``x``/``y`` the nearest point itself.
    """

    s: float
    offset: float
    segment: int
    x: float
    y: float


class PeriodicCubicSpline:
    """The periodic cubic spline through ``(knots[i], values[i])``, ``knots[-1]`` closing the
    loop onto ``values[0]``: C² everywhere, the same curve as SciPy's
    ``CubicSpline(..., bc_type="periodic")`` (a test holds it to that), without importing
    ``scipy.interpolate``, which costs a second in each of thousands of rollout processes."""

    def __init__(self, knots: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(knots, dtype=float)
        y = np.asarray(values, dtype=float)
        n = y.size
        if t.size != n + 1 or n < 3 or np.any(np.diff(t) <= 0):
            raise ValueError("need n ≥ 3 values and n + 1 increasing knots")
        h = np.diff(t)
        slope = np.diff(np.append(y, y[0])) / h
        # second derivatives m: h[i-1]·m[i-1] + 2(h[i-1] + h[i])·m[i] + h[i]·m[i+1]
        #                        = 6(slope[i] − slope[i-1]), indices modulo n
        h_prev = np.roll(h, 1)
        m = _solve_cyclic_tridiagonal(
            h_prev, 2.0 * (h_prev + h), h, 6.0 * (slope - np.roll(slope, 1))
        )
        m_next = np.roll(m, -1)
        self.knots = t
        self.period = t[-1] - t[0]
        # y = a + b·dt + c·dt² + d·dt³ on [t[i], t[i+1]]
        self._a = y
        self._b = slope - h * (2.0 * m + m_next) / 6.0
        self._c = 0.5 * m
        self._d = (m_next - m) / (6.0 * h)
        # the same numbers as Python lists, for one point at a time (the closed loop's case,
        # where NumPy's per-call cost is most of the evaluation)
        self._lists = (t.tolist(), self._a.tolist(), self._b.tolist(), self._c.tolist(),
                       self._d.tolist())  # fmt: skip

    def at(self, s: float, nu: int = 0) -> float:
        """``self(s, nu)`` for one float ``s``, in plain Python with the same arithmetic (so
        the same bits) and a tenth of the cost."""
        knots, a, b, c, d = self._lists
        s = knots[0] + (s - knots[0]) % self.period  # Python's % is NumPy's mod, bit for bit
        i = min(max(bisect_right(knots, s) - 1, 0), len(a) - 1)
        dt = s - knots[i]
        if nu == 0:
            return a[i] + dt * (b[i] + dt * (c[i] + dt * d[i]))
        if nu == 1:
            return b[i] + dt * (2.0 * c[i] + dt * 3.0 * d[i])
        if nu == 2:
            return 2.0 * c[i] + 6.0 * d[i] * dt
        raise ValueError(f"derivative order {nu} not supported (0, 1 or 2)")

    def __call__(self, s: np.ndarray | float, nu: int = 0) -> np.ndarray:
        """The spline (``nu`` = 0) or its first or second derivative at ``s`` (wrapped)."""
        s = self.knots[0] + np.mod(np.asarray(s, dtype=float) - self.knots[0], self.period)
        i = np.clip(np.searchsorted(self.knots, s, side="right") - 1, 0, self._a.size - 1)
        dt = s - self.knots[i]
        a, b, c, d = self._a[i], self._b[i], self._c[i], self._d[i]
        if nu == 0:
            return a + dt * (b + dt * (c + dt * d))
        if nu == 1:
            return b + dt * (2.0 * c + dt * 3.0 * d)
        if nu == 2:
            return 2.0 * c + 6.0 * d * dt
        raise ValueError(f"derivative order {nu} not supported (0, 1 or 2)")


def _solve_cyclic_tridiagonal(
    lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray
) -> np.ndarray:
    """Solve A·x = rhs, A tridiagonal plus the corners A[0, n−1] = lower[0] and
    A[n−1, 0] = upper[n−1] (Sherman–Morrison around the Thomas algorithm)."""
    n = diag.size
    gamma = -diag[0]
    corner_top, corner_bottom = lower[0], upper[-1]
    d = diag.astype(float).copy()
    d[0] -= gamma
    d[-1] -= corner_bottom * corner_top / gamma
    u = np.zeros(n)
    u[0], u[-1] = gamma, corner_bottom
    both = _thomas(lower, d, upper, np.column_stack([rhs, u]))
    y, z = both[:, 0], both[:, 1]
    v_y = y[0] + corner_top / gamma * y[-1]
    v_z = z[0] + corner_top / gamma * z[-1]
    return y - v_y / (1.0 + v_z) * z


def _thomas(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Tridiagonal solve (no pivoting: the spline's matrix is diagonally dominant). The
    recursion runs on Python floats, column by column: the same IEEE operations in the same
    order as on NumPy scalars (the same bits), without NumPy's per-element cost."""
    n = diag.size
    low, mid, up = lower.tolist(), diag.tolist(), upper.tolist()
    c = [0.0] * n
    c[0] = up[0] / mid[0]
    denominators = [mid[0]]
    for i in range(1, n):
        denom = mid[i] - low[i] * c[i - 1]
        c[i] = up[i] / denom
        denominators.append(denom)
    r = np.array(rhs, dtype=float)
    columns = r.reshape(n, -1).T.tolist()
    for col in columns:
        col[0] = col[0] / mid[0]
        for i in range(1, n):
            col[i] = (col[i] - low[i] * col[i - 1]) / denominators[i]
        for i in range(n - 2, -1, -1):
            col[i] -= c[i] * col[i + 1]
    return np.array(columns, dtype=float).T.reshape(r.shape)


class ClosedPath:
    """A closed curve through points ``(x[i], y[i])``, parameterised by arc length."""

    def __init__(self, x: np.ndarray, y: np.ndarray) -> None:
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.ndim != 1 or x.shape != y.shape or x.size < 3:
            raise ValueError(
                f"a closed path needs matching 1-D x, y with ≥ 3 points, got {x.shape}, {y.shape}"
            )
        if x[0] == x[-1] and y[0] == y[-1]:
            x, y = x[:-1], y[:-1]  # the loop closes itself; do not count a zero-length segment
        self.x, self.y = x, y
        self._x_next, self._y_next = np.roll(x, -1), np.roll(y, -1)
        self._dx = self._x_next - x
        self._dy = self._y_next - y
        self._len2 = self._dx * self._dx + self._dy * self._dy
        self.segment_lengths = np.hypot(self._dx, self._dy)
        if np.any(self.segment_lengths == 0.0):
            raise ValueError("a closed path must not repeat a point (zero-length segment)")
        self.s_points = np.concatenate([[0.0], np.cumsum(self.segment_lengths)[:-1]])
        # every segment's numbers in one array, rows: start x, y, direction x, y, squared
        # length, end x, y, length (a projection gathers its candidates once)
        self._segments = np.vstack([x, y, self._dx, self._dy, self._len2, self._x_next,
                                    self._y_next, self.segment_lengths])  # fmt: skip
        self.length = float(self.segment_lengths.sum())

    @cached_property
    def _sx(self) -> PeriodicCubicSpline:
        """The splines through the points, built when first evaluated (a path that is only
        projected onto, like the centre line in most runs, never needs them)."""
        return PeriodicCubicSpline(np.append(self.s_points, self.length), self.x)

    @cached_property
    def _sy(self) -> PeriodicCubicSpline:
        return PeriodicCubicSpline(np.append(self.s_points, self.length), self.y)

    def __len__(self) -> int:
        return self.x.size

    def wrap(self, s: np.ndarray | float) -> np.ndarray | float:
        """Arc length folded into [0, length)."""
        return np.mod(s, self.length)

    # --- projection -------------------------------------------------------------------
    def _candidates(self, s_hint: float | None, window: float | None) -> np.ndarray:
        """Indices (ascending) of the segments meeting [s_hint − window, s_hint + window]. The
        segments are ordered by arc length, so two binary searches bound them; the exact test
        (a segment whose start lies in the window, or that reaches into it) is then applied to
        those and one neighbour on each side only, not to every segment of the path."""
        n = len(self)
        if s_hint is None or window is None or 2 * window >= self.length:
            return np.arange(n)
        low = s_hint - window
        start = low % self.length
        first = int(np.searchsorted(self.s_points, start, side="right")) - 2
        end = start + 2 * window
        if end <= self.length:
            last = int(np.searchsorted(self.s_points, end)) + 1
        else:
            last = n + int(np.searchsorted(self.s_points, end - self.length)) + 1
        if first < 0 or last > n:  # the range wraps round the loop's start: two ranges
            near = np.concatenate(
                [
                    np.arange(0, last - n if last > n else last),
                    np.arange(first % n if first < 0 else first, n),
                ]
            )
            near = np.unique(near)
        else:
            near = np.arange(first, last)
        rel_start = np.mod(self.s_points[near] - low, self.length)
        hit = (rel_start <= 2 * window) | (rel_start + self.segment_lengths[near] >= self.length)
        return near[hit]

    def project(
        self, px: float, py: float, s_hint: float | None = None, window: float | None = None
    ) -> Projection:
        """The nearest point of the path to ``(px, py)``.

        With ``s_hint`` and ``window`` only segments within ``window`` of arc length around
        ``s_hint`` are searched, so a path passing near itself (a hairpin) is not confused.
        Ties go to the lowest segment index. With the compiled kernel enabled
        (``cape.tracks.native``) the same numbers come from C.
        """
        kernel = _kernel
        if (kernel is not None and math.isfinite(px) and math.isfinite(py)
                and (s_hint is None or math.isfinite(s_hint))):  # fmt: skip
            return kernel.project(self, px, py, s_hint, window)
        idx = self._candidates(s_hint, window)
        ax, ay, dx, dy, len2, bx, by, seg_len = self._segments[:, idx]  # one gather
        t = np.clip(((px - ax) * dx + (py - ay) * dy) / len2, 0.0, 1.0)
        # End points exactly (a + 1·(b − a) can miss b by an ulp), so that the two segments
        # meeting at a vertex tie exactly and the lower index wins (SPEC §3, step 1).
        qx = np.where(t <= 0.0, ax, np.where(t >= 1.0, bx, ax + t * dx))
        qy = np.where(t <= 0.0, ay, np.where(t >= 1.0, by, ay + t * dy))
        dist = np.hypot(px - qx, py - qy)
        k = int(np.argmin(dist))
        i = int(idx[k])
        cross = dx[k] * (py - ay[k]) - dy[k] * (px - ax[k])
        side = 1.0 if cross >= 0 else -1.0
        s = float(self.wrap(self.s_points[i] + t[k] * seg_len[k]))
        return Projection(
            s=s, offset=side * float(dist[k]), segment=i, x=float(qx[k]), y=float(qy[k])
        )

    @cached_property
    def _kernel_arrays(self) -> tuple[int, int, int, float]:
        """What the compiled projection reads: the segment table's and the start arc lengths'
        addresses (the arrays live as long as the path), the segment count, the length."""
        segments = np.ascontiguousarray(self._segments)
        s_points = np.ascontiguousarray(self.s_points)
        self._kernel_keep = (segments, s_points)
        return segments.ctypes.data, s_points.ctypes.data, len(self), self.length

    def project_many(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nearest points of the whole path to many points at once (no window): their arc
        lengths ``s`` and the points themselves (n × 2), with ``project``'s arithmetic and tie
        rule, so each row equals ``project(px[i], py[i])``. The points go through in blocks of
        ``PROJECT_BLOCK`` rows, so that the block × segments temporaries stay in cache (the
        same element-wise operations, so the same numbers; 2.5× faster than one block for an
        NMPC's 1142 reference points on a 377-point centre line)."""
        px, py = np.asarray(px, dtype=float).ravel(), np.asarray(py, dtype=float).ravel()
        s, points = np.empty(px.size), np.empty((px.size, 2))
        ax, ay, dx, dy = self.x, self.y, self._dx, self._dy
        for first in range(0, px.size, PROJECT_BLOCK):
            rows = slice(first, first + PROJECT_BLOCK)
            bx, by = px[rows, None], py[rows, None]
            t = np.clip(((bx - ax) * dx + (by - ay) * dy) / self._len2, 0.0, 1.0)
            qx = np.where(t <= 0.0, ax, np.where(t >= 1.0, self._x_next, ax + t * dx))
            qy = np.where(t <= 0.0, ay, np.where(t >= 1.0, self._y_next, ay + t * dy))
            k = np.argmin(np.hypot(bx - qx, by - qy), axis=1)
            r = np.arange(k.size)
            s[rows] = np.mod(self.s_points[k] + t[r, k] * self.segment_lengths[k], self.length)
            points[rows, 0], points[rows, 1] = qx[r, k], qy[r, k]
        return s, points

    # --- smooth evaluation ------------------------------------------------------------------
    def position(self, s: np.ndarray | float) -> np.ndarray:
        """Points ``[x, y]`` at arc length ``s`` (wrapped), shape (2,) or (2, n)."""
        s = self.wrap(np.asarray(s, dtype=float))
        return np.stack([self._sx(s), self._sy(s)])

    def position_at(self, s: float) -> tuple[float, float]:
        """``position(s)`` for one float ``s`` (the same numbers, in plain Python)."""
        s = float(s) % self.length
        return self._sx.at(s), self._sy.at(s)

    def heading_at(self, s: float) -> float:
        """``heading(s)`` for one float ``s`` (the same numbers; NumPy's arctan2, whose last
        bit math.atan2 does not always match)."""
        s = float(s) % self.length
        return float(np.arctan2(self._sy.at(s, 1), self._sx.at(s, 1)))

    def heading(self, s: np.ndarray | float) -> np.ndarray:
        """Tangent direction (rad) at arc length ``s``."""
        s = self.wrap(np.asarray(s, dtype=float))
        return np.arctan2(self._sy(s, 1), self._sx(s, 1))

    def curvature(self, s: np.ndarray | float) -> np.ndarray:
        """Signed curvature (1/m, positive when turning left) at arc length ``s``."""
        s = self.wrap(np.asarray(s, dtype=float))
        x1, y1 = self._sx(s, 1), self._sy(s, 1)
        x2, y2 = self._sx(s, 2), self._sy(s, 2)
        return (x1 * y2 - y1 * x2) / np.power(x1 * x1 + y1 * y1, 1.5)
