"""Adaptive NMPC (SPEC §7.4): the nominal NMPC whose drivetrain parameters are corrected online.

Θ = (Cm1, Cr0, Cr2), held as factors of the internal model's own values (nominal Θ = 1), takes
one gradient step of size α every ``every`` steps on the mean squared one-step prediction error
of [vx, vy, ω] over the last ``every`` steps, projected onto [low, high]. For DPM the factors
act on the drivetrain law and the difference is added to its force
(``InternalModel.corrected``). Details: docs/modules.md.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from cape.controllers.base import require
from cape.controllers.internal import N_STATE
from cape.controllers.nmpc import NMPC_SCHEMA, NominalNMPC
from cape.controllers.registry import register_controller
from cape.numerics.compiled import serialized_function, source_digest
from cape.tracks.geometry import Projection
from cape.tracks.reference import ReferencePoints


@register_controller("anmpc")
class AdaptiveNMPC(NominalNMPC):
    settings_schema: ClassVar[dict[str, Any] | None] = {
        **NMPC_SCHEMA,
        "required": [*NMPC_SCHEMA["required"], "adaptive"],
        "properties": {
            **NMPC_SCHEMA["properties"],
            "adaptive": {
                "type": "object",
                "required": ["every", "alpha", "epsilon", "bounds"],
                "additionalProperties": False,
                "properties": {
                    "every": {"type": "integer", "minimum": 1},
                    "alpha": {"type": "number", "minimum": 0},
                    "epsilon": {"type": "number", "exclusiveMinimum": 0},
                    "bounds": {
                        "type": "array",
                        "items": {"type": "number", "minimum": 0},
                        "minItems": 2,
                        "maxItems": 2,
                    },
                },
            },
        },
    }

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        require(self.settings, ("adaptive",), f"controllers.{self.name}")
        a = self.settings["adaptive"]
        require(a, ("every", "alpha", "epsilon", "bounds"), f"controllers.{self.name}.adaptive")
        self.every = int(a["every"])
        self.alpha = float(a["alpha"])
        self.eps = float(a["epsilon"])
        self.low, self.high = (float(v) for v in a["bounds"])
        key, cache = self._adaptation_key(), self.settings.get("compile")
        self._adapt = serialized_function("anmpc_adapt", key, self._build_adaptation, cache)

    def _adaptation_key(self) -> str:
        """What the adaptation function depends on: one step of the internal model (serialised:
        its equations and the constants it holds), the adaptation's settings, and this module's
        source (how the loss and its differences are formed from that step)."""
        internal = self.internal
        x, u = ca.SX.sym("x", N_STATE), ca.SX.sym("u", 2)
        phi, theta = ca.SX.sym("phi", internal.n_phi), ca.SX.sym("theta", 3)
        step = ca.Function("step", [x, u, phi, theta], [internal.step(x, u, phi, None, theta)])
        settings = (self.every, self.alpha, self.eps, self.low, self.high)
        return f"{step.serialize()}|{settings}|{source_digest(sys.modules[__name__])}"

    def _build_adaptation(self) -> ca.Function:
        """(states, inputs, Φs, measured next velocities, Θ) → (Θ after one projected
        gradient step, the loss at Θ)."""
        m, internal = self.every, self.internal
        xs = ca.SX.sym("x", N_STATE, m)
        us = ca.SX.sym("u", 2, m)
        phis = ca.SX.sym("phi", internal.n_phi, m)
        vs = ca.SX.sym("v", 3, m)
        theta = ca.SX.sym("theta", 3)

        def loss(th: ca.SX) -> ca.SX:
            err = [
                internal.step(xs[:, j], us[:, j], phis[:, j], None, th)[3:6] - vs[:, j]
                for j in range(m)
            ]
            return ca.sumsqr(ca.horzcat(*err)) / (3 * m)

        base = loss(theta)
        grad = ca.vertcat(
            *[(loss(theta + self.eps * ca.DM.eye(3)[:, i]) - base) / self.eps for i in range(3)]
        )
        updated = ca.fmin(ca.fmax(theta - self.alpha * grad, self.low), self.high)
        return ca.Function("anmpc_adapt", [xs, us, phis, vs, theta], [updated, base])

    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        self.theta_now = np.ones(3)
        self.losses: list[float] = []
        self._samples: deque[tuple[np.ndarray, ...]] = deque(maxlen=self.every)
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._since_update = 0

    def theta(self) -> np.ndarray:
        return self.theta_now

    def step(
        self, z: np.ndarray, proj: Projection, ref: ReferencePoints
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if self._pending is not None:  # the last step's prediction can now be scored
            x, u, phi = self._pending
            self._samples.append((x, u, phi, np.asarray(z[3:6], dtype=float)))
            self._since_update += 1
            if self._since_update >= self.every and len(self._samples) == self.every:
                start = time.perf_counter()
                self._update()
                self.clock("adaptation", start)
        x_now = np.concatenate([z, self.u_prev])
        u, info = super().step(z, proj, ref)
        self._pending = (x_now, u.copy(), np.asarray(self.phi_now, dtype=float))
        info["theta"] = self.theta_now.copy()
        return u, info

    def _update(self) -> None:
        xs, us, phis, vs = (np.column_stack(c) for c in zip(*self._samples, strict=True))
        theta, loss = self._adapt(xs, us, phis, vs, self.theta_now)
        self.theta_now = np.asarray(theta, dtype=float).ravel()
        self.losses.append(float(loss))
        self._since_update = 0
