"""RISE (SPEC §7.2): the standard robust integral of the sign of the error (Xian et al. 2004)
on the cross-track error.

The paper writes RISE as a steering-rate law that makes the lateral loop a triple integrator
without damping (it cannot lap any track). CAPE implements the standard form, with the paper's
gains where they have a place:
    e1 = e_cte (positive left of the line) at the projection,
    ė1 = vx·sin(ψ − ψ_ref) + vy·cos(ψ − ψ_ref),
    e2 = ė1 + α·e1,
    δ = −[(k_s + 1)·(e2 − e2(0)) + ∫((k_s + 1)·α·e2 + β·sgn(e2)) dt],  sgn(x) ≈ tanh(x / w),
with |∫β·sgn(e2) dt| ≤ k_u (anti-windup for the robust term), and throttle from the PID speed
loop with its proportional gain set to k_v.
"""

from __future__ import annotations

import math

import numpy as np

from cape.closedloop.reference import ReferencePoints
from cape.controllers.base import Controller, PIDLoop, cross_track_error
from cape.controllers.registry import register_controller
from cape.tracks.geometry import Projection


@register_controller("rise")
class RISEController(Controller):
    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        s = self.settings
        self.speed = PIDLoop.from_config(s["speed"], self.ts, kp=s["kv"])
        self.e2_initial: float | None = None
        self.integral = 0.0
        self.sign_integral = 0.0

    def command(self, z: np.ndarray, proj: Projection, ref: ReferencePoints) -> np.ndarray:
        s = self.settings
        ks, alpha, beta, ku = float(s["ks"]), float(s["alpha"]), float(s["beta"]), float(s["ku"])
        psi_ref = float(self.line.path.heading(proj.s))
        e1 = cross_track_error(z[0], z[1], proj.x, proj.y, psi_ref)
        d_psi = z[2] - psi_ref
        e1_dot = z[3] * math.sin(d_psi) + z[4] * math.cos(d_psi)
        e2 = e1_dot + alpha * e1
        if self.e2_initial is None:
            self.e2_initial = e2
        self.integral += (ks + 1) * alpha * e2 * self.ts
        self.sign_integral = min(
            max(self.sign_integral + beta * math.tanh(e2 / s["sign_width"]) * self.ts, -ku), ku
        )
        steer = -((ks + 1) * (e2 - self.e2_initial) + self.integral + self.sign_integral)
        throttle = self.speed.step(float(ref.speed[0]) - z[3])
        return np.array([throttle, steer])
