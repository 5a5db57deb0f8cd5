"""CAPE's reference raceline (SPEC §2): minimum-curvature path and speed profile."""

from __future__ import annotations

import numpy as np
import pytest

from cape.specs.tracks import ReferenceSettings
from cape.tracks.geometry import ClosedPath
from cape.tracks.raceline import build_raceline, lap_time, min_curvature_offsets, speed_profile
from cape.tracks.track import load_track
from cape.vehicle import ACTUATOR_LIMITS, GROUND_TRUTH

A_LAT = 0.85 * (GROUND_TRUTH.Df + GROUND_TRUTH.Dr) / GROUND_TRUTH.m


@pytest.fixture(scope="module")
def mobil(track_dir, config):
    entry = config["tracks"]["catalogue"]["ETHZMobil"]
    track = load_track(track_dir, "ETHZMobil", entry["prefix"], entry["width"])
    return track, build_raceline(
        track, ReferenceSettings.from_config(config), GROUND_TRUTH, ACTUATOR_LIMITS
    )


def test_second_differences_of_a_circle_shrink_with_its_radius() -> None:
    """On a circle of radius r the second differences are r·(2 − 2cos(2π/N)): the QP moves every
    node to the inner bound (the left normal of a counter-clockwise circle points inward)."""
    theta = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    alpha, points = min_curvature_offsets(ClosedPath(np.cos(theta), np.sin(theta)), 100, 0.1)
    np.testing.assert_allclose(alpha, 0.1, atol=1e-9)
    np.testing.assert_allclose(np.hypot(*points), 0.9, atol=1e-6)


def test_raceline_on_ethzmobil(mobil, config) -> None:
    track, line = mobil
    path = line.path
    assert path.length == pytest.approx(11.4, abs=0.1)  # SPEC §2
    bound = track.width / 2 - config["reference"]["margin"]
    offsets = np.array(
        [
            abs(track.center.project(x, y).offset)
            for x, y in zip(line.x[::10], line.y[::10], strict=True)
        ]
    )
    assert offsets.max() <= bound + 2e-3  # the spline between nodes may bulge by a hair
    assert offsets.max() > 0.8 * bound  # and it does use the track
    v = np.clip(0.9 * line.speed, 1.0, 3.5)
    assert np.sum(path.segment_lengths / v) == pytest.approx(
        7.0, abs=0.15
    )  # "an ideal lap near 7.0 s"
    assert 5.0 < lap_time(line) < 7.0


def test_speed_profile_respects_the_limits(mobil) -> None:
    _, line = mobil
    path = line.path
    kappa = path.curvature(path.s_points)
    # the profile is computed on uniform samples and interpolated onto the path's points
    assert np.all(line.speed**2 * np.abs(kappa) <= A_LAT * 1.01)
    # acceleration never exceeds full throttle's, braking never the lowest throttle's
    dv2 = np.diff(np.append(line.speed, line.speed[0]) ** 2) / (2 * path.segment_lengths)
    p = GROUND_TRUTH.as_dict()
    v = line.speed
    accel_max = ((p["Cm1"] - p["Cm2"] * v) * 1.0 - p["Cr0"] - p["Cr2"] * v**2) / p["m"]
    decel_max = -((p["Cm1"] - p["Cm2"] * v) * -0.1 - p["Cr0"] - p["Cr2"] * v**2) / p["m"]
    assert np.all(dv2 <= accel_max * 1.05 + 1e-6)
    assert np.all(-dv2 <= np.roll(decel_max, -1) * 1.05 + 1e-6)


def test_speed_on_a_circle_is_the_lateral_limit() -> None:
    s = np.linspace(0, 2 * np.pi * 0.5, 300, endpoint=False)
    v = speed_profile(s, np.full(s.size, 2.0), GROUND_TRUTH, ACTUATOR_LIMITS, 0.85)
    np.testing.assert_allclose(v, np.sqrt(A_LAT / 2.0), rtol=1e-12)


def test_offset_bound_must_be_positive() -> None:
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    with pytest.raises(ValueError, match="offset bound must be positive"):
        min_curvature_offsets(ClosedPath(np.cos(theta), np.sin(theta)), 20, 0.0)
