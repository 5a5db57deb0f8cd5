"""The learned-model interface (SPEC §4).

A learned model maps a window Z (H × 7 rows of ``[vx, vy, ω, T_fb, δ_fb, ΔT, Δδ]``) to a
parameter vector Φ, then takes one forward-Euler step of the shared vehicle equations from the
last row. The network part (GRU → fully connected trunk → output layer) is PyTorch; the physics
part is written on the backend-neutral equations of ``cape.vehicle``, so the same code serves
training (tensors), the closed-loop plant (NumPy) and the NMPC (CasADi symbols).

Subclasses say which parameters Φ holds, which are fixed, how Φ becomes the mapping the
equations read, how the commanded input becomes the applied one, and which optional terms of
the equations they switch on.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
from torch import nn

from cape.models.layers import PhysicsGuard, trunk
from cape.vehicle.backend import ops_for
from cape.vehicle.dynamics import velocity_derivatives
from cape.vehicle.params import GROUND_TRUTH

N_FEATURES = 7


def component(phi: Any, i: int) -> Any:
    """Φ's i-th component: the last axis of an array/tensor, the i-th entry of a CasADi vector."""
    if type(phi).__module__.startswith("casadi"):
        return phi[i]
    return phi[..., i]


class LearnedModel(nn.Module):
    """Window → Φ → one Euler step of [vx, vy, ω]."""

    name: ClassVar[str] = "?"
    param_names: ClassVar[tuple[str, ...]] = ()
    """Names of Φ's components, in order."""
    fixed: ClassVar[tuple[str, ...]] = ("lf", "lr", "m")
    """Vehicle parameters not learned, taken from the known geometry and mass of the car."""
    throttle_path: ClassVar[bool] = True
    """False when the dynamics do not depend on the throttle (Frx predicted)."""

    def __init__(self, spec: dict[str, Any], ts: float) -> None:
        super().__init__()
        self.spec = spec
        self.ts = float(ts)
        self.history = int(spec["history"])
        gru, head = spec["gru"], spec["head"]
        self.gru = nn.GRU(N_FEATURES, gru["hidden"], gru["layers"], batch_first=True)
        self.trunk = trunk(
            self.history * gru["hidden"],
            head["width"],
            head["layers"],
            head["activation"],
            head.get("layer_norm_after", ()),
        )
        self.output = self.make_output(head["width"])
        self.register_buffer("feature_mean", torch.zeros(N_FEATURES, dtype=torch.float64))
        self.register_buffer("feature_scale", torch.ones(N_FEATURES, dtype=torch.float64))
        self._constants = {k: getattr(GROUND_TRUTH, k) for k in self.fixed}

    # --- network --------------------------------------------------------------------------
    def make_output(self, width: int) -> nn.Module:
        """The last layer: a physics guard over the config's bounds (override for unbounded Φ)."""
        bounds = self.spec["bounds"]
        missing = [n for n in self.param_names if n not in bounds]
        if missing:
            raise ValueError(f"model {self.name}: config lacks bounds for {missing}")
        return PhysicsGuard(
            width,
            [bounds[n][0] for n in self.param_names],
            [bounds[n][1] for n in self.param_names],
        )

    def set_scaler(self, mean: Any, scale: Any) -> None:
        """Feature standardisation fitted on the training windows (stored with the weights)."""
        self.feature_mean.copy_(torch.as_tensor(mean, dtype=torch.float64))
        self.feature_scale.copy_(torch.as_tensor(scale, dtype=torch.float64))

    def phi(self, windows: torch.Tensor) -> torch.Tensor:
        """Φ (B, P) in float64 for unscaled windows (B, H, 7), whatever the network's precision."""
        z = ((windows - self.feature_mean) / self.feature_scale).to(self.gru.weight_ih_l0.dtype)
        out, _ = self.gru(z)  # hidden state starts at zero for every window
        return self.output(self.trunk(out.reshape(out.shape[0], -1))).to(torch.float64)

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        """Next [vx, vy, ω] (B, 3) for unscaled float64 windows (B, H, 7)."""
        last = windows[:, -1, :]
        vx, vy, omega = last[:, 0], last[:, 1], last[:, 2]
        u_fb = (last[:, 3], last[:, 4])
        u_cmd = (last[:, 3] + last[:, 5], last[:, 4] + last[:, 6])
        nxt = self.step_velocities(vx, vy, omega, u_fb, u_cmd, self.phi(windows))
        return torch.stack(nxt, dim=-1)

    # --- physics (backend-neutral) ------------------------------------------------------------
    def physical_params(self, phi: Any) -> dict[str, Any]:
        """The mapping the vehicle equations read: Φ's components plus the fixed constants."""
        p = dict(self._constants)
        for i, name in enumerate(self.param_names):
            p[name] = component(phi, i)
        return p

    def applied_inputs(
        self, u_fb: tuple[Any, Any], u_cmd: tuple[Any, Any], p: dict[str, Any]
    ) -> tuple[Any, Any]:
        """The input that reaches the wheels this step (instantaneous actuators by default)."""
        return u_cmd

    def equation_terms(self, p: dict[str, Any]) -> dict[str, Any]:
        """Optional terms of the equations this model switches on (``frx``, ``cg_height``)."""
        return {}

    def step_velocities(
        self, vx: Any, vy: Any, omega: Any, u_fb: tuple[Any, Any], u_cmd: tuple[Any, Any], phi: Any
    ) -> tuple[Any, Any, Any]:
        """One forward-Euler step of [vx, vy, ω] with parameters Φ (any backend)."""
        return self.step_with_params(vx, vy, omega, u_fb, u_cmd, self.physical_params(phi))

    def step_with_params(
        self,
        vx: Any,
        vy: Any,
        omega: Any,
        u_fb: tuple[Any, Any],
        u_cmd: tuple[Any, Any],
        p: dict[str, Any],
    ) -> tuple[Any, Any, Any]:
        """The same step from the parameter mapping itself: what a plant uses when it changes the
        parameters (a mismatch) or freezes them (the fixed-parameter variants)."""
        throttle, delta = self.applied_inputs(u_fb, u_cmd, p)
        dvx, dvy, domega = velocity_derivatives(
            vx, vy, omega, throttle, delta, p, **self.equation_terms(p)
        )
        return vx + self.ts * dvx, vy + self.ts * dvy, omega + self.ts * domega

    def frozen_params(self, frozen: dict[str, float]) -> dict[str, Any]:
        """Parameters of the fixed-parameter variant (SPEC §4.5): constants + frozen Φ."""
        return {**self._constants, **frozen}

    @staticmethod
    def first_order_lag(u_fb: Any, u_cmd: Any, tau: Any, ts: float) -> Any:
        """``u_fb + min(1, Ts/τ)·(u_cmd − u_fb)``: τ ≤ Ts means no lag."""
        ops = ops_for(u_fb, u_cmd, tau)
        return u_fb + ops.minimum(1.0, ts / tau) * (u_cmd - u_fb)

    # --- bookkeeping --------------------------------------------------------------------------
    def fc_layers(self) -> int:
        """Fully connected layers, the output (or guard) layer counting as one."""
        return int(self.spec["head"]["layers"]) + 1

    def gru_layers(self) -> int:
        return int(self.spec["gru"]["layers"])

    def n_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
