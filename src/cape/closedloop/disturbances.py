"""The disturbance pipeline scaled by η (SPEC §6).

Six sources, each a small object with one job, composed by ``DisturbancePipeline``:

- measurement noise  z = y + N(0, (σ·|y| + ε)²) per state, σ = η·``sigma_per_eta``, the
                     heading's |y| taken on the heading wrapped to (−π, π]
- process noise      [vx, vy, ω] += N(0, (2η/100·|·| + ε)²) after each plant step
- steering delay     the steering command reaches the plant ``steps`` samples late (FIFO)
- IMU bias drift     random walks added to the measured ψ and ω
- crosswind          vy and ω kicked after each plant step
- parameter mismatch the plant's mass, cornering stiffnesses and friction scaled

A source is active when η exceeds its ``active_from`` (0 by default: any η > 0); at η = 0
nothing is corrupted and no random number is drawn, so every seed gives the same run. All
draws come from one generator seeded by the run's seed, in a fixed order, so a run is exactly
repeatable.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cape.tracks.geometry import wrap_angle

VELOCITIES = slice(3, 6)
SOURCES = ("measurement_noise", "process_noise", "steering_delay", "imu_bias", "crosswind",
           "mismatch")  # fmt: skip
"""The sources' keys in the config's ``disturbances`` section."""


@dataclass
class MeasurementNoise:
    """Relative Gaussian noise on every measured state, with an absolute floor.

    The heading's noise is scaled by the heading wrapped to (−π, π] (``wrap_heading``, SPEC §6):
    a heading sensor reports an angle, not a count of turns, and the unwrapped ψ of a lap grows
    to −6.7 rad, which would make the noise ~15× larger at the end of the lap than at its start.
    The noise is added to the car's own (unwrapped) ψ. Positions keep the paper's σ·|X|, σ·|Y|,
    which depend on where the track's origin lies (docs/closed-loop.md)."""

    sigma: float
    floor: np.ndarray
    wrap_heading: bool = True

    def apply(self, y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        size = np.abs(y)
        if self.wrap_heading:
            size[2] = abs(wrap_angle(float(y[2])))
        return y + rng.standard_normal(y.size) * (self.sigma * size + self.floor)


@dataclass
class ProcessNoise:
    """Relative Gaussian noise on the body velocities after each plant step."""

    sigma: float
    floor: float

    def apply(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        v = x[VELOCITIES]
        out = x.copy()
        out[VELOCITIES] = v + rng.standard_normal(3) * (self.sigma * np.abs(v) + self.floor)
        return out


@dataclass
class SteeringDelay:
    """A FIFO of ``steps`` samples between the steering command and the plant."""

    steps: int
    _queue: deque[float] = field(default_factory=deque, repr=False)

    def reset(self, delta0: float) -> None:
        self._queue = deque([delta0] * self.steps)

    def apply(self, delta_cmd: float) -> float:
        if self.steps == 0:
            return delta_cmd
        self._queue.append(delta_cmd)
        return self._queue.popleft()


@dataclass
class ImuBias:
    """Random-walk biases on the measured heading and yaw rate."""

    sigma_psi: float
    sigma_omega: float
    bias: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def reset(self) -> None:
        self.bias = np.zeros(2)

    def apply(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        self.bias = self.bias + rng.standard_normal(2) * np.array(
            [self.sigma_psi, self.sigma_omega]
        )
        out = z.copy()
        out[2] += self.bias[0]
        out[5] += self.bias[1]
        return out


@dataclass
class Crosswind:
    """Lateral and yaw kicks after each plant step, proportional to speed and yaw rate."""

    vy_gain: float
    vx_floor: float
    omega_gain: float
    omega_floor: float

    def apply(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        kick = rng.standard_normal(2)
        out = x.copy()
        out[4] += kick[0] * self.vy_gain * max(abs(x[3]), self.vx_floor)
        out[5] += kick[1] * self.omega_gain * max(abs(x[5]), self.omega_floor)
        return out


@dataclass
class ParameterMismatch:
    """Multiplicative changes of the plant's parameters (never the controller's)."""

    factors: Mapping[str, float]

    def apply(self, params: Mapping[str, Any]) -> dict[str, Any]:
        out = dict(params)
        for name, factor in self.factors.items():
            if name in out:
                out[name] = out[name] * factor
        return out


@dataclass
class DisturbancePipeline:
    """The active sources for one run, and the run's random generator."""

    eta: float
    rng: np.random.Generator
    noise: MeasurementNoise | None = None
    process: ProcessNoise | None = None
    delay: SteeringDelay | None = None
    bias: ImuBias | None = None
    wind: Crosswind | None = None
    mismatch: ParameterMismatch | None = None

    @classmethod
    def from_config(cls, settings: Mapping[str, Any], eta: float, seed: int) -> DisturbancePipeline:
        """Build the sources active at ``eta`` from the config's ``disturbances`` section."""
        if eta < 0:
            raise ValueError(f"η must be ≥ 0, got {eta}")

        def active(name: str) -> Mapping[str, Any] | None:
            entry = settings[name]
            return entry if eta > float(entry.get("active_from", 0.0)) else None

        pipe = cls(eta=eta, rng=np.random.default_rng(seed))
        if cfg := active("measurement_noise"):
            pipe.noise = MeasurementNoise(
                eta * cfg["sigma_per_eta"],
                np.asarray(cfg["floor"], dtype=float),
                bool(cfg.get("wrap_heading", True)),
            )
        if cfg := active("process_noise"):
            pipe.process = ProcessNoise(eta * cfg["sigma_per_eta"], float(cfg["floor"]))
        if cfg := active("steering_delay"):
            pipe.delay = SteeringDelay(int(cfg["steps"]))
        if cfg := active("imu_bias"):
            pipe.bias = ImuBias(float(cfg["sigma_psi"]), float(cfg["sigma_omega"]))
        if cfg := active("crosswind"):
            pipe.wind = Crosswind(
                cfg["vy_gain"], cfg["vx_floor"], cfg["omega_gain"], cfg["omega_floor"]
            )
        if cfg := active("mismatch"):
            pipe.mismatch = ParameterMismatch(dict(cfg["factors"]))
        return pipe

    def active_sources(self) -> list[str]:
        names = ("noise", "process", "delay", "bias", "wind", "mismatch")
        return [n for n in names if getattr(self, n) is not None]

    def reset(self, delta0: float = 0.0) -> None:
        if self.delay is not None:
            self.delay.reset(delta0)
        if self.bias is not None:
            self.bias.reset()

    def actuate(self, u: np.ndarray) -> np.ndarray:
        """The input that reaches the plant: the steering through the delay line."""
        if self.delay is None:
            return u
        return np.array([u[0], self.delay.apply(float(u[1]))])

    def after_plant(self, x: np.ndarray) -> np.ndarray:
        """Process noise, then crosswind, on the plant's new state."""
        if self.process is not None:
            x = self.process.apply(x, self.rng)
        if self.wind is not None:
            x = self.wind.apply(x, self.rng)
        return x

    def measure(self, x: np.ndarray) -> np.ndarray:
        """What the controller sees: noise, then the IMU biases."""
        z = x
        if self.noise is not None:
            z = self.noise.apply(z, self.rng)
        if self.bias is not None:
            z = self.bias.apply(z, self.rng)
        return z if z is not x else x.copy()

    def plant_params(self, params: Mapping[str, Any]) -> dict[str, Any]:
        return dict(params) if self.mismatch is None else self.mismatch.apply(params)
