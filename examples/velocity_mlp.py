"""Example model: a plain MLP that predicts the accelerations, with no vehicle physics.

One module plus one config entry (examples/extension.yaml) put it through the whole study:
training, the open-loop tables, the rollouts and the figures. Its "physics" is the identity
on the network's output: Φ = [v̇x, v̇y, ω̇] for the next step, so the next velocities are
v + Ts·Φ. With ``gru.layers: 0`` in its config the network is a plain MLP over the
standardised window.

The model cannot tell a controller how an input changes the motion (Φ is held over an NMPC's
horizon, and nothing in the step reads the input), so it is meant for the feedback
controllers (PID, RISE, pure pursuit) as a black-box plant; docs/extending.md says more.
"""

from __future__ import annotations

from typing import Any

from cape.models import register_model
from cape.models.physics import ModelPhysics


@register_model("mlp")
class VelocityMLP(ModelPhysics):
    param_names = ("ax", "ay", "alpha")  # v̇x (m/s²), v̇y (m/s²), ω̇ (rad/s²)
    fixed = ()
    throttle_path = False
    bounded = False

    def step_with_params(
        self,
        vx: Any,
        vy: Any,
        omega: Any,
        u_fb: tuple[Any, Any],
        u_cmd: tuple[Any, Any],
        p: dict[str, Any],
    ) -> tuple[Any, Any, Any]:
        return vx + self.ts * p["ax"], vy + self.ts * p["ay"], omega + self.ts * p["alpha"]
