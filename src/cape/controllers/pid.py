"""PID (SPEC §7.1): δ = PID_ψ(e_ψ) + PID_cte(−e_cte), T = PID_v(e_vx).

Heading and cross-track errors are taken at a look-ahead point just ahead of the projection
(configurable; SPEC default 0.05 m). e_cte is the paper's (positive left of the line), so it
enters negated: a car left of the line steers right.
"""

from __future__ import annotations

import numpy as np

from cape.closedloop.reference import ReferencePoints
from cape.controllers.base import Controller, PIDLoop, cross_track_error, wrap_angle
from cape.controllers.registry import register_controller
from cape.tracks.geometry import Projection


@register_controller("pid")
class PIDController(Controller):
    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        s = self.settings
        self.speed = PIDLoop.from_config(s["speed"], self.ts)
        self.heading = PIDLoop.from_config(s["heading"], self.ts)
        self.cross = PIDLoop.from_config(s["cross_track"], self.ts)

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        s_ahead = proj.s + float(self.settings["lookahead"])
        x_ref, y_ref = self.line.path.position(s_ahead)
        psi_ref = float(self.line.path.heading(s_ahead))
        e_cte = cross_track_error(z[0], z[1], float(x_ref), float(y_ref), psi_ref)
        e_psi = wrap_angle(psi_ref - z[2])
        e_vx = float(ref.speed[0]) - z[3]
        steer = self.heading.step(e_psi) + self.cross.step(-e_cte)
        return np.array([self.speed.step(e_vx), steer])
