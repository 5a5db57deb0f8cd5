"""Which trained networks a run was computed with (issue: every result knows what made it).

A run records, for its plant and its controller's internal model when either is a trained
model (learned, or its frozen-Φ variant), the model's folder, its training replicate and the
SHA-256 of its ``model.pt`` (``meta.json``'s ``weights_sha256``; the exported network and the
frozen Φ are checked against it when they are loaded). ``cape rollout --replicate r`` refuses a
model of another replicate, and the aggregation refuses a run whose digests are not those of
its replicate's current models (cape.study.aggregate).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from cape.closedloop.setup import ModelFolders
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import PlantName
from cape.models.trained import read_meta


def model_replicate(meta: dict[str, Any]) -> int | None:
    """The training replicate (draw) a model's meta.json records (``cape draw`` writes it),
    or None for a training that is no draw."""
    return None if meta.get("replicate") is None else int(meta["replicate"])


def run_models(
    models: Mapping[str, Any],
    plant: str,
    internal: str | None,
    folders: ModelFolders,
    replicate: int,
) -> dict[str, dict[str, Any]]:
    """Role (``plant``, ``internal``) → the trained model it uses (``models``: the config's
    entries): name, folder, replicate and weights digest; ``CapeError`` for a model of another
    training replicate than ``replicate``."""
    used: dict[str, dict[str, Any]] = {}
    for role, name in (("plant", plant), ("internal", internal)):
        if name is None:
            continue
        model = PlantName.parse(name, models, f"--{role}").model
        if model is None:  # the ground truth: no trained model
            continue
        folder = folders(model)
        meta = read_meta(folder)
        trained = model_replicate(meta)
        if trained is not None and trained != replicate:  # a training of no draw: the user's
            draw = paths.model_dir(model, replicate)
            raise CapeError(
                f"--replicate {replicate}: the {model} model in {folder} is draw {trained}'s, "
                "so the run "
                f"would carry its numbers under draw {replicate}; pass --model "
                f"{model}={draw} (made by `snakemake --cores 2 {draw}/{paths.NETWORK}`, with "
                f"training.replicates above {replicate})"
            )
        used[role] = {
            "model": model,
            "folder": str(folder),
            "replicate": trained,
            "weights_sha256": str(meta.get("weights_sha256") or ""),
        }
    return used
