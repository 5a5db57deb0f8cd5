"""What each job reads: the config sections a rule's command depends on, written as a small
JSON file named by its digest (``paths.SPEC``) that the command reads with ``--spec``.

A rule passes the file's path as a param: changing a setting changes the digest, so exactly
the jobs that read it rerun; the command line stays short, whatever the config holds.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cape.config import PRESENTATION_KEYS
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import models_read
from cape.storage.io import write_text

RUN_ONLY_KEYS = ("plant_envelope", "failure_window")
"""Rollout settings that judge or bound a run, which no controller's NLP reads."""

GRID_KEYS = ("replicates", "max_trainings")
"""The training section's keys that size the grid, which no one job reads."""

Config = Mapping[str, Any]


def validate(config: Config, source: str) -> None:
    """The config against its schema and cross-field rules (cape.config), each controller's
    and disturbance source's own keys, and each model's module imported (it registers the
    model); each problem one ``CapeError`` naming the key and the fix."""
    from cape.closedloop.disturbances import validate_sources
    from cape.config import validate_config
    from cape.controllers import controller_class
    from cape.controllers.base import validate_settings
    from cape.models.registry import model_class

    validate_config(config, source)
    for name, entry in config["controllers"].items():
        validate_settings(controller_class(name, entry), name, entry, source)
    validate_sources(config["disturbances"], source)
    for name, entry in config["models"].items():
        model_class(name, entry)


def spec_file(job: str, text: str) -> str:
    """The path of ``job``'s specification ``text``, written once (atomically) if absent.

    Snakemake asks for it while it plans, so a dry run writes it too; ``CapeError`` in one
    line when it cannot be written."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = Path(paths.SPEC.format(job=job, digest=digest))
    try:
        if not path.exists():
            write_text(path, text)
        elif not path.is_file() or path.read_text(errors="replace") != text:
            raise CapeError(
                f"{path}: holds something other than the job specification named by this "
                "digest, which the workflow did not write; move it away and run again"
            )
    except OSError as exc:
        raise CapeError(
            f"{path}: cannot write the job's specification ({exc.strerror or exc}); the workflow "
            f"writes each job's settings under {paths.SPECS}/: make that folder writable"
        ) from None
    return str(path)


def sections(config: Config, *names: str) -> str:
    """Only the named config sections, as JSON (the training section less the grid's keys)."""
    chosen = {name: config[name] for name in names}
    if "training" in chosen:
        chosen["training"] = {k: v for k, v in chosen["training"].items() if k not in GRID_KEYS}
    return json.dumps(chosen, sort_keys=True)


def training(config: Config, model: str, seed: int) -> str:
    """What training reads: the model's own entry (less its label and colour), the training's
    seed, threads and kernels, the sampling time and the split; nothing else, so that
    unrelated config edits never retrain a model."""
    spec = {k: v for k, v in config["models"][model].items() if k not in PRESENTATION_KEYS}
    settings = {k: config["training"][k] for k in ("threads", "fused_adam", "compile")}
    kernels = {k: v for k, v in config["training"].get("kernels", {}).items() if v is not None}
    if kernels:  # unset pins change nothing, so they are not part of a training's identity
        settings["kernels"] = kernels
    return json.dumps(
        {
            "models": {model: spec},
            "training": {**settings, "seed": int(seed)},
            "data": {k: config["data"][k] for k in ("ts", "split")},
        },
        sort_keys=True,
    )


def health(config: Config, model: str) -> str:
    """What a training's health check reads: the split and the checks' settings, the bar's
    models narrowed to this one (naming a new model there reruns no other check)."""
    checks = dict(config["training"]["health"])
    checks["models"] = [m for m in checks.get("models", []) if m == model]
    return json.dumps(
        {"data": {"split": config["data"]["split"]}, "training": {"health": checks}},
        sort_keys=True,
    )


def rollout(config: Config, controller: str, *names: str, solver: bool = False) -> str:
    """What a run reads: the track data, the reference, the disturbances, the run settings,
    this controller's gains and the entries of the models its plant and internal model
    ``names`` read (none of their labels or colours). A solver (``solver=True``) is not given
    what only judges a run (RUN_ONLY_KEYS)."""
    chosen = {k: config[k] for k in ("tracks", "data", "reference", "disturbances", "rollout")}
    if solver:
        chosen["rollout"] = {k: v for k, v in config["rollout"].items() if k not in RUN_ONLY_KEYS}
    chosen["models"] = {
        name: {k: v for k, v in entry.items() if k not in PRESENTATION_KEYS}
        for name, entry in models_read(config["models"], *names).items()
    }
    gains = config["controllers"][controller]
    chosen["controllers"] = {
        controller: {k: v for k, v in gains.items() if k not in PRESENTATION_KEYS}
    }
    return json.dumps(chosen, sort_keys=True)


def notebook_parameters(parameters: Mapping[str, Any]) -> str:
    """A notebook's parameters for papermill's ``-f``, each a string as ``-r`` would pass it
    (a list joined by commas), in the order given."""

    def text(value: Any) -> str:
        return ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)

    return json.dumps({name: text(value) for name, value in parameters.items()}, indent=1)


def export(config: Config) -> str:
    """What exporting a network reads: how its Φ is compiled."""
    return json.dumps({"rollout": {"compile": config["rollout"]["compile"]}}, sort_keys=True)


def grid(config: Config) -> str:
    """What cape.study.grid.study_grid reads, for `cape aggregate` to build the same grid: the
    study section, η, the number of draws and the controllers. In the config's order, not
    sorted: the studies' order decides which folder computes a shared run."""
    return json.dumps(
        {
            "study": config["study"],
            "disturbances": {"eta": config["disturbances"]["eta"]},
            "training": {"replicates": int(config["training"]["replicates"])},
            "controllers": config["controllers"],
        }
    )
