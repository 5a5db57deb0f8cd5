"""What one closed-loop run, or a controller's solver, reads (SPEC §5–§7)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cape.config import section, setting
from cape.specs import Entry, as_record, entries, entry_of
from cape.specs.tracks import ReferenceSettings, TracksSpec


@dataclass(frozen=True)
class ReferenceSpec:
    """The reference line's settings and the track it is on."""

    track: str
    line: str
    """``cape`` (the workflow's raceline file) or ``bayesrace_long`` (BayesRace's own)."""
    settings: ReferenceSettings
    """The ``reference`` section, as ``ReferenceLine`` reads it."""
    tracks_dir: str
    prefix: str
    width: float
    ts: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ReferenceSpec:
        settings = ReferenceSettings.from_config(config)
        tracks = TracksSpec.from_config(config)
        entry = tracks.catalogue[settings.track]
        return cls(
            track=settings.track,
            line=settings.line,
            settings=settings,
            tracks_dir=tracks.dir,
            prefix=entry.prefix,
            width=entry.width,
            ts=float(section(config, "data")["ts"]),
        )


@dataclass(frozen=True)
class DisturbancesSpec:
    """The ``disturbances`` section (SPEC §6): the η grid and the sources, each a registered
    class's own entry (cape/closedloop/disturbances.py reads them)."""

    eta: tuple[str, ...]
    sources: Mapping[str, Entry]
    """Every entry but ``eta``, by name."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> DisturbancesSpec:
        disturbances = section(config, "disturbances")
        sources = {k: v for k, v in disturbances.items() if k != "eta"}
        return cls(tuple(disturbances.get("eta") or ()), entries(sources))


@dataclass(frozen=True)
class Penalty:
    """``rollout.penalty``: what a failed run counts as in the penalised metrics."""

    lap_time: float
    tracking_error: float


@dataclass(frozen=True)
class PhiCompile:
    """``rollout.compile``: the learned models' Φ and the projections as compiled C (``enabled``),
    with the compiler, its flags and the cache folder; a key the section leaves out is None."""

    enabled: bool | None
    cache: str | None
    compiler: str | None
    flags: tuple[str, ...] | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> PhiCompile | None:
        """None when the rollout section has no ``compile``."""
        given = section(config, "rollout").get("compile")
        if given is None:
            return None
        flags = given.get("flags")
        return cls(
            given.get("enabled"),
            given.get("cache"),
            given.get("compiler"),
            None if flags is None else tuple(flags),
        )

    def as_settings(self) -> dict[str, Any]:
        """The keys it was given, as the compiling code reads them (cape/numerics sits below the
        specs, and compiles the controllers' NLPs from their own entries the same way)."""
        return {k: v for k, v in as_record(self).items() if v is not None}


@dataclass(frozen=True)
class RolloutSettings:
    """The ``rollout`` section: one lap's settings and how a run is judged and bounded."""

    vx0: float
    time_limit: float
    horizon: int
    penalty: Penalty
    failure_window: float
    plant_envelope: float | None
    """A learned plant's bound, a multiple of the training data's largest state; None: none."""
    compile: PhiCompile | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> RolloutSettings:
        """The config's values as it spells them (15 stays 15, not 15.0: the workflow passes
        ``time_limit`` on the command line), checked by the schema."""
        rollout = section(config, "rollout")
        penalty = rollout["penalty"]
        return cls(
            vx0=rollout["vx0"],
            time_limit=rollout["time_limit"],
            horizon=rollout["horizon"],
            penalty=Penalty(penalty["lap_time"], penalty["tracking_error"]),
            failure_window=setting(rollout, "failure_window", "rollout"),
            plant_envelope=setting(rollout, "plant_envelope", "rollout"),
            compile=PhiCompile.from_config(config),
        )


@dataclass(frozen=True)
class RunSpec:
    """One run's settings: the controller and its entry, the models' entries its plant and
    internal model read, the reference, the disturbances and the lap's settings."""

    controller: str
    controller_entry: Entry
    models: Mapping[str, Entry]
    reference: ReferenceSpec
    disturbances: DisturbancesSpec
    ts: float
    train_track: str
    rollout: RolloutSettings

    @classmethod
    def from_config(cls, config: Mapping[str, Any], controller: str) -> RunSpec:
        """``controller``'s run from a validated config (or a job's specification of one);
        ``CapeError`` for a controller the config does not have."""
        controllers = section(config, "controllers")
        data = section(config, "data")
        return cls(
            controller=controller,
            controller_entry=entry_of(controllers, controller, "--controller", "controllers"),
            models=entries(section(config, "models")),
            reference=ReferenceSpec.from_config(config),
            disturbances=DisturbancesSpec.from_config(config),
            ts=float(data["ts"]),
            train_track=str(data["train_track"]),
            rollout=RolloutSettings.from_config(config),
        )
