"""Track geometry (SPEC §2): projection, arc length, heading, curvature, inside test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cape.tracks.geometry import ClosedPath, PeriodicCubicSpline
from cape.tracks.track import Track, load_track

R = 2.0
N = 3600  # polyline chord error R·(1 − cos(π/N)) ≈ 7.6e-7 m


@pytest.fixture(scope="module")
def circle() -> ClosedPath:
    """A counter-clockwise circle of radius R about the origin, starting at (R, 0)."""
    theta = np.linspace(0.0, 2 * np.pi, N, endpoint=False)
    return ClosedPath(R * np.cos(theta), R * np.sin(theta))


def test_circle_length(circle: ClosedPath) -> None:
    assert circle.length == pytest.approx(2 * N * R * math.sin(math.pi / N), rel=1e-12)
    assert circle.length == pytest.approx(2 * math.pi * R, rel=1e-5)


@pytest.mark.parametrize("angle", [0.3, 1.7, 3.0, 4.4, 6.1])
@pytest.mark.parametrize("radius", [1.7, 2.0, 2.4])
def test_projection_on_circle(circle: ClosedPath, angle: float, radius: float) -> None:
    """A point at radius r and polar angle θ projects to s ≈ R·θ with offset ≈ R − r
    (left of a counter-clockwise path is inside)."""
    proj = circle.project(radius * math.cos(angle), radius * math.sin(angle))
    # On a polyline the foot of the perpendicular from an off-circle point can slide along a
    # chord by up to |r − R|·π/N from the radial direction (≤ 3e-4 m here).
    assert proj.s == pytest.approx(R * angle, abs=abs(radius - R) * math.pi / N + 1e-5)
    assert proj.offset == pytest.approx(R - radius, abs=1e-5)
    assert math.hypot(proj.x, proj.y) == pytest.approx(R, abs=1e-6)


def test_heading_and_curvature_on_circle(circle: ClosedPath) -> None:
    s = np.linspace(0.0, circle.length, 37)
    theta = s / circle.length * 2 * np.pi
    heading = circle.heading(s)
    np.testing.assert_allclose(np.cos(heading), np.cos(theta + np.pi / 2), atol=1e-6)
    np.testing.assert_allclose(np.sin(heading), np.sin(theta + np.pi / 2), atol=1e-6)
    np.testing.assert_allclose(circle.curvature(s), 1.0 / R, rtol=1e-5)
    pos = circle.position(s)
    np.testing.assert_allclose(np.hypot(pos[0], pos[1]), R, atol=3e-5)


def test_clockwise_circle_has_negative_curvature_and_flipped_offset() -> None:
    theta = np.linspace(0.0, -2 * np.pi, 400, endpoint=False)
    cw = ClosedPath(np.cos(theta), np.sin(theta))
    np.testing.assert_allclose(cw.curvature([0.1, 2.0]), -1.0, rtol=1e-4)
    assert cw.project(0.5, 0.0).offset == pytest.approx(-0.5, abs=1e-4)  # inside is to the right


def test_closing_segment_belongs_to_the_path() -> None:
    """A square: the segment from the last point back to the first counts."""
    sq = ClosedPath(np.array([0.0, 1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0, 1.0]))
    assert sq.length == pytest.approx(4.0)
    proj = sq.project(-0.1, 0.5)  # beside the closing edge (0,1) → (0,0)
    assert proj.segment == 3
    assert proj.s == pytest.approx(3.5)
    assert proj.offset == pytest.approx(-0.1)  # outside a counter-clockwise square: right
    assert sq.project(1.2, 1.2).segment == 1  # beyond a vertex: the tie goes to the lower index


def test_repeated_closing_point_is_dropped() -> None:
    x = np.array([0.0, 1.0, 1.0, 0.0, 0.0])
    y = np.array([0.0, 0.0, 1.0, 1.0, 0.0])
    assert len(ClosedPath(x, y)) == 4 and ClosedPath(x, y).length == pytest.approx(4.0)


def test_windowed_projection_is_not_confused_by_a_hairpin() -> None:
    """A long thin loop: the two straights are 0.1 m apart. Near the lower straight, a global
    search can pick the upper one; a window around the previous progress keeps the right one."""
    top = np.linspace(10.0, 0.0, 201)
    bottom = np.linspace(0.0, 10.0, 201)[1:-1]
    path = ClosedPath(
        np.concatenate([bottom, top]), np.concatenate([np.zeros(199), np.full(201, 0.1)])
    )
    point = (5.0, 0.06)  # closer to the upper straight (0.04) than to the lower (0.06)
    global_proj = path.project(*point)
    assert global_proj.y == pytest.approx(0.1)
    s_lower = 5.0  # progress on the lower straight, which starts at (0.05, 0)
    local = path.project(*point, s_hint=s_lower, window=1.0)
    assert local.y == pytest.approx(0.0)
    assert local.offset == pytest.approx(0.06)
    assert abs(local.s - 4.95) < 1e-9


def test_window_wraps_around_the_start() -> None:
    theta = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    circle = ClosedPath(np.cos(theta), np.sin(theta))
    proj = circle.project(math.cos(-0.05), math.sin(-0.05), s_hint=0.02, window=0.2)
    assert proj.s == pytest.approx(circle.length - 0.05, abs=1e-3)


def test_periodic_spline_equals_scipys_and_is_c2_across_the_seam() -> None:
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(7)
    knots = np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.05, 300))])
    values = rng.normal(size=300)
    mine = PeriodicCubicSpline(knots, values)
    ref = CubicSpline(knots, np.append(values, values[0]), bc_type="periodic")
    s = rng.uniform(0.0, knots[-1], 2000)
    for nu in (0, 1, 2):
        scale = np.abs(ref(s, nu)).max()
        np.testing.assert_allclose(mine(s, nu), ref(s, nu), rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(mine(knots[:-1]), values, atol=1e-13)  # interpolates
    eps = 1e-9
    for nu in (0, 1, 2):  # continuous through the seam at the loop's start
        assert mine(knots[-1] - eps, nu) == pytest.approx(mine(eps, nu), rel=1e-5, abs=1e-6)
    np.testing.assert_allclose(mine(s + 2 * knots[-1]), mine(s), atol=1e-12)  # wraps
    with pytest.raises(ValueError, match="increasing knots"):
        PeriodicCubicSpline(knots[::-1], values)


def test_invalid_paths_are_rejected() -> None:
    with pytest.raises(ValueError, match="≥ 3 points"):
        ClosedPath(np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="zero-length"):
        ClosedPath(np.array([0.0, 1.0, 1.0, 2.0]), np.array([0.0, 0.0, 0.0, 1.0]))


def test_real_tracks_inside_test(track_dir, config) -> None:
    """On ETHZMobil (width 0.46 m) the centre line is inside, the boundaries are at ±w/2."""
    entry = config["tracks"]["catalogue"]["ETHZMobil"]
    track: Track = load_track(track_dir, "ETHZMobil", entry["prefix"], entry["width"])
    assert track.width == 0.46
    assert track.inside(track.center.x[10], track.center.y[10])
    # a point 0.2 m and one 0.26 m off the centre line, along its normal
    s = track.center.s_points[40]
    h = float(track.center.heading(s))
    cx, cy = track.center.position(s)
    nx, ny = -math.sin(h), math.cos(h)
    assert track.inside(cx + 0.2 * nx, cy + 0.2 * ny)
    assert not track.inside(cx + 0.26 * nx, cy + 0.26 * ny)
    assert track.center.project(cx + 0.2 * nx, cy + 0.2 * ny).offset == pytest.approx(0.2, abs=1e-3)
    # the published boundaries lie half a width from the centre line
    offsets = [abs(track.center.project(x, y).offset) for x, y in track.outer.T[::25]]
    np.testing.assert_allclose(offsets, 0.23, atol=2e-3)


@pytest.fixture()
def kernel(tmp_path):
    """The compiled projection (cape.tracks.native), switched off again after the test."""
    from cape.tracks import native

    loaded = native.enable({"enabled": True, "cache": str(tmp_path), "compiler": "gcc",
                            "flags": ["-O2"]})  # fmt: skip
    if loaded is None:
        pytest.skip("no C compiler: the NumPy projection runs alone")
    native.disable()
    yield loaded
    native.disable()


def test_the_compiled_projection_gives_numpys_bits(kernel, track_dir) -> None:
    """On a real track's centre line and a dense closed line through it: random points near
    the path, points at its vertices (where two segments tie), windows that wrap round the
    start, and no window; every field of every projection the same bits."""
    from cape.tracks import geometry

    centre = load_track(track_dir, "ETHZMobil", "ethzMobil", 0.46).center
    dense = ClosedPath(*centre.position(np.linspace(0.0, centre.length, 1200, endpoint=False)))
    rng = np.random.default_rng(7)
    for path in (centre, dense):
        s = np.concatenate([rng.uniform(0, path.length, 1500), rng.uniform(-0.3, 0.3, 300)])
        points = path.position(s) + rng.normal(0.0, 0.08, (2, s.size))
        vertices = rng.integers(0, len(path), 300)
        points = np.hstack([points, np.vstack([path.x[vertices], path.y[vertices]])])
        hints = np.mod(np.concatenate([s, path.s_points[vertices]]) + 0.02, path.length)
        for (px, py), hint in zip(points.T, hints, strict=True):
            for window in (0.5, None):
                h = hint if window else None
                geometry._kernel = None
                expected = path.project(px, py, h, window)
                geometry._kernel = kernel
                assert path.project(px, py, h, window) == expected
        geometry._kernel = None


def test_scalar_evaluation_of_a_reference_point_matches_the_arrays(track_dir) -> None:
    """``ReferencePoints.at`` (what the loop reads each step) against the vectorised arrays."""
    from cape.tracks.reference import ReferencePoints

    path = load_track(track_dir, "ETHZMobil", "ethzMobil", 0.46).center
    s = np.random.default_rng(3).uniform(-1.0, path.length + 1.0, 2000)
    ref = ReferencePoints(s=s, speed=np.ones_like(s), path=path)
    for k in range(s.size):
        assert ref.at(k) == (ref.x[k], ref.y[k], ref.heading[k])


@pytest.mark.parametrize("block", [1, 7, 64, 100_000])
def test_projecting_many_points_gives_each_points_projection(track_dir, monkeypatch, block) -> None:
    """``project_many`` (the NMPC's track lookup) against ``project`` point by point, whatever
    its block size: random points near a real centre line and its vertices, where two
    segments tie and the lower index must win."""
    from cape.tracks import geometry

    monkeypatch.setattr(geometry, "_kernel", None)
    monkeypatch.setattr(geometry, "PROJECT_BLOCK", block)
    path = load_track(track_dir, "ETHZMobil", "ethzMobil", 0.46).center
    rng = np.random.default_rng(11)
    points = path.position(rng.uniform(0, path.length, 200)) + rng.normal(0, 0.1, (2, 200))
    points = np.hstack([points, np.vstack([path.x[:50], path.y[:50]])])
    s, nearest = path.project_many(*points)
    for k, (px, py) in enumerate(points.T):
        proj = path.project(px, py)
        assert (s[k], nearest[k, 0], nearest[k, 1]) == (proj.s, proj.x, proj.y)
