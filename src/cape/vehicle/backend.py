"""Array-library dispatch, so the vehicle equations are written once.

The same function evaluates on NumPy arrays and Python floats (simulation, data), PyTorch
tensors (training, with autograd) and CasADi symbols (the NMPC's NLP). The backend is chosen
from the types of the arguments; PyTorch and CasADi are imported only when one of their
objects is actually passed, so a NumPy-only caller never pays their import time.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Ops:
    """The handful of elementary functions the equations need, for one array library."""

    name: str
    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    atan: Callable[[Any], Any]
    atan2: Callable[[Any, Any], Any]
    abs: Callable[[Any], Any]
    maximum: Callable[[Any, Any], Any]
    minimum: Callable[[Any, Any], Any]
    stack: Callable[[Sequence[Any]], Any]


NUMPY = Ops(
    name="numpy",
    sin=np.sin,
    cos=np.cos,
    atan=np.arctan,
    atan2=np.arctan2,
    abs=np.abs,
    maximum=np.maximum,
    minimum=np.minimum,
    stack=lambda xs: np.stack(np.broadcast_arrays(*xs), axis=0),
)


def _torch_ops() -> Ops:
    import torch

    def _stack(xs: Sequence[Any]) -> Any:
        ts = [x if isinstance(x, torch.Tensor) else None for x in xs]
        ref = next(t for t in ts if t is not None)
        full = [
            t if t is not None else torch.as_tensor(x, dtype=ref.dtype)
            for t, x in zip(ts, xs, strict=True)
        ]
        return torch.stack(torch.broadcast_tensors(*full), dim=0)

    def _as_t(a: Any, b: Any) -> tuple[Any, Any]:
        if not isinstance(a, torch.Tensor):
            a = torch.as_tensor(a, dtype=b.dtype)
        if not isinstance(b, torch.Tensor):
            b = torch.as_tensor(b, dtype=a.dtype)
        return a, b

    return Ops(
        name="torch",
        sin=torch.sin,
        cos=torch.cos,
        atan=torch.atan,
        atan2=lambda y, x: torch.atan2(*_as_t(y, x)),
        abs=torch.abs,
        maximum=lambda a, b: torch.maximum(*_as_t(a, b)),
        minimum=lambda a, b: torch.minimum(*_as_t(a, b)),
        stack=_stack,
    )


def _casadi_ops() -> Ops:
    import casadi as ca

    return Ops(
        name="casadi",
        sin=ca.sin,
        cos=ca.cos,
        atan=ca.atan,
        atan2=ca.atan2,
        abs=ca.fabs,
        maximum=ca.fmax,
        minimum=ca.fmin,
        stack=lambda xs: ca.vertcat(*xs),
    )


_CACHE: dict[str, Ops] = {"numpy": NUMPY}


def ops_for(*values: Any) -> Ops:
    """The backend of the first argument that is a PyTorch tensor or a CasADi object."""
    for v in values:
        module = type(v).__module__
        if module.startswith("torch") and "torch" in sys.modules:
            if "torch" not in _CACHE:
                _CACHE["torch"] = _torch_ops()
            return _CACHE["torch"]
        if module.startswith("casadi"):
            if "casadi" not in _CACHE:
                _CACHE["casadi"] = _casadi_ops()
            return _CACHE["casadi"]
    return NUMPY
