"""Φ of one window as one compiled function: the scaled window, the GRU stack, the trunk and
the physics guard in a single call of C code, cached per trained model (``rollout.compile``).

The scaling and the GRU are CasADi's code of ``NumpyNetwork.front_function``; the trunk (in
float32, as the training graph computes it) and the guard (in float64) are C written here. The
generated code depends on this module's source, which is part of the cache key. The library in
detail: docs/modules.md.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.models.trunk import Layer
from cape.numerics.compiled import cached_library, generated

LANES = 8
"""float32 lanes of one vector: rows of the weights are padded with zeros to a multiple."""
FRONT = "phi_front"
"""The name of CasADi's function (window → the trunk's input); in a library, followed by the
library's key: ``phi`` calls it by its exported name, which must not resolve to the function of
another network's library loaded into the same process."""
PHI = "phi"
"""The name of the whole prediction in the library (window → Φ)."""


def compiled_phi(
    front: Callable[[str], ca.Function],
    layers: Sequence[Layer],
    guard: tuple[np.ndarray, np.ndarray] | None,
    parts: Sequence[np.ndarray],
    compile_settings: dict[str, Any],
) -> tuple[ca.Function, Path] | None:
    """The whole prediction (window, 7 × H with column t = row t, → Φ) from the cached library,
    compiled when missing, and that library; None without a compiler. ``front(name)`` builds the
    SX function of the scaling and the GRU, called only when the library must be compiled
    (building it takes seconds); ``parts``: what it is built from (arrays, the source of the
    code that builds it), for the cache key with this module's source and the trunk."""
    digest = hashlib.sha256(Path(__file__).read_bytes())
    for array in parts:
        digest.update(repr((array.dtype.str, array.shape)).encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    for layer in layers:
        digest.update(layer.kind.encode())
        for array in (layer.weight, layer.bias):
            if array is not None:
                digest.update(repr(array.shape).encode() + array.tobytes())
        digest.update(repr(layer.eps).encode())
    for array in guard or ():
        digest.update(array.tobytes())

    key = digest.hexdigest()

    def generate(directory: Path) -> Path:
        function = front(f"{FRONT}_{key[:16]}")
        gen = ca.CodeGenerator("phi.c", {"with_header": False})
        gen.add(function)
        source = generated(gen, "phi.c", directory)
        with source.open("a") as out:
            out.write(trunk_code(function, layers, guard))
        return source

    library = cached_library(
        key,
        compile_settings,
        generate,
        prefix="phi",
        what="the learned models' Φ",
        setting="`rollout.compile.enabled: false`",
    )
    return None if library is None else (ca.external(PHI, str(library)), library)


def trunk_code(
    front: ca.Function, layers: Sequence[Layer], guard: tuple[np.ndarray, np.ndarray] | None
) -> str:
    """The C code that follows CasADi's code of ``front``: the trunk's weights, its layers, the
    guard, and ``phi``, the whole prediction, with the interface of a CasADi external function
    (``ca.external`` loads it)."""
    blob = _Blob()
    steps: list[str] = []
    width = int(front.nnz_out(0))
    widths = [_padded(width)]
    current, other = "a", "b"
    for layer in layers:
        if layer.kind == "linear":
            assert layer.weight is not None and layer.bias is not None
            n_in, n_out = layer.weight.shape
            if n_in != width:
                raise ValueError(f"a linear layer of {n_in} inputs after {width} features")
            rows = np.zeros((n_out, _padded(n_in)), np.float32)
            rows[:, :n_in] = layer.weight.T
            w, b = blob.add(rows), blob.add(layer.bias)
            steps.append(
                f"cape_dense(cape_data.f + {w}, cape_data.f + {b}, {current}, {other}, "
                f"{n_out}, {_padded(n_in)});"
            )
            if _padded(n_out) > n_out:  # the next product reads the padding: zeros
                steps.append(f"for (i = {n_out}; i < {_padded(n_out)}; ++i) {other}[i] = 0.0f;")
            current, other = other, current
            width = n_out
            widths.append(_padded(n_out))
        elif layer.kind == "layer_norm":
            assert layer.weight is not None and layer.bias is not None
            w, b = blob.add(layer.weight), blob.add(layer.bias)
            steps.append(
                f"cape_layer_norm({current}, cape_data.f + {w}, cape_data.f + {b}, "
                f"{_c_float(layer.eps)}, {width});"
            )
        elif layer.kind in ACTIVATIONS:
            steps.append(f"for (i = 0; i < {width}; ++i) {ACTIVATIONS[layer.kind](current)};")
        else:
            raise ValueError(f"no C code for layer kind {layer.kind!r}")
    n_phi = width
    if guard is not None:
        lower, upper = (np.asarray(g, np.float64) for g in guard)
        if lower.shape != (n_phi,) or upper.shape != (n_phi,):
            raise ValueError(f"guard bounds of shape {lower.shape} for {n_phi} outputs")
        bounds = (
            f"static const double cape_lower[{n_phi}] = {{{', '.join(map(float.hex, lower))}}};\n"
            f"static const double cape_upper[{n_phi}] = {{{', '.join(map(float.hex, upper))}}};\n"
        )
        output = GUARD.format(y=current)
    else:
        bounds = ""
        output = f"for (i = 0; i < {n_phi}; ++i) phi[i] = (double) {current}[i];"
    return TEMPLATE.format(
        data=blob.literal(),
        n_floats=blob.size or LANES,
        n_bytes=4 * (blob.size or LANES),
        bounds=bounds,
        buffer=max(widths),
        n_features=int(front.nnz_out(0)),
        features_padded=_padded(int(front.nnz_out(0))),
        steps="\n  ".join(steps),
        output=output,
        front=front.name(),
        phi=PHI,
        n_window=int(front.nnz_in(0)),
        rows=int(front.size1_in(0)),
        cols=int(front.size2_in(0)),
        n_phi=n_phi,
    )


ACTIVATIONS: dict[str, Callable[[str], str]] = {
    # in float32, as PyTorch computes them: GELU exact (erf); Mish x·tanh(softplus(x)) written
    # with one exp, tanh(log(1 + t)) = n / (n + 2) for n = t·(t + 2), t = eˣ (one libm call
    # instead of three), and x itself past 20, where tanh(softplus(x)) rounds to 1
    # (and n would overflow); ReLU keeps a NaN, like torch.relu
    "gelu": lambda y: f"{y}[i] = 0.5f * {y}[i] * (1.0f + erff({y}[i] * 0.70710678118654752f))",
    "mish": lambda y: f"{y}[i] = cape_mish({y}[i])",
    "relu": lambda y: f"{y}[i] = {y}[i] < 0.0f ? 0.0f : {y}[i]",
    "tanh": lambda y: f"{y}[i] = tanhf({y}[i])",
}

GUARD = """for (i = 0; i < N_PHI; ++i) {{
    /* min + σ·(max − min) in float64, kept inside the bounds; a NaN stays a NaN */
    double s = 0.5 * (1.0 + tanh(0.5 * (double) {y}[i]));
    double v = cape_lower[i] + s * (cape_upper[i] - cape_lower[i]);
    phi[i] = v < cape_lower[i] ? cape_lower[i] : (v > cape_upper[i] ? cape_upper[i] : v);
  }}"""

TEMPLATE = """
/* ---- CAPE: the trunk and the guard (cape.models.compiled_phi) ---------------------------- */
#include <string.h>
#define N_PHI {n_phi}

typedef float cape_v8f __attribute__((vector_size(32)));
#if defined(__x86_64__) && defined(__linux__) && defined(__GNUC__) && !defined(__clang__) \\
    && __GNUC__ >= 11
/* an AVX2 + FMA build of the product beside the baseline one, chosen when the library loads */
#define CAPE_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define CAPE_CLONES
#endif

/* every float32 constant of the trunk, as the bytes of this machine's floats */
static const union {{
  float f[{n_floats}];
  char c[{n_bytes}];
}} __attribute__((aligned(32))) cape_data = {{.c =
{data}}};
{bounds}
/* a macro, not a function: a vector argument would be passed differently by the two builds */
#define CAPE_SUM8(a) \\
  ((((a)[0] + (a)[1]) + ((a)[2] + (a)[3])) + (((a)[4] + (a)[5]) + ((a)[6] + (a)[7])))

/* y = W·x + b: W (m × n) by rows, n a multiple of 8 (zero columns pad it, x is zero there) */
CAPE_CLONES static void cape_dense(const float* w, const float* b, const float* x, float* y,
                                   int m, int n) {{
  int j = 0, k;
  cape_v8f v, f;
  for (; j + 4 <= m; j += 4) {{
    const float *w0 = w + (long) j * n, *w1 = w0 + n, *w2 = w1 + n, *w3 = w2 + n;
    cape_v8f a0 = {{0}}, a1 = {{0}}, a2 = {{0}}, a3 = {{0}};
    for (k = 0; k < n; k += 8) {{
      memcpy(&v, x + k, sizeof v);
      memcpy(&f, w0 + k, sizeof f); a0 += f * v;
      memcpy(&f, w1 + k, sizeof f); a1 += f * v;
      memcpy(&f, w2 + k, sizeof f); a2 += f * v;
      memcpy(&f, w3 + k, sizeof f); a3 += f * v;
    }}
    y[j] = b[j] + CAPE_SUM8(a0);
    y[j + 1] = b[j + 1] + CAPE_SUM8(a1);
    y[j + 2] = b[j + 2] + CAPE_SUM8(a2);
    y[j + 3] = b[j + 3] + CAPE_SUM8(a3);
  }}
  for (; j < m; ++j) {{
    const float* w0 = w + (long) j * n;
    cape_v8f a0 = {{0}};
    for (k = 0; k < n; k += 8) {{
      memcpy(&v, x + k, sizeof v);
      memcpy(&f, w0 + k, sizeof f); a0 += f * v;
    }}
    y[j] = b[j] + CAPE_SUM8(a0);
  }}
}}

static inline float cape_mish(float x) {{
  float t, n;
  if (x > 20.0f) return x;
  t = expf(x);
  n = t * (t + 2.0f);
  return x * (n / (n + 2.0f));
}}

/* PyTorch's LayerNorm (biased variance), the statistics in float64 */
static inline void cape_layer_norm(float* x, const float* w, const float* b, float eps, int n) {{
  double mean = 0.0, var = 0.0, d, r;
  int i;
  for (i = 0; i < n; ++i) mean += x[i];
  mean /= n;
  for (i = 0; i < n; ++i) {{
    d = x[i] - mean;
    var += d * d;
  }}
  r = 1.0 / sqrt(var / n + eps);
  for (i = 0; i < n; ++i) x[i] = (float) ((x[i] - mean) * r) * w[i] + b[i];
}}

/* the trunk on the front's output (float64), and the guard or the plain output */
static void cape_trunk(const casadi_real* features, casadi_real* phi) {{
  float a[{buffer}] __attribute__((aligned(32))), b[{buffer}] __attribute__((aligned(32)));
  int i;
  for (i = 0; i < {n_features}; ++i) a[i] = (float) features[i];
  for (; i < {features_padded}; ++i) a[i] = 0.0f;
  {steps}
  {output}
}}

static const casadi_int cape_sp_window[3] = {{{rows}, {cols}, 1}};
static const casadi_int cape_sp_phi[3] = {{N_PHI, 1, 1}};

CASADI_SYMBOL_EXPORT casadi_int {phi}_n_in(void) {{ return 1; }}
CASADI_SYMBOL_EXPORT casadi_int {phi}_n_out(void) {{ return 1; }}
CASADI_SYMBOL_EXPORT const char* {phi}_name_in(casadi_int i) {{ return i == 0 ? "window" : 0; }}
CASADI_SYMBOL_EXPORT const char* {phi}_name_out(casadi_int i) {{ return i == 0 ? "phi" : 0; }}
CASADI_SYMBOL_EXPORT const casadi_int* {phi}_sparsity_in(casadi_int i) {{
  return i == 0 ? cape_sp_window : 0;
}}
CASADI_SYMBOL_EXPORT const casadi_int* {phi}_sparsity_out(casadi_int i) {{
  return i == 0 ? cape_sp_phi : 0;
}}
CASADI_SYMBOL_EXPORT int {phi}_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw,
                                  casadi_int* sz_w) {{
  /* the front's work, one more argument and result slot, and the front's output */
  {front}_work(sz_arg, sz_res, sz_iw, sz_w);
  *sz_arg += 1;
  *sz_res += 1;
  *sz_w += {n_features};
  return 0;
}}

/* window (its {n_window} values, row after row) → Φ; slots past the inputs and outputs are
   scratch, as in CasADi's own code, so the caller's pointers are left as they were */
CASADI_SYMBOL_EXPORT int {phi}(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                             casadi_real* w, int mem) {{
  (void) mem;
  arg[1] = arg[0];
  res[1] = w;
  if ({front}(arg + 1, res + 1, iw, w + {n_features}, 0)) return 1;
  if (res[0]) cape_trunk(w, res[0]);
  return 0;
}}
"""


class _Blob:
    """float32 arrays laid end to end, each from a multiple of 8 floats (32-byte aligned)."""

    def __init__(self) -> None:
        self.chunks: list[np.ndarray] = []
        self.size = 0

    def add(self, array: np.ndarray) -> int:
        """Append ``array`` (as float32); its offset in floats."""
        flat = np.ascontiguousarray(array, dtype=np.float32).reshape(-1)
        padded = np.zeros(_padded(flat.size), np.float32)
        padded[: flat.size] = flat
        offset = self.size
        self.chunks.append(padded)
        self.size += padded.size
        return offset

    def data(self) -> bytes:
        """The floats' bytes, in this machine's order (the library is built where it runs)."""
        return np.concatenate(self.chunks or [np.zeros(LANES, np.float32)]).tobytes()

    def literal(self) -> str:
        """The bytes as adjacent string literals of exactly that length (gcc parses them much
        faster than numbers: about 1 s for DDM's 11 MB); octal escapes but for printable ASCII."""
        data = self.data()
        return "\n".join(
            '  "' + "".join(_ESCAPED[c] for c in data[i : i + 96]) + '"'
            for i in range(0, len(data), 96)
        )


def _escape(byte: int) -> str:
    char = chr(byte)
    if 0x20 <= byte < 0x7F and char not in '"\\?':  # '?': no trigraph can form
        return char
    return f"\\{byte:03o}"


_ESCAPED = [_escape(b) for b in range(256)]


def _padded(n: int) -> int:
    return -(-n // LANES) * LANES


def _c_float(value: float) -> str:
    return f"{float(np.float32(value)).hex()}f"
