"""Robust NMPC (SPEC §7.5): the nominal NMPC fed by an EKF, with an additive disturbance
estimate in its prediction and a track margin that grows with the recent prediction error.

- the EKF's estimate replaces the measured state (``estimate``);
- d̂ = low-pass of (x̂_k − x_k^model)/Ts on [vx, vy, ω], where x_k^model is the internal model's
  one-step prediction from the previous estimate; d̂ enters the horizon as an NLP parameter,
  x_{k+1} = x_k + Ts·(f(x_k, u_k, Φ) + d̂);
- the soft track constraint's margin m_k = m0 + γ·r_k, r_k the mean position prediction error of
  the last ``error_window`` steps clipped to [0, r_max], replaces the nominal margin.
"""

from __future__ import annotations

from collections import deque
from typing import Any, ClassVar

import numpy as np

from cape.controllers.base import require
from cape.controllers.ekf import ExtendedKalmanFilter, NoiseLevels
from cape.controllers.nmpc import NMPC_SCHEMA, NominalNMPC
from cape.controllers.registry import register_controller


@register_controller("rnmpc")
class RobustNMPC(NominalNMPC):
    settings_schema: ClassVar[dict[str, Any] | None] = {
        **NMPC_SCHEMA,
        "required": [*NMPC_SCHEMA["required"], "robust"],
        "properties": {
            **NMPC_SCHEMA["properties"],
            "robust": {
                "type": "object",
                "required": [
                    "m0",
                    "gamma",
                    "r_max",
                    "error_window",
                    "dhat_filter",
                    "ekf_model_std",
                ],
                "additionalProperties": False,
                "properties": {
                    **{k: {"type": "number", "minimum": 0} for k in ("m0", "gamma", "r_max")},
                    "error_window": {"type": "integer", "minimum": 1},
                    "dhat_filter": {"type": "number", "minimum": 0, "maximum": 1},
                    "ekf_model_std": {
                        "type": "array",
                        "items": {"type": "number", "minimum": 0},
                        "minItems": 6,
                        "maxItems": 6,
                    },
                },
            },
        },
    }

    needs_noise_levels = True

    def __init__(self, *args: Any, levels: NoiseLevels | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        require(self.settings, ("robust",), f"controllers.{self.name}")
        r = self.settings["robust"]
        keys = ("m0", "gamma", "r_max", "error_window", "dhat_filter", "ekf_model_std")
        require(r, keys, f"controllers.{self.name}.robust")
        self.m0, self.gamma, self.r_max = float(r["m0"]), float(r["gamma"]), float(r["r_max"])
        self.window = int(r["error_window"])
        self.beta = float(r["dhat_filter"])
        self.ekf = ExtendedKalmanFilter(
            self.internal, levels or NoiseLevels(), tuple(r["ekf_model_std"])
        )

    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        self.ekf.reset(z0)
        self.errors: deque[float] = deque(maxlen=self.window)
        self._u_before = np.zeros(2)  # the input before the last one: the NLP's x0 carried it

    def step(self, z: np.ndarray, proj: Any, ref: Any) -> tuple[np.ndarray, dict[str, Any]]:
        u_before = self.u_prev.copy()
        u, info = super().step(z, proj, ref)
        self._u_before = u_before
        info["margin"] = self.margin()
        return u, info

    def estimate(self, z: np.ndarray) -> np.ndarray:
        if self.phi_now is None:  # first step: nothing to predict from yet
            return self.ekf.x.copy()
        # the prediction is the internal model's own first step from the last estimate
        estimate = self.ekf.update(z, self._u_before, self.u_prev, self.phi_now)
        prior = self.ekf.prior
        assert prior is not None
        raw = (estimate[3:6] - prior[3:6]) / self.ts
        self.dhat = (1 - self.beta) * self.dhat + self.beta * raw
        self.errors.append(float(np.hypot(*(estimate[0:2] - prior[0:2]))))
        return estimate

    def margin(self) -> float:
        r = float(np.mean(self.errors)) if self.errors else 0.0
        return self.m0 + self.gamma * min(max(r, 0.0), self.r_max)
