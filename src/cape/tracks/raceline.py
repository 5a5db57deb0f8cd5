"""CAPE's own reference raceline (SPEC §2): one minimum-curvature QP and a friction-limited
speed profile.

For any track: lateral offsets along the centre line's normals at equally spaced nodes, from one
bounded least-squares problem (|α_i| ≤ width/2 − margin), then a periodic spline through the
points; the speed profile is a forward–backward pass over two laps. Why not the BayesRace
racelines, and why the curvature is not iterated: docs/modules.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from cape.specs.tracks import ReferenceSettings
from cape.tracks.geometry import ClosedPath
from cape.tracks.track import Track
from cape.vehicle.dynamics import drivetrain_force
from cape.vehicle.params import ActuatorLimits, VehicleParams


@dataclass(frozen=True)
class Raceline:
    """A closed reference path sampled densely, with its speed profile (unscaled, m/s)."""

    x: np.ndarray
    y: np.ndarray
    speed: np.ndarray

    @property
    def path(self) -> ClosedPath:
        return ClosedPath(self.x, self.y)


def min_curvature_offsets(
    center: ClosedPath, nodes: int, bound: float
) -> tuple[np.ndarray, np.ndarray]:
    """Offsets α (nodes,) along the centre line's left normals and the path points (2, nodes).

    Minimises Σ‖p_{i−1} − 2p_i + p_{i+1}‖² (cyclic) with p_i = c_i + α_i·n_i, |α_i| ≤ bound.
    """
    if bound <= 0:
        raise ValueError(f"the offset bound must be positive (width/2 − margin), got {bound}")
    s = np.linspace(0.0, center.length, nodes, endpoint=False)
    c = center.position(s)
    heading = center.heading(s)
    normal = np.stack([-np.sin(heading), np.cos(heading)])
    eye = np.eye(nodes)
    second = np.roll(eye, -1, axis=1) - 2 * eye + np.roll(eye, 1, axis=1)  # cyclic D
    a = np.vstack([second * normal[0], second * normal[1]])  # D·diag(n)
    b = np.concatenate([second @ c[0], second @ c[1]])
    solution = lsq_linear(a, -b, bounds=(-bound, bound), method="bvls", tol=1e-12)
    alpha = solution.x
    return alpha, c + alpha * normal


def speed_profile(
    s: np.ndarray,
    curvature: np.ndarray,
    params: VehicleParams,
    limits: ActuatorLimits,
    lateral_factor: float,
    laps: int = 2,
) -> np.ndarray:
    """Friction-limited speed along a closed path sampled at arc lengths ``s`` (uniform step).

    Lateral limit ``a_lat = lateral_factor·(Df + Dr)/m``; forward pass with the drivetrain
    at full throttle, backward pass braking at the lowest throttle; both over ``laps`` laps
    so that the start of the loop is consistent with its end.
    """
    p = params.as_dict()
    ds = float(s[1] - s[0])
    a_lat = lateral_factor * (params.Df + params.Dr) / params.m
    v_corner = np.sqrt(a_lat / np.maximum(np.abs(curvature), 1e-9))
    n = s.size
    v = np.tile(v_corner, laps)
    for i in range(1, v.size):  # accelerate
        u = v[i - 1]
        accel = max(float(drivetrain_force(u, limits.T_max, p)) / params.m, 0.0)
        v[i] = min(v[i], np.sqrt(u * u + 2 * accel * ds))
    fwd = v[-n:].copy()
    v = np.tile(fwd, laps)
    for i in range(v.size - 2, -1, -1):  # brake
        u = v[i + 1]
        decel = max(-float(drivetrain_force(u, limits.T_min, p)) / params.m, 0.0)
        v[i] = min(v[i], np.sqrt(u * u + 2 * decel * ds))
    return v[:n]


def build_raceline(
    track: Track, settings: ReferenceSettings, params: VehicleParams, limits: ActuatorLimits
) -> Raceline:
    """The minimum-curvature raceline of ``track`` with its speed profile (``settings``: the
    ``reference`` section's nodes, margin, resolution and lateral factor)."""
    bound = track.width / 2 - float(settings.margin)
    _, points = min_curvature_offsets(track.center, int(settings.nodes), bound)
    spline_path = ClosedPath(points[0], points[1])
    samples = max(int(np.ceil(spline_path.length / float(settings.resolution))), 3)
    s = np.linspace(0.0, spline_path.length, samples, endpoint=False)
    xy = spline_path.position(s)
    dense = ClosedPath(xy[0], xy[1])
    s_dense = dense.s_points
    uniform = np.linspace(0.0, dense.length, samples, endpoint=False)
    kappa = dense.curvature(uniform)
    v = speed_profile(uniform, kappa, params, limits, float(settings.lateral_factor))
    speed = np.interp(s_dense, uniform, v, period=dense.length)
    return Raceline(x=xy[0], y=xy[1], speed=speed)


def lap_time(line: Raceline) -> float:
    """Time to drive one lap at the line's speed profile (trapezoidal in 1/v)."""
    path = line.path
    inv = 1.0 / line.speed
    return float(np.sum(path.segment_lengths * 0.5 * (inv + np.roll(inv, -1))))
