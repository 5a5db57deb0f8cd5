"""Example disturbance source: a throttle delay, the throttle command reaching the motor
``steps`` samples late (a FIFO, like the steering delay of SPEC §6).

One module plus one config entry (examples/disturbance.yaml) add it to every run, to table 3
(its own column) and to the block diagram (figure 1); nothing else changes. The class says
where it acts (``stages``), how it is named (``label``, ``column``), what its table cell shows
(``cell``), and which keys its config entry has (``settings_schema``, checked when the workflow
starts); ``from_settings`` builds it at the run's η.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from cape.closedloop.disturbances import Source, register_source


@register_source("throttle_delay")
class ThrottleDelay(Source):
    stages = ("actuation",)
    label = "throttle delay"
    column = "throttle delay (steps)"
    settings_schema: ClassVar[dict[str, Any] | None] = {
        "type": "object",
        "required": ["steps"],
        "additionalProperties": False,
        "properties": {"steps": {"type": "integer", "minimum": 0}},
    }

    def __init__(self, steps: int) -> None:
        self.steps = steps
        self._queue: deque[float] = deque()

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], eta: float) -> ThrottleDelay:
        return cls(int(settings["steps"]))

    @classmethod
    def cell(cls, settings: Mapping[str, Any], eta: float) -> str:
        return str(settings["steps"])

    def reset(self, delta0: float) -> None:
        self._queue = deque([0.0] * self.steps)  # the car starts with the throttle released

    def actuate(self, u: np.ndarray) -> np.ndarray:
        if self.steps == 0:
            return u
        self._queue.append(float(u[0]))
        return np.array([self._queue.popleft(), u[1]])
