"""What one closed-loop run, or a controller's solver, reads (SPEC §5–§7)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cape.config import section
from cape.errors import CapeError
from cape.specs.tracks import TracksSpec


@dataclass(frozen=True)
class ReferenceSpec:
    """The reference line's settings and the track it is on."""

    track: str
    line: str
    """``cape`` (the workflow's raceline file) or ``bayesrace_long`` (BayesRace's own)."""
    settings: Mapping[str, Any]
    """The ``reference`` section, as ``ReferenceLine`` reads it."""
    tracks_dir: str
    prefix: str
    width: float
    ts: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ReferenceSpec:
        settings = section(config, "reference")
        tracks = TracksSpec.from_config(config)
        name = settings["track"]
        entry = tracks.catalogue[name]
        return cls(
            track=name,
            line=settings["line"],
            settings=settings,
            tracks_dir=tracks.dir,
            prefix=entry.prefix,
            width=entry.width,
            ts=float(section(config, "data")["ts"]),
        )


@dataclass(frozen=True)
class RunSpec:
    """One run's settings: the controller and its entry, the models' entries its plant and
    internal model read, the reference, the disturbances and the lap's settings."""

    controller: str
    controller_entry: Mapping[str, Any]
    models: Mapping[str, Mapping[str, Any]]
    reference: ReferenceSpec
    disturbances: Mapping[str, Any]
    ts: float
    train_track: str
    horizon: int
    time_limit: float
    vx0: float
    penalty: Mapping[str, Any]
    failure_window: float
    plant_envelope: float | None
    compile: Mapping[str, Any] | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any], controller: str) -> RunSpec:
        """``controller``'s run from a validated config (or a job's specification of one);
        ``CapeError`` for a controller the config does not have."""
        controllers = section(config, "controllers")
        if controller not in controllers:
            known = ", ".join(controllers)
            raise CapeError(
                f"--controller {controller}: not in the config's `controllers` ({known})"
            )
        rollout = section(config, "rollout")
        data = section(config, "data")
        envelope = rollout.get("plant_envelope")
        return cls(
            controller=controller,
            controller_entry=controllers[controller],
            models=section(config, "models"),
            reference=ReferenceSpec.from_config(config),
            disturbances=section(config, "disturbances"),
            ts=float(data["ts"]),
            train_track=data["train_track"],
            horizon=int(rollout["horizon"]),
            time_limit=float(rollout["time_limit"]),
            vx0=float(rollout["vx0"]),
            penalty=rollout["penalty"],
            failure_window=float(rollout.get("failure_window", 0.5)),
            plant_envelope=None if envelope is None else float(envelope),
            compile=rollout.get("compile"),
        )
