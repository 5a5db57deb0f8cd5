"""Example controller: pure pursuit (the data recorder's law, SPEC §3) as a closed-loop baseline.

One module plus one config entry (examples/extension.yaml) run it in every study that lists
it. The goal point lies ``lookahead`` metres of arc length ahead of the car's projection on the
reference line; the steering angle is the bicycle model's pure-pursuit law
δ = atan(2·L·sin α / L_d) with α the goal's bearing from the heading and L = lf + lr; the
throttle is proportional to the speed error, T = kp·(v_ref − vx).
"""

from __future__ import annotations

import math

import numpy as np

from cape.controllers import register_controller
from cape.controllers.base import Controller, require
from cape.tracks.geometry import Projection
from cape.tracks.reference import ReferencePoints
from cape.vehicle.params import GROUND_TRUTH


@register_controller("purepursuit")
class PurePursuitController(Controller):
    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        require(self.settings, ("lookahead", "kp"), "controllers.purepursuit")
        self.lookahead = float(self.settings["lookahead"])
        self.kp = float(self.settings["kp"])
        self.wheelbase = GROUND_TRUTH.lf + GROUND_TRUTH.lr

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        gx, gy = self.line.path.position(proj.s + self.lookahead)
        alpha = math.atan2(float(gy) - z[1], float(gx) - z[0]) - z[2]
        delta = math.atan2(2.0 * self.wheelbase * math.sin(alpha), self.lookahead)
        throttle = self.kp * (float(ref.speed[0]) - z[3])
        return np.array([throttle, delta])
