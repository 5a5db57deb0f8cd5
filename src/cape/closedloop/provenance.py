"""Which trained networks a run was computed with (issue: every result knows what made it).

A run records, for its plant and its controller's internal model when either is a trained
model (learned, or its frozen-Φ variant), the model's folder, its training replicate and the
SHA-256 of its ``model.pt`` (``meta.json``'s ``weights_sha256``; the exported network and the
frozen Φ are checked against it when they are loaded). ``cape rollout --replicate r`` refuses a
model of another replicate, and the aggregation refuses a run whose digests are not those of
its replicate's current models (cape.study.aggregate).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from cape.closedloop.setup import ModelFolders, parse_plant
from cape.config import section
from cape.errors import CapeError
from cape.models.trained import read_meta


def model_replicate(folder: Path, meta: dict[str, Any]) -> int | None:
    """The training replicate of the model in ``folder``: what its meta.json records, else
    what its folder says (``rep<r>/<model>``), else None."""
    if meta.get("replicate") is not None:
        return int(meta["replicate"])
    match = re.fullmatch(r"rep([0-9]+)", Path(folder).parent.name)
    return int(match.group(1)) if match else None


def run_models(
    config: dict[str, Any], plant: str, internal: str | None, folders: ModelFolders, replicate: int
) -> dict[str, dict[str, Any]]:
    """Role (``plant``, ``internal``) → the trained model it uses: name, folder, replicate and
    weights digest; ``CapeError`` for a model of another training replicate than ``replicate``."""
    models = section(config, "models")
    used: dict[str, dict[str, Any]] = {}
    for role, name in (("plant", plant), ("internal", internal)):
        if name is None:
            continue
        kind, model = parse_plant(name, models, f"--{role}")
        if kind == "truth" or model is None:
            continue
        folder = folders(model)
        meta = read_meta(folder)
        trained = model_replicate(folder, meta)
        if trained is not None and trained != replicate:  # a training of no draw: the user's
            raise CapeError(
                f"--replicate {replicate}: the {model} model in {folder} is replicate {trained}'s, "
                "so the run "
                f"would carry its numbers under replicate {replicate}; pass --model "
                f"{model}=results/models/rep{replicate}/{model} (trained by `snakemake --cores 2 "
                f"results/models/rep{replicate}/{model}/network.npz`, with training.replicates "
                f"above {replicate})"
            )
        used[role] = {
            "model": model,
            "folder": str(folder),
            "replicate": trained,
            "weights_sha256": str(meta.get("weights_sha256") or ""),
        }
    return used
