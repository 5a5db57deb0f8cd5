"""A fast single-window inference path for the closed loop.

The closed loop asks for Φ of one window thousands of times. At batch size one PyTorch's
per-operation overhead dominates (its GRU runs 49–80 tiny cells of about 20 operations each:
milliseconds per window here), and so would NumPy's. So the GRU stack, all cells of all
layers, is one compiled loop (Numba, cached on disk after the first compilation) in float64,
and the fully connected trunk is a handful of NumPy matrix–vector products in float32, like
the training graph (the trunk's weights, up to 11 MB, are read once per call, so their width
sets its speed). A test holds the result to the training graph (≤ 1e-6 relative).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from scipy.special import erf
from torch import nn

from cape.models.base import LearnedModel
from cape.models.layers import PhysicsGuard

Array = np.ndarray


def _sigmoid(x: Array) -> Array:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def _mish(x: Array) -> Array:
    return x * np.tanh(np.logaddexp(0.0, x))


def _gelu(x: Array) -> Array:
    return 0.5 * x * (1.0 + erf(x * np.float32(1.0 / np.sqrt(2.0))))


_ACTIVATIONS: dict[type[nn.Module], Callable[[Array], Array]] = {
    nn.Mish: _mish,
    nn.GELU: _gelu,
    nn.ReLU: lambda x: np.maximum(x, 0.0),
    nn.Tanh: np.tanh,
}


@numba.njit(cache=True)
def gru_stack(
    x: Array, w_ih0: Array, w_ih: Array, w_hh: Array, b_ih: Array, b_hh: Array
) -> Array:  # pragma: no cover - compiled; tested through FastPredictor
    """PyTorch's multi-layer GRU (zero initial state) on one sequence ``x`` (T, in).

    ``w_ih0`` (in, 3h) is layer 0's input weight, transposed; ``w_ih`` (L−1, h, 3h) the other
    layers'; ``w_hh`` (L, h, 3h); biases (L, 3h). Gate order r, z, n as in PyTorch:
    r = σ(Wir·x + bir + Whr·h + bhr), z likewise, n = tanh(Win·x + bin + r·(Whn·h + bhn)),
    h' = (1 − z)·n + z·h. Returns the last layer's outputs (T, h).
    """
    steps = x.shape[0]
    layers, hidden = w_hh.shape[0], w_hh.shape[1]
    inp = x
    gates = np.empty((steps, 3 * hidden))
    gh = np.empty(3 * hidden)
    for layer in range(layers):
        w = w_ih0 if layer == 0 else w_ih[layer - 1]
        n_in = w.shape[0]
        for t in range(steps):
            for j in range(3 * hidden):
                acc = b_ih[layer, j]
                for k in range(n_in):
                    acc += inp[t, k] * w[k, j]
                gates[t, j] = acc
        out = np.empty((steps, hidden))
        h = np.zeros(hidden)
        for t in range(steps):
            for j in range(3 * hidden):
                acc = b_hh[layer, j]
                for k in range(hidden):
                    acc += h[k] * w_hh[layer, k, j]
                gh[j] = acc
            for j in range(hidden):
                r = 1.0 / (1.0 + np.exp(-(gates[t, j] + gh[j])))
                z = 1.0 / (1.0 + np.exp(-(gates[t, hidden + j] + gh[hidden + j])))
                n = np.tanh(gates[t, 2 * hidden + j] + r * gh[2 * hidden + j])
                out[t, j] = (1.0 - z) * n + z * h[j]
            h = out[t].copy()
        inp = out
    return inp


class FastPredictor:
    """Φ and the next velocities of one window, from a trained ``LearnedModel``."""

    def __init__(self, model: LearnedModel) -> None:
        self.model = model
        self.history = model.history
        self.mean = model.feature_mean.detach().numpy().astype(np.float64)
        self.scale = model.feature_scale.detach().numpy().astype(np.float64)
        as_np = lambda t: t.detach().numpy().astype(np.float64)  # noqa: E731
        gru = model.gru
        weight = lambda name: as_np(getattr(gru, name))  # noqa: E731
        n_layers = gru.num_layers
        self.w_ih0 = np.ascontiguousarray(weight("weight_ih_l0").T)
        rest = [weight(f"weight_ih_l{i}").T for i in range(1, n_layers)]
        self.w_ih = (
            np.ascontiguousarray(np.stack(rest))
            if rest
            else np.zeros((0, gru.hidden_size, 3 * gru.hidden_size))
        )
        self.w_hh = np.ascontiguousarray(
            np.stack([weight(f"weight_hh_l{i}").T for i in range(n_layers)])
        )
        self.b_ih = np.stack([weight(f"bias_ih_l{i}") for i in range(n_layers)])
        self.b_hh = np.stack([weight(f"bias_hh_l{i}") for i in range(n_layers)])
        self.layers: list[Callable[[Array], Array]] = []
        as_f32 = lambda t: t.detach().numpy().astype(np.float32)  # noqa: E731
        for module in model.trunk:
            self.layers.append(self._convert(module, as_f32))
        out = model.output
        self.guard: tuple[Array, Array] | None = None
        if isinstance(out, PhysicsGuard):
            self.layers.append(self._convert(out.linear, as_f32))
            self.guard = (out.lower.numpy().copy(), out.upper.numpy().copy())
        else:
            self.layers.append(self._convert(out, as_f32))

    @staticmethod
    def _convert(module: nn.Module, as_np: Callable[[Any], Array]) -> Callable[[Array], Array]:
        if isinstance(module, nn.Linear):
            weight, bias = np.ascontiguousarray(as_np(module.weight).T), as_np(module.bias)
            return lambda x: x @ weight + bias
        if isinstance(module, nn.LayerNorm):
            w, b, eps = as_np(module.weight), as_np(module.bias), module.eps

            def layer_norm(x: Array) -> Array:
                centred = x - x.mean()
                return centred / np.sqrt((centred * centred).mean() + eps) * w + b

            return layer_norm
        for kind, fn in _ACTIVATIONS.items():
            if isinstance(module, kind):
                return fn
        raise TypeError(f"no fast path for layer {type(module).__name__}")

    def phi(self, window: Array) -> Array:
        """Φ (P,) in float64 for one unscaled window (H, 7)."""
        x = (window - self.mean) / self.scale
        x = gru_stack(x, self.w_ih0, self.w_ih, self.w_hh, self.b_ih, self.b_hh)
        y = x.reshape(-1).astype(np.float32)
        for layer in self.layers:
            y = layer(y)
        y = y.astype(np.float64)
        if self.guard is not None:
            lower, upper = self.guard
            y = np.clip(lower + _sigmoid(y) * (upper - lower), lower, upper)
        return y

    def predict(self, window: Array) -> Array:
        """Next [vx, vy, ω] (3,) for one unscaled window (H, 7)."""
        last = window[-1]
        nxt = self.model.step_velocities(
            last[0],
            last[1],
            last[2],
            (last[3], last[4]),
            (last[3] + last[5], last[4] + last[6]),
            self.phi(window),
        )
        return np.array(nxt, dtype=np.float64)
