"""RISE (SPEC §7.2): the standard robust integral of the sign of the error (Xian et al. 2004)
on the cross-track error.

The steering is the standard RISE law on e1 = e_cte, with the paper's gains where they have a
place and the anti-windup bound k_u; the throttle is the PID speed loop with its proportional
gain set to k_v. Latency compensation (SPEC §7.1–7.2): ``lead``, ``compensate_delay``,
``speed_schedule``; ``lead: 0``, ``compensate_delay: false`` and ``speed_schedule: null`` give
the law as printed (the ``rise_paper`` entry). The law's equations: docs/modules.md.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from cape.controllers.base import (
    GAINS,
    PREVIEW_SCHEMA,
    Controller,
    PIDLoop,
    preview_time,
    require,
)
from cape.controllers.registry import register_controller
from cape.tracks.geometry import Projection, cross_track_error
from cape.tracks.reference import ReferencePoints

SETTINGS = (
    "ks", "alpha", "beta", "ku", "sign_width", "kv", "speed", "lead", "compensate_delay",
    "speed_schedule",
)  # fmt: skip


@register_controller("rise")
class RISEController(Controller):
    settings_schema: ClassVar[dict[str, Any] | None] = {
        "type": "object",
        "required": list(SETTINGS),
        "additionalProperties": False,
        "properties": {
            **{k: {"type": "number", "minimum": 0} for k in ("ks", "alpha", "beta", "ku", "kv")},
            **PREVIEW_SCHEMA,
            "sign_width": {"type": "number", "exclusiveMinimum": 0},
            "speed": GAINS,
            "speed_schedule": {"type": ["number", "null"], "exclusiveMinimum": 0},
        },
    }

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        require(self.settings, SETTINGS, f"controllers.{self.name}")
        s = self.settings
        self.ks, self.alpha = float(s["ks"]), float(s["alpha"])
        self.beta, self.ku = float(s["beta"]), float(s["ku"])
        self.sign_width = float(s["sign_width"])
        self.preview = preview_time(s, self.actuator_delay)
        self.v0 = None if s["speed_schedule"] is None else float(s["speed_schedule"])

    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        s = self.settings
        self.speed = PIDLoop.from_config(s["speed"], self.ts, kp=s["kv"])
        self.e2_initial: float | None = None
        self.integral = 0.0
        self.sign_integral = 0.0

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        ks, alpha = self.ks, self.alpha
        x, y, psi, proj = self.previewed(z, proj, self.preview)
        psi_ref = self.line.path.heading_at(proj.s)
        e1 = cross_track_error(x, y, proj.x, proj.y, psi_ref)
        d_psi = psi - psi_ref
        e1_dot = z[3] * math.sin(d_psi) + z[4] * math.cos(d_psi)
        e2 = e1_dot + alpha * e1
        if self.e2_initial is None:
            self.e2_initial = e2
        self.integral += (ks + 1) * alpha * e2 * self.ts
        self.sign_integral = min(
            max(
                self.sign_integral + self.beta * math.tanh(e2 / self.sign_width) * self.ts,
                -self.ku,
            ),
            self.ku,
        )
        steer = -((ks + 1) * (e2 - self.e2_initial) + self.integral + self.sign_integral)
        if self.v0 is not None and z[3] > self.v0:
            steer *= self.v0 / float(z[3])
        throttle = self.speed.step(float(ref.speed[0]) - z[3])
        return np.array([throttle, steer])
