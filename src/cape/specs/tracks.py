"""What the track and data commands read: the track files, the catalogue, the data sets."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.config import section


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
            download_timeout=float(tracks.get("download_timeout", 30)),
            catalogue=MappingProxyType(catalogue),
        )


@dataclass(frozen=True)
class DataSpec:
    """The data sets of SPEC §3: the ``data`` section (the protocol's settings, read by
    ``cape.data.bayesrace.ProtocolSettings``) and each data track's raceline file."""

    tracks: TracksSpec
    data: Mapping[str, Any]
    racelines: Mapping[str, str]

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> DataSpec:
        data = section(config, "data")
        racelines = {name: str(entry["raceline"]) for name, entry in data["tracks"].items()}
        return cls(TracksSpec.from_config(config), data, MappingProxyType(racelines))


@dataclass(frozen=True)
class RacelineSpec:
    """CAPE's raceline of a track: the catalogue and the ``reference`` section."""

    tracks: TracksSpec
    reference: Mapping[str, Any]

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> RacelineSpec:
        return cls(TracksSpec.from_config(config), section(config, "reference"))
