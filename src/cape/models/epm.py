"""Enhanced Physics Model (the paper's proposal), SPEC §4.3.

The Deep Dynamics physics plus dynamic load transfer with load-sensitive tyre forces (centre
of gravity height h) and first-order actuator lags (τ_δ, τ_T). With h = 0 and τ ≤ Ts it equals
the Deep Dynamics Model exactly.
"""

from __future__ import annotations

from typing import Any

from cape.models.ddm import DDM_PARAMS
from cape.models.physics import ModelPhysics
from cape.models.registry import register_model


@register_model("epm")
class EnhancedPhysics(ModelPhysics):
    param_names = (*DDM_PARAMS, "h", "tau_delta", "tau_T")

    def applied_inputs(
        self, u_fb: tuple[Any, Any], u_cmd: tuple[Any, Any], p: dict[str, Any]
    ) -> tuple[Any, Any]:
        throttle = self.first_order_lag(u_fb[0], u_cmd[0], p["tau_T"], self.ts)
        delta = self.first_order_lag(u_fb[1], u_cmd[1], p["tau_delta"], self.ts)
        return throttle, delta

    def equation_terms(self, p: dict[str, Any]) -> dict[str, Any]:
        return {"cg_height": p["h"]}
