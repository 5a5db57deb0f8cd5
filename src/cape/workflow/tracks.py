"""The tracks stage for the rules: the verified track files, the data sets and the reference's
raceline (``TRACKS`` in the rules)."""

from __future__ import annotations

from dataclasses import dataclass

from cape.layout import paths
from cape.specs.run import RolloutSettings
from cape.specs.tracks import DataSettings, ReferenceSettings, TracksSpec
from cape.tracks.manifest import BAYESRACE_FILES


@dataclass(frozen=True)
class TrackFiles:
    """The track files' folder and the catalogue's tracks, the data sets' tracks (the one that
    trains, the one that tests), and the reference's track with the time limit its raceline is
    checked against."""

    dir: str
    tracks: tuple[str, ...]
    data_tracks: tuple[str, ...]
    train_track: str
    test_track: str
    reference_track: str
    time_limit: float
    """``rollout.time_limit``, as the config spells it (the raceline rule passes it on)."""

    @classmethod
    def of(
        cls,
        tracks: TracksSpec,
        data: DataSettings,
        reference: ReferenceSettings,
        rollout: RolloutSettings,
    ) -> TrackFiles:
        return cls(
            dir=tracks.dir,
            tracks=tuple(sorted(tracks.catalogue)),
            data_tracks=tuple(sorted(data.tracks)),
            train_track=data.train_track,
            test_track=data.test_track,
            reference_track=reference.track,
            time_limit=rollout.time_limit,
        )

    def files(self) -> list[str]:
        """The verified BayesRace files under the resources folder."""
        return [f"{self.dir}/{name}" for name in BAYESRACE_FILES]

    def raceline(self) -> str:
        """The reference track's raceline, which every run follows."""
        return paths.raceline(self.reference_track)
