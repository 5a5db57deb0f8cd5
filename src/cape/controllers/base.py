"""The controller interface (SPEC §7) and the pieces the feedback laws share.

Every controller sees the measured state and the shared reference (SPEC §5.2), returns a
command ``[T, δ]`` inside the actuator limits and steering rate of SPEC §1, and says what it
needs of an internal model (PID and RISE need none).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from cape.tracks.geometry import Projection
from cape.tracks.reference import ReferenceLine, ReferencePoints
from cape.vehicle.params import ActuatorLimits

PREVIEW_SCHEMA: dict[str, Any] = {
    "lead": {"type": "number", "minimum": 0},
    "compensate_delay": {"type": "boolean"},
}
"""The feedback laws' latency compensation (SPEC §7.1): the preview is the actuator's steering
delay (when ``compensate_delay``) plus the law's own ``lead`` (s)."""


def preview_time(settings: dict[str, Any], actuator_delay: float) -> float:
    """How far ahead the measured pose is predicted (s): the actuator's delay, if the law
    compensates it, plus the law's own lead."""
    delay = actuator_delay if settings["compensate_delay"] else 0.0
    return delay + float(settings["lead"])


def preview_pose(z: np.ndarray, t_p: float) -> tuple[float, float, float]:
    """The measured pose predicted ``t_p`` seconds ahead with the measured body velocities held
    (SPEC §7.1, latency compensation): ψ advances by ω·t_p and the position by the body velocity
    rotated to the mid-interval heading. ``t_p = 0`` returns the measured pose itself."""
    x, y, psi = float(z[0]), float(z[1]), float(z[2])
    if t_p == 0.0:
        return x, y, psi
    vx, vy, omega = float(z[3]), float(z[4]), float(z[5])
    mid = psi + 0.5 * omega * t_p
    c, s = math.cos(mid), math.sin(mid)
    return x + t_p * (vx * c - vy * s), y + t_p * (vx * s + vy * c), psi + omega * t_p


@dataclass
class PIDLoop:
    """One PID loop with a clamped integrator (anti-windup) and a saturated output."""

    kp: float
    ki: float
    kd: float
    i_max: float  # largest |ki·∫e| (output units)
    ts: float
    integral: float = 0.0
    previous: float | None = None

    def reset(self) -> None:
        self.integral, self.previous = 0.0, None

    def step(self, error: float) -> float:
        if self.ki > 0:
            bound = self.i_max / self.ki
            self.integral = min(max(self.integral + error * self.ts, -bound), bound)
        derivative = 0.0 if self.previous is None else (error - self.previous) / self.ts
        self.previous = error
        return self.kp * error + self.ki * self.integral + self.kd * derivative

    @classmethod
    def from_config(cls, gains: dict[str, float], ts: float, kp: float | None = None) -> PIDLoop:
        return cls(
            kp=float(gains["kp"] if kp is None else kp),
            ki=float(gains["ki"]),
            kd=float(gains["kd"]),
            i_max=float(gains["i_max"]),
            ts=ts,
        )


GAINS = {
    "type": "object",
    "required": ["kp", "ki", "kd", "i_max"],
    "additionalProperties": False,
    "properties": {k: {"type": "number", "minimum": 0} for k in ("kp", "ki", "kd", "i_max")},
}
"""The JSON schema of one PID loop's gains (every feedback controller's speed loop too)."""

ENTRY = {"module": {"type": "string"}, "type": {"type": "string"}, "label": {"type": "string"}}
"""The keys every controller entry may have besides its own settings."""


