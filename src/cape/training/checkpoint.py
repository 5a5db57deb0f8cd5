"""Saving and loading trained models, with clear errors for corrupt or mismatched files.

A model folder holds ``model.pt`` (the state dict: float32 network weights plus the feature
scaler and guard bounds), ``meta.json`` (what was trained, on what, how), ``loss.csv``,
``frozen_phi.json`` (SPEC §4.5) and ``network.npz`` (the weights exported for the closed loop,
which reads them without PyTorch: ``cape.models.trained``).
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cape.errors import CapeError
from cape.layout import paths
from cape.models.base import LearnedModel
from cape.models.network import save_network
from cape.models.trained import FORMAT_VERSION, load_physics, read_meta
from cape.storage.io import write_files


def save_model(
    model: LearnedModel,
    folder: str | Path,
    meta: dict[str, Any],
    extra: Mapping[str, bytes] | None = None,
) -> None:
    """Write ``model.pt``, ``meta.json`` and the ``extra`` files (name → content) into
    ``folder``, all or none (``cape.storage.io.write_files``: new weights never stand beside an old
    ``meta.json``)."""
    folder = Path(folder)
    buffer = io.BytesIO()
    torch.save(model.state_dict(), buffer)
    weights = buffer.getvalue()
    full = {
        "weights_sha256": hashlib.sha256(weights).hexdigest(),  # checked by every load
        "format": FORMAT_VERSION,
        "name": model.name,
        "class": f"{type(model.physics).__module__}.{type(model.physics).__qualname__}",
        "ts": model.ts,
        "spec": model.spec,
        "param_names": list(model.param_names),
        **meta,
    }
    files = {folder / paths.WEIGHTS: weights}
    files[folder / paths.META] = (json.dumps(full, indent=2, sort_keys=True) + "\n").encode()
    files.update({folder / name: data for name, data in (extra or {}).items()})
    write_files(files)


def load_model(folder: str | Path, expected_name: str | None = None) -> LearnedModel:
    """The trained model in ``folder``, in evaluation mode.

    Raises ``CapeError`` naming the file and the fix when the folder is incomplete, a file is
    corrupt, the model is not the expected one, or the weights do not fit the architecture.
    """
    folder = Path(folder)
    model = LearnedModel(load_physics(folder, expected_name))
    name = model.name
    weights = folder / paths.WEIGHTS
    recorded = read_meta(folder).get("weights_sha256")
    if weights.is_file() and recorded != hashlib.sha256(weights.read_bytes()).hexdigest():
        why = (
            (
                "does not match the checksum recorded in meta.json when it was trained (the file "
                "was damaged or replaced)"
            )
            if recorded
            else "has no checksum in meta.json"
        )
        raise CapeError(f"{weights}: {why}; train it again (`snakemake --cores 1 --force "
                        f"{weights}`, which replaces the training's own files)")  # fmt: skip
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise CapeError(f"{weights}: missing; train the model again") from None
    except Exception as exc:  # torch raises several types for a damaged file
        raise CapeError(
            f"{weights}: not a readable checkpoint ({type(exc).__name__}: {exc}); "
            "delete it and train again"
        ) from exc
    if not isinstance(state, dict):
        raise CapeError(f"{weights}: expected a state dict, found {type(state).__name__}")
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    wrong = sorted(
        k for k in set(expected) & set(state) if tuple(state[k].shape) != tuple(expected[k].shape)
    )
    if missing or unexpected or wrong:
        details = []
        if missing:
            details.append(f"missing {missing[:3]}")
        if unexpected:
            details.append(f"unexpected {unexpected[:3]}")
        if wrong:
            k = wrong[0]
            details.append(
                f"{k} has shape {tuple(state[k].shape)}, the architecture in meta.json "
                f"needs {tuple(expected[k].shape)}"
            )
        raise CapeError(
            f"{weights}: does not match the {name} architecture of {folder / paths.META} ("
            + "; ".join(details)
            + "). The weights and the config disagree: retrain the model."
        )
    model.load_state_dict(state)
    model.eval()
    return model


def export_network(
    folder: str | Path, out: str | Path | None = None, expected_name: str | None = None
) -> Path:
    """Write the trained network of ``folder`` as ``network.npz`` (or ``out``) for the closed
    loop; returns the path written."""
    folder = Path(folder)
    target = Path(out) if out is not None else folder / paths.NETWORK
    arrays = load_model(folder, expected_name).network_arrays()
    arrays["weights_sha256"] = np.array(read_meta(folder)["weights_sha256"])  # what it is from
    bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v))]
    if bad:
        raise CapeError(
            f"{folder / paths.WEIGHTS}: non-finite weights ({', '.join(bad[:3])}); the training "
            "diverged or the file is damaged: train the model again"
        )
    save_network(target, arrays)
    return target
