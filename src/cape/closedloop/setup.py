"""Assembling one run from its names: plant, controller, η, seed (what ``cape rollout`` does)."""

from __future__ import annotations

import inspect
import json
import math
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cape.closedloop.disturbances import DisturbancePipeline
from cape.closedloop.envelope import Envelope
from cape.closedloop.plants import FixedParameterPlant, LearnedPlant, Plant, TruthPlant
from cape.closedloop.rollout import LapResult, run_lap
from cape.config import checked_once
from cape.controllers import controller_class
from cape.controllers.base import Controller, validate_settings
from cape.controllers.ekf import NoiseLevels
from cape.controllers.internal import InternalModel, fixed_internal
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import PlantName, truth_structure
from cape.models.registry import model_class
from cape.models.trained import TrainedModel, load_physics, load_trained, read_meta
from cape.specs.run import ReferenceSpec, RunSpec
from cape.storage.integrity import check_arrays, check_record
from cape.tracks import native
from cape.tracks.reference import ReferenceLine, check_time_limit
from cape.tracks.track import Track, load_raceline, load_track
from cape.vehicle.params import ACTUATOR_LIMITS, GROUND_TRUTH


def load_reference(spec: ReferenceSpec, raceline: str | None) -> tuple[ReferenceLine, Track]:
    """The reference line and its track; ``raceline``: the line's file (default: the
    workflow's, results/raceline/<track>.npz)."""
    track = load_track(spec.tracks_dir, spec.track, spec.prefix, spec.width)
    if spec.line == "bayesrace_long":
        rl = load_raceline(spec.tracks_dir, f"{spec.prefix}_raceline_long.npz")
        x, y, speed = rl.x, rl.y, rl.speed
    else:
        path = Path(raceline or paths.raceline(spec.track))
        if not path.is_file():
            raise CapeError(
                f"{path}: reference raceline missing; build it with `snakemake --cores 1 {path}`"
            )
        fix = f"delete it and rebuild it with `snakemake --cores 1 {path}`"
        try:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {k: npz[k] for k in npz.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise CapeError(f"{path}: not a readable raceline ({exc}); {fix}") from None
        check_arrays(arrays, path, fix)
        x, y, speed = arrays["x"], arrays["y"], arrays["speed"]
    return ReferenceLine(x, y, speed, spec.settings, spec.ts), track


@dataclass(frozen=True)
class ModelFolders:
    """Where each trained model's files are: the folder given for its name (what a workflow
    rule declares as its inputs), else ``<root>/<name>`` (the command line's ``--models-dir``)."""

    root: Path = Path(paths.models_of(0))
    named: Mapping[str, Path] = field(default_factory=dict)

    def __call__(self, name: str) -> Path:
        return Path(self.named.get(name, Path(self.root) / name))

    @classmethod
    def of(cls, models: Path | str | ModelFolders) -> ModelFolders:
        return models if isinstance(models, ModelFolders) else cls(Path(models))


def compile_settings(spec: RunSpec) -> dict[str, Any] | None:
    """``rollout.compile`` as the compiling code reads it (cape/numerics), None without it."""
    return None if spec.rollout.compile is None else spec.rollout.compile.as_settings()


def frozen_phi(models: Path | ModelFolders, model_name: str) -> dict[str, float]:
    """The frozen Φ of a trained model (SPEC §4.5), or an error saying how to build it."""
    path = ModelFolders.of(models)(model_name) / paths.FROZEN_PHI
    fix = f"delete it and rebuild it with `snakemake --cores 1 {path}`"
    if not path.is_file():
        raise CapeError(f"{path}: missing; build it with `snakemake --cores 1 {path}`")
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CapeError(f"{path}: not readable JSON ({exc}); {fix}") from None
    check_record(record, path, fix)
    weights = read_meta(path.parent).get("weights_sha256")
    if record.get("weights_sha256") != weights:
        raise CapeError(
            f"{path}: frozen from other weights than the model.pt beside it (its meta.json "
            f"records {str(weights)[:12]}…, the file {str(record.get('weights_sha256'))[:12]}…): "
            f"it is stale; {fix}"
        )
    phi = record.get("phi")
    if not isinstance(phi, dict) or not all(
        isinstance(v, int | float) and math.isfinite(v) for v in phi.values()
    ):
        raise CapeError(f"{path}: `phi` is not a mapping of finite numbers; {fix}")
    return phi


def build_internal(
    spec: RunSpec,
    name: str,
    models_dir: Path | ModelFolders,
    loaded: dict[str, TrainedModel] | None = None,
) -> InternalModel:
    """The controller's internal model by name: a learned model, ``<model>-fixed`` or ``truth``
    (the ground-truth parameters in the Deep Dynamics structure). ``loaded`` holds trained
    models the caller already read (the plant's), so a network is not loaded twice."""
    models, ts = spec.models, spec.ts
    parsed = PlantName.parse(name, models, "--internal")
    kind, model_name = parsed.kind, parsed.model
    if parsed.is_truth:
        structure = truth_structure(models)
        physics = model_class(structure, models[structure])(models[structure], ts)
        truth = GROUND_TRUTH.as_dict()
        return fixed_internal(
            physics, {n: truth[n] for n in physics.param_names if n in truth}, source="truth"
        )
    folder = ModelFolders.of(models_dir)(str(model_name))
    if kind == "learned":
        trained = (loaded or {}).get(str(model_name)) or load_trained(
            folder, model_name, compile_settings(spec)
        )
        return InternalModel(trained.physics, "learned", predictor=trained.network)
    physics = load_physics(folder, model_name)
    return fixed_internal(physics, frozen_phi(models_dir, str(model_name)))


@dataclass
class AssembledRun:
    """An assembled run: call it to drive the lap."""

    plant: Plant
    controller: Controller
    line: ReferenceLine
    track: Track
    disturbances: DisturbancePipeline
    spec: RunSpec
    internal: str
    envelope: Envelope | None = None
    envelope_source: dict[str, str] | None = None  # the training data set: path and digest

    def __call__(self) -> LapResult:
        return run_lap(
            self.plant,
            self.controller,
            self.line,
            self.track,
            self.disturbances,
            self.spec.rollout,
            envelope=self.envelope,
        )


def build_run(
    spec: RunSpec,
    plant_name: str,
    eta: float,
    seed: int,
    internal: str | None,
    models_dir: Path | ModelFolders,
    raceline: str | None = None,
    validate: bool = True,
    envelope_data: str | None = None,
) -> AssembledRun:
    """Everything one run of ``spec``'s controller needs, from names; errors name the missing
    piece and the fix. ``models_dir``: where the trained models' folders are (a root, or a
    ``ModelFolders``). ``validate``: check the controller's settings against its schema
    (skipped for a job's specification, which the workflow validated when it started).
    ``envelope_data``: the training data set whose states bound a learned or fixed-parameter
    plant (default results/data/DYN-PP-<train track>.npz; SPEC §5.3)."""
    models, ts, controller_name = spec.models, spec.ts, spec.controller
    plant_parsed = PlantName.parse(plant_name, models, "--plant")
    kind, model_name = plant_parsed.kind, plant_parsed.model
    if internal is not None:  # a bad name is an error for any controller
        PlantName.parse(internal, models, "--internal")
    compiled = compile_settings(spec)
    native.enable(compiled)  # projections in C: the same numbers
    line, track = load_reference(spec.reference, raceline)
    check_time_limit(float(spec.rollout.time_limit), line.ideal_lap_time())
    disturbances = DisturbancePipeline.from_config(spec.disturbances.sources, eta, seed)
    transform = disturbances.plant_params
    loaded: dict[str, TrainedModel] = {}
    folders = ModelFolders.of(models_dir)
    if plant_parsed.is_truth:
        plant: Plant = TruthPlant(GROUND_TRUTH.as_dict(), ts, transform, compiled)
    elif kind == "learned":
        trained = load_trained(folders(str(model_name)), model_name, compiled)
        loaded[str(model_name)] = trained
        plant = LearnedPlant(trained, transform)
    else:
        physics = load_physics(folders(str(model_name)), expected_name=model_name)
        plant = FixedParameterPlant(physics, frozen_phi(folders, str(model_name)), transform)
    envelope, envelope_source = None, None
    bound = spec.rollout.plant_envelope
    if not plant_parsed.is_truth and bound is not None:
        path = envelope_data or paths.dataset(spec.train_track)
        trained_on = read_meta(folders(str(model_name))).get("data_sha256")
        envelope, envelope_source = Envelope.of_file(path, float(bound), trained_on)
    entry = spec.controller_entry
    cls = controller_class(controller_name, entry)
    if validate:
        validate_settings(cls, controller_name, entry)
    else:  # a rule's config: checked once per entry on this machine (cape.config.checked_once)
        code = tuple(  # the class's module and everything of the controllers' it may use
            {
                Path(inspect.getfile(cls)),
                *Path(inspect.getfile(validate_settings)).parent.glob("*.*"),
            }
        )
        what = json.dumps([controller_name, cls.__module__, cls.__qualname__, entry], default=str)

        def check() -> None:
            validate_settings(cls, controller_name, entry, "--spec/--config-json")

        checked_once(what, check, code)
    default_internal = str(plant_parsed)
    internal_model = None
    if cls.needs_internal_model:
        internal_model = build_internal(spec, internal or default_internal, folders, loaded)
    extra: dict[str, Any] = {}
    if cls.needs_noise_levels:
        extra["levels"] = NoiseLevels.from_pipeline(disturbances)
    controller = cls(
        entry,
        line,
        ACTUATOR_LIMITS,
        ts,
        track=track,
        internal=internal_model,
        name=controller_name,
        actuator_delay=disturbances.steering_delay(ts),  # SPEC §7.1: the latency, never η
        **extra,
    )
    return AssembledRun(
        plant=plant,
        controller=controller,
        line=line,
        track=track,
        disturbances=disturbances,
        spec=spec,
        # a controller without an internal model runs on none: its runs are named after the plant
        internal=(internal or default_internal) if cls.needs_internal_model else default_internal,
        envelope=envelope,
        envelope_source=envelope_source,
    )
