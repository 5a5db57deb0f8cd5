"""Track data (obtained and verified) and track geometry (SPEC §2)."""

from cape.tracks.geometry import ClosedPath, Projection
from cape.tracks.manifest import BAYESRACE_FILES, UPSTREAM_COMMIT
from cape.tracks.track import Raceline, Track, load_raceline, load_track

__all__ = [
    "BAYESRACE_FILES",
    "UPSTREAM_COMMIT",
    "ClosedPath",
    "Projection",
    "Raceline",
    "Track",
    "load_raceline",
    "load_track",
]
