"""The trunk of an exported network, layer by layer: what ``network.npz`` holds and both the
NumPy trunk (``cape.models.network``) and the compiled one (``cape.models.compiled_phi``)
evaluate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("linear", "layer_norm", "mish", "gelu", "relu", "tanh")
"""The layer kinds an exported trunk may hold."""


@dataclass(frozen=True)
class Layer:
    """One layer of the trunk as exported: ``linear`` (weight in × out, bias), ``layer_norm``
    (weight, bias, eps) or an activation (``mish``, ``gelu``, ``relu``, ``tanh``), float32."""

    kind: str
    weight: np.ndarray | None = None
    bias: np.ndarray | None = None
    eps: float = 0.0
