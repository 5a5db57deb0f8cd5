"""The network half of a learned model (SPEC §4), in PyTorch: window → Φ.

Every model shares one network: a GRU over the standardised window (none when ``gru.layers`` is
0), a fully connected trunk, and an output layer that is a physics guard when Φ is bounded.
``LearnedModel`` holds the model's ``ModelPhysics`` (``cape.models.physics``) and answers for it
(``model.param_names``, ``model.step_velocities(...)``). Only training and the open-loop
evaluation need this class; the closed loop never imports PyTorch (docs/modules.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from cape.models.layers import ACTIVATIONS, PhysicsGuard, gru_stages, trunk
from cape.models.network import NETWORK_FORMAT, NumpyNetwork
from cape.models.physics import N_FEATURES, ModelPhysics


class LearnedModel(nn.Module):
    """Window → Φ (network) → one Euler step of [vx, vy, ω] (the model's physics)."""

    def __init__(self, physics: ModelPhysics) -> None:
        super().__init__()
        self.physics = physics
        spec = physics.spec
        gru, head = spec["gru"], spec["head"]
        self.gru = (
            nn.GRU(N_FEATURES, gru["hidden"], gru["layers"], batch_first=True)
            if gru["layers"] > 0
            else None
        )
        row = gru["hidden"] if self.gru is not None else N_FEATURES
        self.trunk = trunk(
            physics.history * row,
            head["width"],
            head["layers"],
            head["activation"],
            head.get("layer_norm_after", ()),
        )
        self.output: nn.Module = (
            PhysicsGuard(head["width"], *physics.bounds())
            if physics.bounded
            else nn.Linear(head["width"], len(physics.param_names))
        )
        self.register_buffer("feature_mean", torch.zeros(N_FEATURES, dtype=torch.float64))
        self.register_buffer("feature_scale", torch.ones(N_FEATURES, dtype=torch.float64))

    def __getattr__(self, name: str) -> Any:
        """Parameters, buffers and layers first (``nn.Module``), then the model's physics."""
        try:
            return super().__getattr__(name)
        except AttributeError:
            physics = self.__dict__.get("physics")
            if physics is None or name.startswith("__"):
                raise
            return getattr(physics, name)

    def set_scaler(self, mean: Any, scale: Any) -> None:
        """Feature standardisation fitted on the training windows (stored with the weights)."""
        self.feature_mean.copy_(torch.as_tensor(mean, dtype=torch.float64))
        self.feature_scale.copy_(torch.as_tensor(scale, dtype=torch.float64))

    def phi(self, windows: torch.Tensor, stages: bool = False) -> torch.Tensor:
        """Φ (B, P) in float64 for unscaled windows (B, H, 7), whatever the network's precision.
        ``stages``: the GRU computed stage by stage (``gru_stages``: the training step's graph,
        the same equations up to rounding) instead of by ``nn.GRU``."""
        dtype = next(self.output.parameters()).dtype
        out = ((windows - self.feature_mean) / self.feature_scale).to(dtype)
        if self.gru is not None:  # hidden state starts at zero for every window
            out = gru_stages(self.gru, out) if stages else self.gru(out)[0]
        return self.output(self.trunk(out.reshape(out.shape[0], -1))).to(torch.float64)

    def forward(self, windows: torch.Tensor, stages: bool = False) -> torch.Tensor:
        """Next [vx, vy, ω] (B, 3) for unscaled float64 windows (B, H, 7); ``stages`` as in
        ``phi``."""
        last = windows[:, -1, :]
        vx, vy, omega = last[:, 0], last[:, 1], last[:, 2]
        u_fb = (last[:, 3], last[:, 4])
        u_cmd = (last[:, 3] + last[:, 5], last[:, 4] + last[:, 6])
        phi = self.phi(windows, stages=True) if stages else self.phi(windows)
        nxt = self.physics.step_velocities(vx, vy, omega, u_fb, u_cmd, phi)
        return torch.stack(nxt, dim=-1)

    # --- export to the closed loop ------------------------------------------------------------
    def network_arrays(self) -> dict[str, np.ndarray]:
        """The network as plain arrays (the format ``NumpyNetwork`` reads): the scaler, the
        GRU's weights transposed for row-vector products, the trunk layer by layer, the guard."""

        def arr(t: torch.Tensor) -> np.ndarray:
            return t.detach().cpu().numpy()

        out: dict[str, np.ndarray] = {
            "format": np.array(NETWORK_FORMAT),
            "feature_mean": arr(self.feature_mean),
            "feature_scale": arr(self.feature_scale),
        }
        gru = self.gru
        if gru is not None:
            n = gru.num_layers
            out["gru_w_ih0"] = arr(gru.weight_ih_l0).T
            out["gru_w_ih"] = (
                np.stack([arr(getattr(gru, f"weight_ih_l{i}")).T for i in range(1, n)])
                if n > 1
                else np.zeros((0, gru.hidden_size, 3 * gru.hidden_size), np.float32)
            )
            out["gru_w_hh"] = np.stack([arr(getattr(gru, f"weight_hh_l{i}")).T for i in range(n)])
            out["gru_b_ih"] = np.stack([arr(getattr(gru, f"bias_ih_l{i}")) for i in range(n)])
            out["gru_b_hh"] = np.stack([arr(getattr(gru, f"bias_hh_l{i}")) for i in range(n)])
        kinds: list[str] = []
        activation = {cls: name for name, cls in ACTIVATIONS.items()}
        last = self.output.linear if isinstance(self.output, PhysicsGuard) else self.output
        for module in [*self.trunk, last]:
            i = len(kinds)
            if isinstance(module, nn.Linear):
                kinds.append("linear")
                out[f"layer{i}_weight"] = arr(module.weight).T
                out[f"layer{i}_bias"] = arr(module.bias)
            elif isinstance(module, nn.LayerNorm):
                kinds.append("layer_norm")
                out[f"layer{i}_weight"] = arr(module.weight)
                out[f"layer{i}_bias"] = arr(module.bias)
                out[f"layer{i}_eps"] = np.array(module.eps)
            elif type(module) in activation:
                kinds.append(activation[type(module)])
            else:
                raise TypeError(f"no NumPy export for layer {type(module).__name__}")
        out["layers"] = np.array(kinds)
        if isinstance(self.output, PhysicsGuard):
            out["guard_lower"] = arr(self.output.lower)
            out["guard_upper"] = arr(self.output.upper)
        return out

    def inference(self) -> NumpyNetwork:
        """The same network on NumPy, for one window at a time (the closed loop's path)."""
        return NumpyNetwork(self.network_arrays())

    # --- bookkeeping --------------------------------------------------------------------------
    def fc_layers(self) -> int:
        """Fully connected layers, the output (or guard) layer counting as one."""
        return int(self.physics.spec["head"]["layers"]) + 1

    def gru_layers(self) -> int:
        return int(self.physics.spec["gru"]["layers"])

    def n_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
