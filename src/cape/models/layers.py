"""Building blocks of the networks: the fully connected trunk, the physics guard, and the GRU
stack written stage by stage for the compiled training step."""

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


def gru_stages(gru: nn.GRU, x: torch.Tensor) -> torch.Tensor:
    """``gru(x)[0]`` (zero initial state, ``batch_first``, one direction) computed along the
    anti-diagonals of the layer × time grid, for the compiled training step.

    Why: cell (l, t) needs only (l, t−1) and (l−1, t), so all cells with l + t = s are
    independent and go in one batched product. The compiled graph then has L + T − 1 stages
    instead of L·T cells (EPM 13 instead of 49, DPM 17 instead of 80): fewer kernels to compile
    and to launch, and one small batched GEMM per stage instead of one per cell. The equations
    are PyTorch's (gate order r, z, n; ``n = tanh(W_in·x + b_in + r·(W_hn·h + b_hn))``); only
    the summation order of the products differs, so the result agrees with ``nn.GRU`` to
    rounding (tests/test_training.py). The evaluation and the exported network use ``nn.GRU``
    itself.
    """
    if gru.bidirectional or not gru.batch_first or gru.proj_size or not gru.bias:
        raise ValueError("gru_stages: only a batch-first, one-way GRU with biases")
    layers, hidden = gru.num_layers, gru.hidden_size
    batch, steps = x.shape[0], x.shape[1]
    w_ih = [getattr(gru, f"weight_ih_l{i}") for i in range(layers)]
    b_ih = [getattr(gru, f"bias_ih_l{i}") for i in range(layers)]
    w_hh = torch.stack([getattr(gru, f"weight_hh_l{i}") for i in range(layers)]).transpose(1, 2)
    b_hh = torch.stack([getattr(gru, f"bias_hh_l{i}") for i in range(layers)]).unsqueeze(1)
    inputs0 = nn.functional.linear(x, w_ih[0], b_ih[0])  # layer 0: every step at once
    if layers > 1:
        w_up = torch.stack(w_ih[1:]).transpose(1, 2)  # (L−1, H, 3H): layer l reads layer l−1
        b_up = torch.stack(b_ih[1:]).unsqueeze(1)
    previous: torch.Tensor | None = None  # hidden states of the layers active at stage s − 1
    first_previous = 0  # the lowest of those layers
    outputs = []
    for stage in range(layers + steps - 1):
        first, last = max(0, stage - steps + 1), min(layers - 1, stage)  # layer l at t = s − l
        states = [] if previous is None else [previous[first - first_previous :]]
        if last == stage:  # layer `last` starts (t = 0): its state is zero
            states.append(x.new_zeros(1, batch, hidden))
        state = torch.cat(states) if len(states) > 1 else states[0]
        from_state = torch.bmm(state, w_hh[first : last + 1]) + b_hh[first : last + 1]
        gates = [inputs0[:, stage].unsqueeze(0)] if first == 0 else []
        lowest_fed = max(first, 1)  # layers ≥ 1 read the layer below at the same step
        if previous is not None and lowest_fed <= last:
            below = previous[lowest_fed - 1 - first_previous : last - first_previous]
            up = slice(lowest_fed - 1, last)
            gates.append(torch.bmm(below, w_up[up]) + b_up[up])
        from_input = torch.cat(gates) if len(gates) > 1 else gates[0]
        i_r, i_z, i_n = from_input.chunk(3, dim=-1)
        h_r, h_z, h_n = from_state.chunk(3, dim=-1)
        reset, update = torch.sigmoid(i_r + h_r), torch.sigmoid(i_z + h_z)
        candidate = torch.tanh(i_n + reset * h_n)
        previous = (1 - update) * candidate + update * state
        first_previous = first
        if last == layers - 1:
            outputs.append(previous[-1])
    return torch.stack(outputs, dim=1)
