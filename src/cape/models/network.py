"""The learned models' network on NumPy: what the closed loop runs, without PyTorch.

The closed loop asks for Φ of one window thousands of times per run, and a rollout job is a
process of its own, so two costs matter: the per-window time and the start-up. At batch size
one PyTorch's per-operation overhead dominates (its GRU runs 49–80 tiny cells of about 20
operations each: milliseconds per window), and importing it costs seconds per job. So the
trained weights are exported once to ``network.npz`` (``LearnedModel.network_arrays``) and run
here: the GRU stack, all cells of all layers, as one CasADi function (compiled C, cached after
the first compilation) in float64, and the fully connected trunk as a handful of NumPy
matrix–vector products in float32, like the training graph (the trunk's weights, up to 11 MB,
are read once per call, so their width sets its speed). A test holds the result to the
training graph (≤ 1e-6 relative).
"""

from __future__ import annotations

import hashlib
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.buffered import BufferedCall
from cape.compiled import cached_functions, compiled_functions
from cape.errors import CapeError
from cape.integrity import check_arrays, sealed_arrays
from cape.io import save_npz

Array = np.ndarray
NETWORK_FORMAT = 1
"""Version of ``network.npz``'s layout; a file of another version is rejected with the fix."""


def _sigmoid(x: Array) -> Array:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def _mish(x: Array) -> Array:
    return x * np.tanh(np.logaddexp(0.0, x))


def _gelu(x: Array) -> Array:
    from scipy.special import erf  # only GELU needs it; scipy.special is slow to import

    return 0.5 * x * (1.0 + erf(x * np.float32(1.0 / np.sqrt(2.0))))


ACTIVATIONS: dict[str, Callable[[Array], Array]] = {
    "mish": _mish,
    "gelu": _gelu,
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
}


def gru_stack(x: ca.SX, w_ih0: Array, w_ih: Array, w_hh: Array, b_ih: Array, b_hh: Array) -> ca.SX:
    """PyTorch's multi-layer GRU (zero initial state) on one sequence ``x`` (T × in, CasADi),
    the trained weights as constants: the last layer's outputs (T × h).

    ``w_ih0`` (in, 3h) is layer 0's input weight, transposed; ``w_ih`` (L−1, h, 3h) the other
    layers'; ``w_hh`` (L, h, 3h); biases (L, 3h). Gate order r, z, n as in PyTorch:
    r = σ(Wir·x + bir + Whr·h + bhr), z likewise, n = tanh(Win·x + bin + r·(Whn·h + bhn)),
    h' = (1 − z)·n + z·h.
    """
    layers, hidden = w_hh.shape[0], w_hh.shape[1]
    inp = x
    for layer in range(layers):
        w = ca.DM(w_ih0 if layer == 0 else w_ih[layer - 1])
        gates = ca.mtimes(inp, w) + ca.repmat(ca.DM(b_ih[layer]).T, inp.shape[0], 1)
        h = ca.SX.zeros(1, hidden)
        rows = []
        for t in range(inp.shape[0]):
            g = gates[t, :]
            gh = ca.mtimes(h, ca.DM(w_hh[layer])) + ca.DM(b_hh[layer]).T
            r = 1.0 / (1.0 + ca.exp(-(g[:hidden] + gh[:hidden])))
            z = 1.0 / (1.0 + ca.exp(-(g[hidden : 2 * hidden] + gh[hidden : 2 * hidden])))
            n = ca.tanh(g[2 * hidden :] + r * gh[2 * hidden :])
            h = (1.0 - z) * n + z * h
            rows.append(h)
        inp = ca.vertcat(*rows)
    return inp


def gru_function(
    history: int, gru: tuple[Array, ...], compile_settings: Mapping[str, Any] | None = None
) -> BufferedCall:
    """The GRU stack on one window (the scaled window, row after row) as a CasADi function,
    called through its buffer. With ``compile_settings`` it runs as compiled C, cached under a
    digest of the weights (``cape export-network`` builds it once per trained model): tens of
    microseconds a window, and no Numba to import and dispatch (a second in every rollout
    process). Without, in CasADi's virtual machine."""
    n_in = gru[0].shape[0]
    fingerprint = hashlib.sha256(repr((history, n_in)).encode())
    for array in gru:
        fingerprint.update(np.ascontiguousarray(array).tobytes())
    if compile_settings and compile_settings.get("enabled", False):
        cached = cached_functions({"gru": "gru"}, fingerprint.hexdigest(), dict(compile_settings))
        if cached is not None:
            return BufferedCall(cached[0]["gru"])
    x = ca.SX.sym("x", n_in, history)  # column t is row t of the window
    out = gru_stack(x.T, *gru)
    function = ca.Function("gru", [x], [ca.vec(out.T)])
    if compile_settings and compile_settings.get("enabled", False):
        compiled, _ = compiled_functions(
            "gru", {"gru": function}, dict(compile_settings), fingerprint.hexdigest()
        )
        function = compiled["gru"]
    return BufferedCall(function)


