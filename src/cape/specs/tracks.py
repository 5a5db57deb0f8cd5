"""What the track and data commands read: the track files, the catalogue, the data sets, and
the reference line's settings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.config import section, setting
from cape.specs.training import Split


@dataclass(frozen=True)
class TrackEntry:
    """A track of ``tracks.catalogue``: its files' prefix and its width (m)."""

    prefix: str
    width: float


@dataclass(frozen=True)
class TracksSpec:
    """Where the verified track files are, where they come from, and the catalogue."""

    dir: str
    mirror: str | None
    upstream_url: str | None
    download_timeout: float
    catalogue: Mapping[str, TrackEntry]

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> TracksSpec:
        tracks = section(config, "tracks")
        catalogue = {
            name: TrackEntry(str(entry["prefix"]), float(entry["width"]))
            for name, entry in tracks["catalogue"].items()
        }
        return cls(
            dir=str(tracks["dir"]),
            mirror=tracks.get("mirror"),
            upstream_url=tracks.get("upstream_url"),
            download_timeout=float(setting(tracks, "download_timeout", "tracks")),
            catalogue=MappingProxyType(catalogue),
        )


@dataclass(frozen=True)
class DataTrack:
    """A track of ``data.tracks``: the raceline file its laps follow and the start heading."""

    raceline: str
    psi0: float


@dataclass(frozen=True)
class DataSettings:
    """The ``data`` section: the protocol of SPEC §3 (``cape.data.bayesrace.ProtocolSettings``
    reads it), its tracks, the tracks that train and test, and the split of the windows."""

    steps: int
    ts: float
    vx0: float
    lookahead: float
    speed_gain: float
    tracks: Mapping[str, DataTrack]
    train_track: str
    test_track: str
    split: Split

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> DataSettings:
        data = section(config, "data")
        tracks = {n: DataTrack(str(t["raceline"]), t["psi0"]) for n, t in data["tracks"].items()}
        return cls(
            steps=data["steps"],
            ts=data["ts"],
            vx0=data["vx0"],
            lookahead=data["lookahead"],
            speed_gain=data["speed_gain"],
            tracks=MappingProxyType(tracks),
            train_track=str(data["train_track"]),
            test_track=str(data["test_track"]),
            split=Split.from_config(config),
        )


@dataclass(frozen=True)
class DataSpec:
    """The data sets of SPEC §3: the track files and the ``data`` section."""

    tracks: TracksSpec
    data: DataSettings

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> DataSpec:
        return cls(TracksSpec.from_config(config), DataSettings.from_config(config))

    @property
    def racelines(self) -> dict[str, str]:
        """Each data track's raceline file."""
        return {name: track.raceline for name, track in self.data.tracks.items()}


@dataclass(frozen=True)
class ReferenceSettings:
    """The ``reference`` section (SPEC §2, §5.2): the line's track and kind (``cape``, the
    workflow's raceline, or ``bayesrace_long``), CAPE's minimum-curvature raceline (nodes,
    margin to the edge, resolution, lateral factor of the speed profile), the speed rule (scale,
    clipped to [v_min, v_max]) and the window a projection searches."""

    track: str
    line: str
    nodes: int
    margin: float
    resolution: float
    lateral_factor: float
    scale: float
    v_min: float
    v_max: float
    projection_window: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ReferenceSettings:
        reference = section(config, "reference")
        return cls(
            track=str(reference["track"]),
            line=str(reference["line"]),
            nodes=reference["nodes"],
            margin=reference["margin"],
            resolution=reference["resolution"],
            lateral_factor=reference["lateral_factor"],
            scale=reference["scale"],
            v_min=reference["v_min"],
            v_max=reference["v_max"],
            projection_window=setting(reference, "projection_window", "reference"),
        )


@dataclass(frozen=True)
class RacelineSpec:
    """CAPE's raceline of a track: the catalogue and the ``reference`` section."""

    tracks: TracksSpec
    reference: ReferenceSettings

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> RacelineSpec:
        return cls(TracksSpec.from_config(config), ReferenceSettings.from_config(config))
