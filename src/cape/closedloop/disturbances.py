"""The disturbance pipeline scaled by η (SPEC §6), made of sources that plug in like models and
controllers: ``@register_source("name")`` and an entry of the config's ``disturbances`` section
(``module:`` for one outside CAPE, docs/extending.md).

A source acts through ``Source``'s hooks (``actuate``, ``plant_params``, ``after_plant``,
``measure``) when η exceeds its ``active_from`` (0 by default). At η = 0 nothing is corrupted and
no random number is drawn. One generator seeded by the run's seed serves the sources in a fixed
order, so a run is exactly repeatable. The six sources of SPEC §6: docs/modules.md.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from cape.errors import CapeError
from cape.registry import Registry
from cape.tracks.geometry import wrap_angle

VELOCITIES = slice(3, 6)
STAGES = ("actuation", "plant", "after_plant", "measurement")
"""Where a source acts: the figure's boxes."""


class Source:
    """One disturbance source. Subclasses set the class attributes, build themselves from their
    config entry at η (``from_settings``) and override the hooks they act through."""

    name: ClassVar[str] = "?"
    stages: ClassVar[tuple[str, ...]] = ()
    """The points of the loop where it acts (``STAGES``)."""
    label: ClassVar[str] = "?"
    """How the block diagram names it."""
    column: ClassVar[str] = "?"
    """Its column in table 3."""
    settings_schema: ClassVar[dict[str, Any] | None] = None
    """JSON schema of its config entry's own keys."""

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> Source:
        raise NotImplementedError

    @classmethod
    def cell(cls, settings: Mapping[str, Any], eta: float) -> str:
        """Its table-3 cell at an η where it is active: its size there, or ✓."""
        return "✓"

    def reset(self, delta0: float) -> None:
        """Before a run (the state a source keeps: a delay line, a bias)."""

    def actuate(self, u: np.ndarray) -> np.ndarray:
        return u

    def plant_params(self, params: dict[str, Any]) -> dict[str, Any]:
        return params

    def after_plant(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return x

    def measure(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return z


SOURCE_REGISTRY: Registry[Any] = Registry("source", {}, section="disturbances")
SOURCE_ORDER = ("measurement_noise", "process_noise", "steering_delay", "imu_bias", "crosswind",
                "mismatch")  # fmt: skip
"""SPEC §6's sources, in the order they act and draw their random numbers."""
register_source = SOURCE_REGISTRY.register


def source_class(name: str, settings: Mapping[str, Any] | None = None) -> type[Source]:
    """The class of the config's disturbance entry ``name`` (its ``module`` imported)."""
    return SOURCE_REGISTRY.get(name, settings or {})


def source_entries(disturbances: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    """The config's source entries (every key of ``disturbances`` but ``eta``) in the order
    they act and draw: SPEC §6's six in their fixed order, then any others by name. (Not the
    file's order, which a JSON round trip with sorted keys would change.)"""
    names = [k for k in disturbances if k != "eta"]
    rank = {name: i for i, name in enumerate(SOURCE_ORDER)}
    names.sort(key=lambda k: (rank.get(k, len(rank)), k))
    return {k: disturbances[k] for k in names}


def is_active(settings: Mapping[str, Any], eta: float) -> bool:
    return eta > float(settings.get("active_from", 0.0))


@register_source("measurement_noise")
class MeasurementNoise(Source):
    """Relative Gaussian noise on every measured state, with an absolute floor.

    The heading's noise is scaled by the heading wrapped to (−π, π] (``wrap_heading``, SPEC §6):
    a heading sensor reports an angle, not a count of turns, and the unwrapped ψ of a lap grows
    to −6.7 rad, which would make the noise ~15× larger at the end of the lap than at its start.
    The noise is added to the car's own (unwrapped) ψ. Positions keep the paper's σ·|X|, σ·|Y|,
    which depend on where the track's origin lies (docs/closed-loop.md)."""

    stages = ("measurement",)
    label = "measurement noise"
    column = "measurement noise σ (%)"

    def __init__(self, sigma: float, floor: np.ndarray, wrap_heading: bool = True) -> None:
        self.sigma, self.floor, self.wrap_heading = sigma, floor, wrap_heading

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> MeasurementNoise:
        return cls(eta * settings["sigma_per_eta"], np.asarray(settings["floor"], dtype=float),
                   bool(settings.get("wrap_heading", True)))  # fmt: skip

    @classmethod
    def cell(cls, settings: Mapping[str, Any], eta: float) -> str:
        return f"{100 * eta * settings['sigma_per_eta']:.1f}"

    def apply(self, y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        size = np.abs(y)
        if self.wrap_heading:
            size[2] = abs(wrap_angle(float(y[2])))
        return y + rng.standard_normal(y.size) * (self.sigma * size + self.floor)

    def measure(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.apply(z, rng)


@register_source("process_noise")
class ProcessNoise(Source):
    """Relative Gaussian noise on the body velocities after each plant step."""

    stages = ("after_plant",)
    label = "process noise"
    column = "process noise σ (%)"

    def __init__(self, sigma: float, floor: float) -> None:
        self.sigma, self.floor = sigma, floor

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> ProcessNoise:
        return cls(eta * settings["sigma_per_eta"], float(settings["floor"]))

    @classmethod
    def cell(cls, settings: Mapping[str, Any], eta: float) -> str:
        return f"{100 * eta * settings['sigma_per_eta']:.1f}"

    def apply(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        v = x[VELOCITIES]
        out = x.copy()
        out[VELOCITIES] = v + rng.standard_normal(3) * (self.sigma * np.abs(v) + self.floor)
        return out

    def after_plant(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.apply(x, rng)


@register_source("steering_delay")
class SteeringDelay(Source):
    """A FIFO of ``steps`` samples between the steering command and the plant."""

    stages = ("actuation",)
    label = "steering delay"
    column = "steering delay (steps)"

    def __init__(self, steps: int) -> None:
        self.steps = steps
        self._queue: deque[float] = deque()

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> SteeringDelay:
        return cls(int(settings["steps"]))

    @classmethod
    def cell(cls, settings: Mapping[str, Any], eta: float) -> str:
        return settings["steps"]

    def reset(self, delta0: float) -> None:
        self._queue = deque([delta0] * self.steps)

    def apply(self, delta_cmd: float) -> float:
        if self.steps == 0:
            return delta_cmd
        self._queue.append(delta_cmd)
        return self._queue.popleft()

    def actuate(self, u: np.ndarray) -> np.ndarray:
        return np.array([u[0], self.apply(float(u[1]))])


@register_source("imu_bias")
class ImuBias(Source):
    """Random-walk biases on the measured heading and yaw rate."""

    stages = ("measurement",)
    label = "IMU bias"
    column = "IMU bias drift"

    def __init__(self, sigma_psi: float, sigma_omega: float) -> None:
        self.sigma_psi, self.sigma_omega = sigma_psi, sigma_omega
        self.bias = np.zeros(2)

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> ImuBias:
        return cls(float(settings["sigma_psi"]), float(settings["sigma_omega"]))

    def reset(self, delta0: float = 0.0) -> None:
        self.bias = np.zeros(2)

    def apply(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        self.bias = self.bias + rng.standard_normal(2) * np.array(
            [self.sigma_psi, self.sigma_omega]
        )
        out = z.copy()
        out[2] += self.bias[0]
        out[5] += self.bias[1]
        return out

    def measure(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.apply(z, rng)


@register_source("crosswind")
class Crosswind(Source):
    """Lateral and yaw kicks after each plant step, proportional to speed and yaw rate."""

    stages = ("after_plant",)
    label = "crosswind"
    column = "crosswind"

    def __init__(
        self, vy_gain: float, vx_floor: float, omega_gain: float, omega_floor: float
    ) -> None:
        self.vy_gain, self.vx_floor = vy_gain, vx_floor
        self.omega_gain, self.omega_floor = omega_gain, omega_floor

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> Crosswind:
        return cls(settings["vy_gain"], settings["vx_floor"], settings["omega_gain"],
                   settings["omega_floor"])  # fmt: skip

    def apply(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        kick = rng.standard_normal(2)
        out = x.copy()
        out[4] += kick[0] * self.vy_gain * max(abs(x[3]), self.vx_floor)
        out[5] += kick[1] * self.omega_gain * max(abs(x[5]), self.omega_floor)
        return out

    def after_plant(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.apply(x, rng)


@register_source("mismatch")
class ParameterMismatch(Source):
    """Multiplicative changes of the plant's parameters (never the controller's)."""

    stages = ("plant",)
    label = "mismatch"
    column = "parameter mismatch"

    def __init__(self, factors: Mapping[str, float]) -> None:
        self.factors = dict(factors)

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> ParameterMismatch:
        return cls(dict(settings["factors"]))

    def apply(self, params: Mapping[str, Any]) -> dict[str, Any]:
        out = dict(params)
        for name, factor in self.factors.items():
            if name in out:
                out[name] = out[name] * factor
        return out

    def plant_params(self, params: dict[str, Any]) -> dict[str, Any]:
        return self.apply(params)


BUILTIN = {"noise": MeasurementNoise, "process": ProcessNoise, "delay": SteeringDelay,
           "bias": ImuBias, "wind": Crosswind, "mismatch": ParameterMismatch}  # fmt: skip
"""The six sources of SPEC §6 by the attribute names ``DisturbancePipeline`` gives them."""
SOURCES = SOURCE_ORDER
"""Their keys in the config's ``disturbances`` section."""


class DisturbancePipeline:
    """The active sources of one run, in the config's order, and the run's random generator.
    The six built-in sources are also attributes (``noise``, ``process``, ``delay``, ``bias``,
    ``wind``, ``mismatch``; None when inactive): the robust NMPC's EKF reads their sizes."""

    def __init__(self, eta: float, rng: np.random.Generator, sources: list[Source] | None = None,
                 **builtin: Source | None) -> None:  # fmt: skip
        self.eta = eta
        self.rng = rng
        self.sources = list(sources or []) + [
            s for key, s in builtin.items() if s is not None and key in BUILTIN
        ]

    def __getattr__(self, name: str) -> Any:
        if name in BUILTIN:
            return next((s for s in self.sources if type(s) is BUILTIN[name]), None)
        raise AttributeError(name)

    @classmethod
    def from_config(cls, settings: Mapping[str, Any], eta: float, seed: int) -> DisturbancePipeline:
        """The sources active at ``eta`` from the config's ``disturbances`` section."""
        if not eta >= 0:
            raise ValueError(f"η must be ≥ 0, got {eta}")
        sources = [
            source_class(name, entry).from_settings(entry, eta)
            for name, entry in source_entries(settings).items()
            if is_active(entry, eta)
        ]
        return cls(eta, np.random.default_rng(seed), sources)

    def steering_delay(self, ts: float) -> float:
        """The actuator's steering delay in this run (s): what a controller is told (SPEC §7.1)."""
        return self.delay.steps * ts if self.delay is not None else 0.0

    def active_sources(self) -> list[str]:
        return [s.name for s in self.sources]

    def reset(self, delta0: float = 0.0) -> None:
        for source in self.sources:
            source.reset(delta0)

    def actuate(self, u: np.ndarray) -> np.ndarray:
        """The input that reaches the plant (through the delay lines)."""
        for source in self.sources:
            u = source.actuate(u)
        return u

    def after_plant(self, x: np.ndarray) -> np.ndarray:
        """The plant's new state after the sources acting on it (process noise, crosswind)."""
        for source in self.sources:
            x = source.after_plant(x, self.rng)
        return x

    def measure(self, x: np.ndarray) -> np.ndarray:
        """What the controller sees: the state through the measuring sources."""
        z = x
        for source in self.sources:
            z = source.measure(z, self.rng)
        return z if z is not x else x.copy()

    def plant_params(self, params: Mapping[str, Any]) -> dict[str, Any]:
        p = dict(params)
        for source in self.sources:
            p = source.plant_params(p)
        return p


def validate_sources(disturbances: Mapping[str, Any], source: str = "config") -> None:
    """Each source entry against its class's ``settings_schema`` (a misspelt key, a missing
    one, a wrong type), naming ``disturbances.<name>.<key>`` and the fix."""
    from cape import schemas

    for name, entry in source_entries(disturbances).items():
        cls = source_class(name, entry)
        schema = cls.settings_schema
        if schema is None:
            continue
        full = {**schema, "properties": {"module": {"type": "string"},
                                         "active_from": {"type": "number", "minimum": 0},
                                         **schema.get("properties", {})}}  # fmt: skip
        errors = sorted(schemas.validator(full).iter_errors(entry),
                        key=lambda e: list(e.absolute_path))  # fmt: skip
        if errors:
            where = ".".join(["disturbances", name, *(str(p) for p in errors[0].absolute_path)])
            raise CapeError(
                f"{source}: `{where}`: {errors[0].message}. Fix the entry: the "
                f"{cls.__name__} source reads exactly the keys of its schema."
            )