def validate_settings(cls: type, name: str, settings: Any, source: str = "config") -> None:
    """Check a controller entry against its class's ``settings_schema`` (a JSON schema of its
    own keys: a misspelt or missing key, a wrong type, a value out of range) and raise
    ``CapeError`` naming the key and the fix. A class without a schema is checked by its own
    ``require`` calls only."""
    from cape import schemas
    from cape.errors import CapeError

    schema = getattr(cls, "settings_schema", None)
    if schema is None:
        return
    full = {**schema, "properties": {**ENTRY, **schema.get("properties", {})}}
    validator = schemas.validator(full)
    errors = sorted(validator.iter_errors(settings), key=lambda e: list(e.absolute_path))
    if errors:
        first = errors[0]
        where = ".".join(["controllers", name, *(str(p) for p in first.absolute_path)])
        raise CapeError(
            f"{source}: `{where}`: {first.message}. Fix the entry: the {cls.__name__} class "
            f"({cls.__module__}) reads exactly the keys of its settings_schema "
            "(config/config.yaml shows every one)."
        )
    check = getattr(cls, "check_settings", None)
    if check is not None:  # what a schema cannot say (e.g. a solver's own option names)
        check(name, settings, source)


def require(settings: dict[str, Any], keys: tuple[str, ...], where: str) -> None:
    """A clear error for a missing setting, naming the config key to add."""
    missing = [k for k in keys if k not in settings]
    if missing:
        from cape.errors import CapeError

        raise CapeError(
            f"config: `{where}` lacks {', '.join(missing)}; add it (see config/config.yaml)"
        )


class Controller:
    """Base class: limits, the previous command, and the interface the rollout calls."""

    name: ClassVar[str] = "?"
    settings_schema: ClassVar[dict[str, Any] | None] = None
    """JSON schema of the config entry's own keys (checked when the workflow or a run starts)."""
    needs_internal_model: ClassVar[bool] = False
    needs_noise_levels: ClassVar[bool] = False
    """True for a controller whose design uses the run's disturbance sizes (the robust NMPC's
    EKF); it then receives ``levels=NoiseLevels`` as a keyword."""

    def __init__(
        self,
        settings: dict[str, Any],
        line: ReferenceLine,
        limits: ActuatorLimits,
        ts: float,
        track: Any = None,
        internal: Any = None,
        name: str | None = None,
        actuator_delay: float = 0.0,
    ) -> None:
        if name is not None:
            self.name = name  # the config entry's name (several entries may share one class)
        self.settings = settings
        self.line = line
        self.limits = limits
        self.ts = ts
        self.track = track  # the Track, for controllers with track constraints
        self.internal = internal  # an InternalModel, for model-based controllers
        # the steering delay of the run's actuator (s): a racing stack knows its own latency
        # (SPEC §7.1); a controller is told this, never η or a draw
        self.actuator_delay = float(actuator_delay)
        self.u_prev = np.zeros(2)
        self.phase_s: dict[str, float] = {}

    def reset(self, z0: np.ndarray) -> None:
        self.u_prev = np.zeros(2)
        self.phase_s = {}  # seconds spent in each named part of the steps (timing.json)

    def libraries(self) -> list[Path]:
        """The compiled libraries it solves with (none for a controller that solves nothing);
        ``cape build-solver`` records them."""
        return []

    def clock(self, phase: str, since: float) -> float:
        """Add the time since ``since`` (``time.perf_counter()``) to ``phase``; return now."""
        now = time.perf_counter()
        self.phase_s[phase] = self.phase_s.get(phase, 0.0) + (now - since)
        return now

    def previewed(self, z: np.ndarray, proj: Projection, t_p: float) -> tuple[Any, ...]:
        """The measured pose predicted ``t_p`` ahead (``preview_pose``) and its projection on
        the reference, searched near the measured one: what PID and RISE take their errors
        from (SPEC §7.1). ``t_p = 0``: the measurement and its projection as they are."""
        x, y, psi = preview_pose(z, t_p)
        return x, y, psi, (self.line.project(x, y, proj.s) if t_p else proj)

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        """The raw command for measured state ``z``; ``step`` applies the limits."""
        raise NotImplementedError

    def step(
        self, z: np.ndarray, proj: Projection, ref: ReferencePoints
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """The command, saturated and rate-limited, and what the controller reports."""
        u = self.limits.clip(
            self.command(z, proj, ref), delta_prev=float(self.u_prev[1]), ts=self.ts
        )
        self.u_prev = u
        return u, {}
