"""Which CPU code paths a training's kernels take (``training.kernels``; docs/models.md).

MKL (``MKL_CBWR``), ATen (``ATEN_CPU_CAPABILITY``) and Inductor (``cpp.simdlen``) can each be
pinned; unset, a training takes the CPU's own paths (the default). MKL and ATen read their
variables when PyTorch loads, so ``pin_before_torch`` runs before ``import torch``. Why:
docs/modules.md.
"""

from __future__ import annotations

import os
import sys
from dataclasses import fields
from typing import Any

from cape.errors import CapeError
from cape.specs.training import Kernels

ENVIRONMENT = {"mkl_cbwr": "MKL_CBWR", "aten_capability": "ATEN_CPU_CAPABILITY"}

SELECTING = (
    "MKL_CBWR",
    "ATEN_CPU_CAPABILITY",
    "MKL_ENABLE_INSTRUCTIONS",
    "MKL_DEBUG_CPU_TYPE",
    "ONEDNN_MAX_CPU_ISA",
    "DNNL_MAX_CPU_ISA",
)
"""Environment variables that choose the training's kernels' code paths (MKL's branch, ATen's
and oneDNN's instruction set): set by hand, they draw another network (docs/models.md)."""


def pinned(settings: Kernels | None) -> dict[str, Any]:
    """The pins that are set (what a training's identity records; empty: the CPU's own)."""
    if settings is None:
        return {}
    return {f.name: v for f in fields(settings) if (v := getattr(settings, f.name)) is not None}


def in_effect(settings: Kernels | None) -> dict[str, Any]:
    """What decides a training's kernels beyond the CPU: the config's pins and every selecting
    variable set in the environment (by its name; a config pin sets its own variable, so it
    shows once, as the pin). Part of a training's identity: recorded in meta.json and in the
    checkpoint's fingerprint, so that no checkpoint resumes under another setting."""
    pins = pinned(settings)
    pinned_vars = {ENVIRONMENT[k] for k in pins if k in ENVIRONMENT}
    env = {v: os.environ[v] for v in SELECTING if v in os.environ and v not in pinned_vars}
    return {**pins, **env}


def pin_before_torch(settings: Kernels | None) -> None:
    """Set MKL's and ATen's code paths in the environment; refused once PyTorch is loaded
    (they would then silently not apply)."""
    pins = pinned(settings)
    wanted = {ENVIRONMENT[k]: str(v) for k, v in pins.items() if k in ENVIRONMENT}
    if not wanted:
        return
    if "torch" in sys.modules and any(os.environ.get(k) != v for k, v in wanted.items()):
        raise CapeError(
            "training.kernels: PyTorch is already loaded in this process, so "
            f"{', '.join(wanted)} would not apply; set them before Python starts"
        )
    os.environ.update(wanted)


def pin_inductor(settings: Kernels | None) -> None:
    """Inductor's vector width for the compiled training step (``inductor_simdlen``)."""
    simdlen = pinned(settings).get("inductor_simdlen")
    if simdlen is not None:
        import torch._inductor.config as inductor

        inductor.cpp.simdlen = int(simdlen)
