"""The learned models' network without PyTorch: what the closed loop runs.

The trained weights, exported to ``network.npz`` (``LearnedModel.network_arrays``), run here
compiled (``rollout.compile``, the default: one C function per trained model,
``cape.models.compiled_phi``) or uncompiled (CasADi's virtual machine and a NumPy float32 trunk,
the compiled one's fallback). Both keep to the training graph within its own float32 rounding
(tests: ≤ 1e-6 relative on the next state). Neither imports SciPy. Why, and the two paths:
docs/modules.md.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.errors import CapeError
from cape.models.compiled_phi import FRONT, compiled_phi
from cape.models.physics import N_FEATURES
from cape.models.trunk import KINDS, Layer
from cape.numerics.buffered import BufferedCall
from cape.storage.integrity import check_arrays, sealed_arrays
from cape.storage.io import save_npz

Array = np.ndarray
NETWORK_FORMAT = 1
"""Version of ``network.npz``'s layout; a file of another version is rejected with the fix."""


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


class NumpyNetwork:
    """Φ of one window from exported arrays (``LearnedModel.network_arrays``); compiled with
    ``compile_settings`` (``rollout.compile``) enabled and a compiler at hand, else uncompiled.
    """

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
        self.layers: list[Layer] = []
        for i, kind in enumerate(str(k) for k in arrays["layers"]):
            if kind == "linear":
                self.layers.append(Layer(kind, f32(f"layer{i}_weight"), f32(f"layer{i}_bias")))
            elif kind == "layer_norm":
                eps = float(arrays[f"layer{i}_eps"])
                self.layers.append(Layer(kind, f32(f"layer{i}_weight"), f32(f"layer{i}_bias"), eps))
            elif kind in KINDS:
                self.layers.append(Layer(kind))
            else:
                raise ValueError(f"layer {i}: unknown kind {kind!r}")
        linear = [layer for layer in self.layers if layer.kind == "linear"]
        hidden = self.gru[2].shape[1] if self.gru is not None else self.mean.size
        assert linear[0].weight is not None and linear[-1].bias is not None
        self.history = int(linear[0].weight.shape[0]) // hidden
        """Rows of the window the trunk was built for."""
        self.n_outputs = int(linear[-1].bias.shape[0])
        """Components of Φ."""
        self.guard: tuple[Array, Array] | None = None
        if "guard_lower" in arrays:
            self.guard = (f64("guard_lower"), f64("guard_upper"))
        self._phi: Callable[[Array], Array] | None = None
        self.library: Path | None = None
        """The compiled library Φ runs in; None: uncompiled (known after the first prediction)."""

    def front_function(self, name: str = FRONT) -> ca.Function:
        """The scaling and the GRU stack on one window (7 × H, column t = row t of the window)
        as a CasADi function ``name``: the trunk's input, the GRU's outputs row after row (or,
        without a GRU, the scaled window's rows)."""
        x = ca.SX.sym("window", N_FEATURES, self.history)
        scaled = (x - ca.repmat(ca.DM(self.mean), 1, self.history)) / ca.repmat(
            ca.DM(self.scale), 1, self.history
        )
        out = ca.vec(gru_stack(scaled.T, *self.gru).T) if self.gru is not None else ca.vec(scaled)
        return ca.Function(name, [x], [out])

    def phi(self, window: Array) -> Array:
        """Φ (P,) in float64 for one unscaled window (H, 7)."""
        if self._phi is None:  # built on first use: a network loaded but never asked costs nothing
            self._phi = self._build()
        return self._phi(window)

    def _build(self) -> Callable[[Array], Array]:
        settings = self.compile_settings
        if settings and settings.get("enabled", False):
            # what the generated code depends on besides the trunk: this module's source (the
            # front's construction), the window length, the scaler, the GRU's weights
            source = np.frombuffer(Path(__file__).read_bytes(), np.uint8)
            parts = [source, np.array(self.history), self.mean, self.scale, *(self.gru or ())]
            compiled = compiled_phi(
                self.front_function, self.layers, self.guard, parts, dict(settings)
            )
            if compiled is not None:
                function, self.library = compiled
                call = BufferedCall(function)
                return lambda window: call(window.reshape(-1))[0].copy()
        return self.uncompiled_phi()

    def uncompiled_phi(self, front: ca.Function | None = None) -> Callable[[Array], Array]:
        """Φ of a window through the NumPy trunk, after ``front`` (default: the scaling and the
        GRU in CasADi's virtual machine; ``benchmarks/model_inference.py`` passes them compiled
        alone, the previous default)."""
        call = BufferedCall(front if front is not None else self.front_function())
        trunk = [_numpy_layer(layer) for layer in self.layers]
        guard = self.guard

        def phi(window: Array) -> Array:
            y = call(window.reshape(-1))[0].astype(np.float32)
            for layer in trunk:
                y = layer(y)
            y = y.astype(np.float64)
            if guard is not None:
                lower, upper = guard
                y = np.clip(lower + _sigmoid(y) * (upper - lower), lower, upper)
            return y

        return phi


def _numpy_layer(layer: Layer) -> Callable[[Array], Array]:
    """The uncompiled trunk's layer: float32 NumPy, as the training graph computes it."""
    weight, bias = layer.weight, layer.bias
    if layer.kind == "linear":
        assert weight is not None and bias is not None
        return lambda x: x @ weight + bias
    if layer.kind == "layer_norm":
        assert weight is not None and bias is not None
        eps = layer.eps

        def layer_norm(x: Array) -> Array:
            centred = x - x.mean()
            return centred / np.sqrt((centred * centred).mean() + eps) * weight + bias

        return layer_norm
    if layer.kind == "gelu":
        return _gelu
    return ACTIVATIONS[layer.kind]


def _sigmoid(x: Array) -> Array:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def _mish(x: Array) -> Array:
    return x * np.tanh(np.logaddexp(0.0, x))


_ERF: dict[int, BufferedCall] = {}


def _gelu(x: Array) -> Array:
    """Exact GELU, PyTorch's default: 0.5·x·(1 + erf(x/√2)), erf from CasADi (SciPy's
    ``scipy.special`` costs half a second to import in every rollout process)."""
    erf = _ERF.get(x.size)
    if erf is None:
        s = ca.MX.sym("x", x.size)
        erf = _ERF[x.size] = BufferedCall(ca.Function("erf", [s], [ca.erf(s)]))
    e = erf(x * np.float32(1.0 / np.sqrt(2.0)))[0].astype(np.float32)
    return np.float32(0.5) * x * (np.float32(1.0) + e)


ACTIVATIONS: dict[str, Callable[[Array], Array]] = {
    "mish": _mish,
    "gelu": _gelu,
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
}


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
