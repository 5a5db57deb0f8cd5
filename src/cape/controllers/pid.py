"""PID (SPEC §7.1): δ = PID_ψ(e_ψ) + PID_cte(−e_cte), T = PID_v(e_vx).

The errors are taken at a look-ahead point (``lookahead``: ``{time: t_L}``, the default, 0.05 s,
or ``{distance: L}``) on the measured pose predicted ahead by the actuator's steering delay plus
the law's own ``lead`` (``preview_time``); e_cte is positive left of the line. ``lead: 0`` and
``compensate_delay: false`` with a fixed look-ahead is the law as printed (the ``pid_paper``
entry). Why the compensation: docs/modules.md.
"""

from __future__ import annotations

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
from cape.tracks.geometry import Projection, cross_track_error, wrap_angle
from cape.tracks.reference import ReferencePoints

SETTINGS = ("speed", "heading", "cross_track", "lookahead", "lead", "compensate_delay")


@register_controller("pid")
class PIDController(Controller):
    settings_schema: ClassVar[dict[str, Any] | None] = {
        "type": "object",
        "required": list(SETTINGS),
        "additionalProperties": False,
        "properties": {
            "speed": GAINS,
            "heading": GAINS,
            "cross_track": GAINS,
            "lookahead": {
                "type": "object",
                "minProperties": 1,
                "maxProperties": 1,
                "additionalProperties": False,
                "properties": {
                    "time": {"type": "number", "minimum": 0},
                    "distance": {"type": "number", "minimum": 0},
                },
            },
            **PREVIEW_SCHEMA,
        },
    }

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        require(self.settings, SETTINGS, f"controllers.{self.name}")
        self.preview = preview_time(self.settings, self.actuator_delay)
        ahead = self.settings["lookahead"]
        self.lookahead_time = float(ahead.get("time", 0.0))
        self.lookahead_distance = float(ahead.get("distance", 0.0))

    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        s = self.settings
        self.speed = PIDLoop.from_config(s["speed"], self.ts)
        self.heading = PIDLoop.from_config(s["heading"], self.ts)
        self.cross = PIDLoop.from_config(s["cross_track"], self.ts)

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        x, y, psi, proj = self.previewed(z, proj, self.preview)
        ahead = self.lookahead_distance + self.lookahead_time * max(float(z[3]), 0.0)
        s_ahead = proj.s + ahead
        x_ref, y_ref = self.line.path.position_at(s_ahead)
        psi_ref = self.line.path.heading_at(s_ahead)
        e_cte = cross_track_error(x, y, float(x_ref), float(y_ref), psi_ref)
        e_psi = wrap_angle(psi_ref - psi)
        e_vx = float(ref.speed[0]) - z[3]
        steer = self.heading.step(e_psi) + self.cross.step(-e_cte)
        return np.array([self.speed.step(e_vx), steer])