class NumpyNetwork:
    """Φ of one window from exported arrays (``LearnedModel.network_arrays``)."""

    def __init__(
        self, arrays: Mapping[str, Array], compile_settings: Mapping[str, Any] | None = None
    ) -> None:
        self.compile_settings = compile_settings
        f64 = lambda name: np.ascontiguousarray(arrays[name], dtype=np.float64)  # noqa: E731
        f32 = lambda name: np.ascontiguousarray(arrays[name], dtype=np.float32)  # noqa: E731
        self.mean, self.scale = f64("feature_mean"), f64("feature_scale")
        self.gru: tuple[Array, ...] | None = None  # no GRU: the trunk reads the window's rows
        if "gru_w_hh" in arrays:
            self.gru = tuple(f64(f"gru_{k}") for k in ("w_ih0", "w_ih", "w_hh", "b_ih", "b_hh"))
        self._gru: BufferedCall | None = None
        self.layers: list[Callable[[Array], Array]] = []
        linear = [i for i, k in enumerate(arrays["layers"]) if str(k) == "linear"]
        hidden = self.gru[2].shape[1] if self.gru is not None else self.mean.size
        self.history = int(arrays[f"layer{linear[0]}_weight"].shape[0]) // hidden
        """Rows of the window the trunk was built for."""
        self.n_outputs = int(arrays[f"layer{linear[-1]}_bias"].shape[0])
        """Components of Φ."""
        for i, kind in enumerate(str(k) for k in arrays["layers"]):
            if kind == "linear":
                self.layers.append(_linear(f32(f"layer{i}_weight"), f32(f"layer{i}_bias")))
            elif kind == "layer_norm":
                eps = float(arrays[f"layer{i}_eps"])
                self.layers.append(_layer_norm(f32(f"layer{i}_weight"), f32(f"layer{i}_bias"), eps))
            elif kind in ACTIVATIONS:
                self.layers.append(ACTIVATIONS[kind])
            else:
                raise ValueError(f"layer {i}: unknown kind {kind!r}")
        self.guard: tuple[Array, Array] | None = None
        if "guard_lower" in arrays:
            self.guard = (f64("guard_lower"), f64("guard_upper"))

    def phi(self, window: Array) -> Array:
        """Φ (P,) in float64 for one unscaled window (H, 7)."""
        x = (window - self.mean) / self.scale
        if self.gru is not None:
            if self._gru is None:  # built on first use, for this window length
                self._gru = gru_function(x.shape[0], self.gru, self.compile_settings)
            x = self._gru(x.reshape(-1))[0]
        y = x.reshape(-1).astype(np.float32)
        for layer in self.layers:
            y = layer(y)
        y = y.astype(np.float64)
        if self.guard is not None:
            lower, upper = self.guard
            y = np.clip(lower + _sigmoid(y) * (upper - lower), lower, upper)
        return y


def _linear(weight: Array, bias: Array) -> Callable[[Array], Array]:
    return lambda x: x @ weight + bias


def _layer_norm(weight: Array, bias: Array, eps: float) -> Callable[[Array], Array]:
    def layer_norm(x: Array) -> Array:
        centred = x - x.mean()
        return centred / np.sqrt((centred * centred).mean() + eps) * weight + bias

    return layer_norm


def save_network(path: str | Path, arrays: Mapping[str, Array]) -> None:
    """Write the exported network atomically, with the checksum its readers verify."""
    save_npz(path, **sealed_arrays(arrays))


def load_network(
    path: str | Path,
    compile_settings: Mapping[str, Any] | None = None,
    weights_sha256: str | None = None,
) -> NumpyNetwork:
    """The network in ``path``, or a ``CapeError`` naming the file and the fix.
    ``weights_sha256``: the digest of the ``model.pt`` it must have been exported from (its
    ``meta.json`` records it), so that a network left from earlier weights is refused."""
    path = Path(path)
    fix = f"rebuild it with `snakemake --cores 1 {path}`"
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise CapeError(f"{path}: missing; {fix}") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise CapeError(f"{path}: not a readable network ({exc}); delete it and {fix}") from exc
    check_arrays(arrays, path, fix)
    version = int(arrays["format"]) if "format" in arrays else None
    if version != NETWORK_FORMAT:
        raise CapeError(f"{path}: network format {version}, expected {NETWORK_FORMAT}; {fix}")
    if weights_sha256 is not None:
        exported = str(arrays["weights_sha256"]) if "weights_sha256" in arrays else None
        if exported != weights_sha256:
            raise CapeError(
                f"{path}: exported from other weights than the model.pt beside it (its "
                f"meta.json records {weights_sha256[:12]}…, the network "
                f"{(exported or 'none')[:12]}…): it is stale; rebuild it with `cape "
                f"export-network --model NAME={path.parent}` or `snakemake --cores 1 {path}`"
            )
    try:
        return NumpyNetwork(arrays, compile_settings)
    except (KeyError, ValueError, IndexError) as exc:
        raise CapeError(f"{path}: incomplete network ({exc}); delete it and {fix}") from exc
