"""Typed parameter sets of the car (SPEC §1).

The ground-truth set is the data-generating simulator: the published BayesRace data sets are
reproduced from it bit for bit, so it is a fact of the study, not a tunable number. Other
sets (a mismatched plant, a learned model's frozen Φ) are made from it with ``replace``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

GRAVITY = 9.81
"""Gravitational acceleration (m/s²), SPEC §1."""


@dataclass(frozen=True)
class VehicleParams:
    """Geometry, inertia, drivetrain and Pacejka tyre parameters of the single-track model."""

    lf: float
    lr: float
    m: float
    Iz: float
    Cm1: float
    Cm2: float
    Cr0: float
    Cr2: float
    Bf: float
    Cf: float
    Df: float
    Ef: float
    Br: float
    Cr: float
    Dr: float
    Er: float
    Shf: float = 0.0
    Svf: float = 0.0
    Shr: float = 0.0
    Svr: float = 0.0

    def as_dict(self) -> dict[str, float]:
        """The parameters by name, the mapping the equations read."""
        return dataclasses.asdict(self)

    def replace(self, **changes: float) -> VehicleParams:
        """A copy with some parameters changed; unknown names are an error."""
        unknown = set(changes) - set(self.as_dict())
        if unknown:
            raise KeyError(
                f"unknown vehicle parameter(s) {sorted(unknown)}; known: {sorted(self.as_dict())}"
            )
        return dataclasses.replace(self, **changes)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))


GROUND_TRUTH = VehicleParams(
    lf=0.029,
    lr=0.033,
    m=0.041,
    Iz=27.8e-6,
    Cm1=0.287,
    Cm2=0.0545,
    Cr0=0.0518,
    Cr2=0.00035,
    Bf=5.579,
    Cf=1.2,
    Df=0.192,
    Ef=-0.083,
    Br=5.3852,
    Cr=1.2691,
    Dr=0.1737,
    Er=-0.019,
    Shf=-0.0013,
    Svf=0.00043,
    Shr=-0.00376,
    Svr=0.00091,
)
"""The data-generating parameter set of SPEC §1."""


@dataclass(frozen=True)
class ActuatorLimits:
    """Bounds every controller respects: throttle, steering angle and steering rate."""

    T_min: float = -0.1
    T_max: float = 1.0
    delta_max: float = 0.35
    delta_rate_max: float = 5.0  # rad/s

    def max_steering_step(self, ts: float) -> float:
        """Largest steering change in one sample of length ``ts`` (0.1 rad at 50 Hz)."""
        return self.delta_rate_max * ts

    def clip(self, u: Any, delta_prev: float | None = None, ts: float | None = None) -> np.ndarray:
        """Saturate a command ``[T, δ]``; with ``delta_prev`` and ``ts`` also its steering rate."""
        throttle, steer = float(u[0]), float(u[1])
        throttle = min(max(throttle, self.T_min), self.T_max)
        if delta_prev is not None:
            if ts is None:
                raise ValueError("a steering-rate limit needs the sampling time ts")
            step = self.max_steering_step(ts)
            steer = min(max(steer, delta_prev - step), delta_prev + step)
        steer = min(max(steer, -self.delta_max), self.delta_max)
        return np.array([throttle, steer])


ACTUATOR_LIMITS = ActuatorLimits()
"""The limits of SPEC §1: T ∈ [−0.1, 1], δ ∈ [−0.35, 0.35] rad, |δ̇| ≤ 5 rad/s."""
