"""Building blocks of the networks: the fully connected trunk and the physics guard."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

ACTIVATIONS = {"mish": nn.Mish, "gelu": nn.GELU, "relu": nn.ReLU, "tanh": nn.Tanh}


def trunk(
    in_features: int, width: int, layers: int, activation: str, layer_norm_after: Sequence[int] = ()
) -> nn.Sequential:
    """``layers`` × [Linear(width) + activation], a LayerNorm after the listed (1-based) ones."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; choose one of {sorted(ACTIVATIONS)}")
    blocks: list[nn.Module] = []
    size = in_features
    for i in range(1, layers + 1):
        blocks += [nn.Linear(size, width), ACTIVATIONS[activation]()]
        if i in layer_norm_after:
            blocks.append(nn.LayerNorm(width))
        size = width
    return nn.Sequential(*blocks)


class PhysicsGuard(nn.Module):
    """Linear → sigmoid → ``min + σ·(max − min)``: every output inside its physical bounds."""

    def __init__(self, in_features: int, lower: Sequence[float], upper: Sequence[float]) -> None:
        super().__init__()
        self.linear = nn.Linear(in_features, len(lower))
        self.register_buffer("lower", torch.tensor(lower, dtype=torch.float64))
        self.register_buffer("upper", torch.tensor(upper, dtype=torch.float64))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        sigma = torch.sigmoid(self.linear(x)).to(torch.float64)
        # the clamp only absorbs the last-ulp rounding of lower + 1·(upper − lower)
        return torch.clamp(self.lower + sigma * (self.upper - self.lower), self.lower, self.upper)
