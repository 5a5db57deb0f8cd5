"""Loading and checking the study configuration.

``config/config.yaml`` is the one place the study's numbers live. Snakemake validates it
against the schema shipped in the package (``cape/schemas/config.schema.yaml``) at start-up;
the ``cape`` command does the same when run by hand. Rules hand each command only the
sections it needs (as JSON), so a change in one section reruns only the jobs that read it.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from cape import schemas
from cape.errors import CapeError
from cape.layout.names import TRUTH, plant_names

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CONFIG = Path("config") / "config.yaml"
PRESENTATION_KEYS = ("label", "color")
"""A model's or controller's keys that only name or colour it: no job's result reads them."""


def _fill_defaults(instance: Any, schema: dict[str, Any]) -> None:
    """Insert the schema's ``default`` values for missing object keys, recursively."""
    if not isinstance(instance, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        if key not in instance and "default" in sub:
            instance[key] = copy.deepcopy(sub["default"])  # never the (cached) schema's own
        if key in instance:
            _fill_defaults(instance[key], sub)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for key, value in instance.items():
            if key not in schema.get("properties", {}):
                _fill_defaults(value, extra)


def check_consistency(
    config: dict[str, Any], source: str = "config", partial: bool = False
) -> None:
    """Cross-field rules a JSON schema cannot express; raise ``CapeError`` naming the field.
    ``partial``: the parts of sections a rule passes; a rule whose fields are not all there
    is not checked (the workflow checked the whole config when it started)."""
    rules = [_check_tracks, _check_training, _check_distinct, _check_eta_labels, _check_seeds]
    if "study" in config and (not partial or {"models", "controllers"} <= config.keys()):
        rules.append(_check_grid)  # names every model and controller: needs them all
    for rule in rules:
        try:
            rule(config, source)
        except (KeyError, TypeError):
            if not partial:
                raise


def _check_tracks(config: dict[str, Any], source: str) -> None:
    catalogue = config["tracks"]["catalogue"]
    data = config["data"]
    for name in data["tracks"]:
        if name not in catalogue:
            raise CapeError(
                f"{source}: field `data.tracks.{name}` names a track missing from "
                f"`tracks.catalogue` ({sorted(catalogue)}); add it there or remove it here."
            )
    reference = config.get("reference")
    if reference is not None and reference["track"] not in catalogue:
        raise CapeError(
            f"{source}: field `reference.track` is {reference['track']!r}, which is not in "
            f"`tracks.catalogue` ({sorted(catalogue)}); choose one of those."
        )
    if reference is not None and reference["v_min"] > reference["v_max"]:
        raise CapeError(f"{source}: field `reference.v_min` exceeds `reference.v_max`; swap them.")
    for key in ("train_track", "test_track"):
        if data[key] not in data["tracks"]:
            raise CapeError(
                f"{source}: field `data.{key}` is {data[key]!r}, which is not one of "
                f"`data.tracks` ({sorted(data['tracks'])}); choose one of those."
            )


def _check_distinct(config: dict[str, Any], source: str) -> None:
    """Two models (or controllers) with the same label or colour: one in every legend."""
    for name in ("models", "controllers"):
        _distinct(config.get(name) or {}, name, source)


def _distinct(entries: dict[str, Any], name: str, source: str) -> None:
    for key in ("label", "color"):
        seen: dict[str, str] = {}
        for entry, settings in entries.items():
            value = settings.get(key) if isinstance(settings, dict) else None
            if not isinstance(value, str):
                continue
            spelled = " ".join(value.split()).lower()
            if spelled in seen:
                raise CapeError(
                    f"{source}: field `{name}.{entry}.{key}` is {value!r}, the same as "
                    f"`{name}.{seen[spelled]}.{key}`; give each its own, or the figures' legends "
                    "cannot tell them apart"
                )
            seen[spelled] = entry


def _check_training(config: dict[str, Any], source: str) -> None:
    training = config.get("training") or {}
    cap = training.get("max_trainings")
    if cap is not None and cap < int(training.get("replicates", 1)):
        raise CapeError(
            f"{source}: field `training.max_trainings` is {cap}, below `training.replicates` "
            f"({training['replicates']}): a model could never have its draws; raise it or set null"
        )


def _check_seeds(config: dict[str, Any], source: str) -> None:
    """Draw r's disturbance seeds are r·seed_stride + 0 … its seeds − 1 (SPEC §10, revision 7):
    a draw's seeds (the study's, or a stage plan's) must fit within the stride, or two draws
    would share seeds."""
    study = config["study"]
    stride = int(study["seed_stride"])
    plan = (config.get("question") or {}).get("plan") or {}
    counts = [("study.seeds", study["seeds"])]
    counts += [("question.plan.seeds", max(plan.get("seeds") or [0]))]
    for key, count in counts:
        if int(count) > stride:
            raise CapeError(
                f"{source}: field `{key}` is {count}, more than `study.seed_stride` ({stride}): "
                "draw 1's seeds would overlap draw 0's; raise `study.seed_stride` to at least "
                f"{count} (or lower `{key}`)"
            )


def schema_default(key: str) -> Any:
    """The config schema's default of ``key`` (dotted, e.g. ``study.seed_stride``; ``*`` for any
    entry of a section of named entries, e.g. ``study.studies.*.kind``), for a builder given
    sections validated without their defaults filled in (``partial``: a ``--config-json``, a
    notebook's or a test's sections): the schema is the one place a default is written.
    ``KeyError`` when it has none."""
    node: Any = schemas.load_schema(schemas.CONFIG)
    for part in key.split("."):
        node = node["additionalProperties"] if part == "*" else node["properties"][part]
    return copy.deepcopy(node["default"])


def setting(section: Mapping[str, Any], key: str, where: str) -> Any:
    """``section[key]``, or the schema's default of ``where.key`` (of ``key``: ``where`` empty,
    the top level) when the section lacks it (sections validated without their defaults
    filled in: a job file, a ``--config-json``)."""
    return section[key] if key in section else schema_default(f"{where}.{key}".strip("."))


ETA_RANGE = (0.0, 5.0)
"""η runs from 0 to 5 (SPEC §6)."""


def check_eta(value: Any, where: str) -> float:
    """η as a float, or ``CapeError`` when it is not a finite number within ``ETA_RANGE``."""
    try:
        eta = float(value)
    except (TypeError, ValueError):
        raise CapeError(f"{where}: η {value!r} is not a number; give one in [0, 5]") from None
    low, high = ETA_RANGE
    if not low <= eta <= high:  # also false for NaN
        raise CapeError(f"{where}: η {value!r} is outside [{low:g}, {high:g}] (SPEC §6)")
    return eta


def _check_eta_labels(config: dict[str, Any], source: str) -> None:
    """Every η label is a number in range, listed once per list, and spelled one way in the
    whole config: a label names the runs' folders, so ``"1"`` and ``"1.0"`` would be two
    folders of the same runs, counted twice in every table."""
    lists = []
    if "eta" in config.get("disturbances", {}):
        lists.append(("disturbances.eta", config["disturbances"]["eta"]))
    for study, grid in (config.get("study") or {}).get("studies", {}).items():
        if "eta" in grid:
            lists.append((f"study.studies.{study}.eta", grid["eta"]))
    spelled: dict[float, tuple[str, str]] = {}  # η → its first label and where it stands
    for where, labels in lists:
        listed: dict[float, int] = {}
        for i, label in enumerate(labels):
            eta = check_eta(label, f"{source}: field `{where}[{i}]`")
            if eta in listed:
                raise CapeError(
                    f"{source}: field `{where}[{i}]` is {label!r}, the same η as "
                    f"`{where}[{listed[eta]}]` ({labels[listed[eta]]!r}); list each η once"
                )
            listed[eta] = i
            first, there = spelled.setdefault(eta, (label, f"{where}[{i}]"))
            if first != label:
                raise CapeError(
                    f"{source}: field `{where}[{i}]` spells η {eta:g} as {label!r}, `{there}` "
                    f"as {first!r}; spell it the same way everywhere (it names the run folders)"
                )


def _check_grid(config: dict[str, Any], source: str) -> None:
    """Every name of the study grid must exist in the config: an unknown one is an error here,
    not a study that silently lacks it (or reuses stale results)."""
    plants = plant_names(config.get("models", {}))
    controllers = list(config.get("controllers", {}))
    for study, grid in config["study"]["studies"].items():
        where = f"study.studies.{study}"
        for key, known in (("plants", plants), ("internal", plants),
                           ("controllers", controllers)):  # fmt: skip
            for name in grid.get(key, []) or []:
                if name not in known:
                    raise CapeError(
                        f"{source}: field `{where}.{key}` names {name!r}, which the config does "
                        f"not define; use one of {', '.join(known)} (or add it to the config)"
                    )
    # a full config has every default filled in; the parts a rule passes may lack a key, and
    # then its rule is not checked here (the workflow checked the whole config)
    training = config.get("training") or {}
    replicates = int(training["replicates"]) if "replicates" in training else None
    for study, grid in config["study"]["studies"].items() if replicates is not None else ():
        chosen = grid.get("replicates", [0])
        for r in [] if chosen == "all" else chosen:
            if r >= replicates:
                raise CapeError(
                    f"{source}: field `study.studies.{study}.replicates` names draw {r}, "
                    f"but `training.replicates` is {replicates} (draws 0 … "
                    f"{replicates - 1}); drop it or raise `training.replicates`"
                )
    for i, name in enumerate(config.get("training", {}).get("health", {}).get("models", [])):
        if name not in config.get("models", {}):
            raise CapeError(
                f"{source}: field `training.health.models[{i}]` names {name!r}, which the config "
                f"does not define; use one of {', '.join(config.get('models', {}))}"
            )
    paper = config["study"].get("paper")
    if paper is not None and paper not in config["study"]["studies"]:
        raise CapeError(
            f"{source}: field `study.paper` names {paper!r}, which is not a study of "
            f"`study.studies` ({', '.join(config['study']['studies'])}); name one of those, "
            "or set it to null for a grid without the paper's study (and no scorecard)"
        )
    reference = config["study"].get("reference_model")
    if reference is not None and reference not in config.get("models", {}):
        raise CapeError(
            f"{source}: field `study.reference_model` names {reference!r}, which the config "
            f"does not define; use one of {', '.join(config.get('models', {}))}"
        )
    ground_truth = config["study"].get("ground_truth")
    if ground_truth is not None and paper is not None:  # no paper's study: no scorecard reads it
        grid = config["study"]["studies"].get(ground_truth)
        if grid is None or list(grid.get("plants", [])) != [TRUTH]:
            raise CapeError(
                f"{source}: field `study.ground_truth` names {ground_truth!r}, which is not a "
                "study of `study.studies` whose plants are [truth]; name the ground-truth study, "
                "or set it to null for a scorecard without the ground-truth plant's rows"
            )
    if paper is None and "paper" in config["study"]:
        for study, grid in config["study"]["studies"].items():
            if grid.get("kind") == "bicycle":
                raise CapeError(
                    f"{source}: field `study.studies.{study}.kind` is bicycle, which compares "
                    "against the paper's study, but `study.paper` is null; name that study in "
                    "`study.paper`"
                )


RENAMED = {("study", "real_car"): "ground_truth"}
"""Keys renamed: (section, old key) → new key. The ground-truth study runs the simulated car
with its true parameters (SPEC §1), never hardware, so it is not called the real car."""


def _refuse_renamed(config: dict[str, Any], source: str) -> None:
    for (name, old), new in RENAMED.items():
        entries = config.get(name)
        if isinstance(entries, dict) and old in entries:
            raise CapeError(
                f"{source}: field `{name}.{old}` was renamed `{name}.{new}`; write "
                f"`{new}: {entries[old]}` under `{name}` instead"
            )


def _without_required(schema: Any) -> Any:
    """``schema`` with no key required anywhere: rules pass the parts of sections they read."""
    if isinstance(schema, dict):
        return {k: _without_required(v) for k, v in schema.items() if k != "required"}
    if isinstance(schema, list):
        return [_without_required(v) for v in schema]
    return schema


def validate_config(
    config: dict[str, Any], source: str = "config", partial: bool = False
) -> dict[str, Any]:
    """Validate ``config`` against the schema (filling defaults) and the cross-field rules.
    ``partial``: the sections a rule passes (``--config-json``): none is required, and no
    default is filled in (the workflow filled them when it validated the whole config)."""
    _refuse_renamed(config, source)
    schema = schemas.load_schema(schemas.CONFIG)
    if partial:
        schema = _without_required(schema)
    else:
        _fill_defaults(config, schema)
    validator = schemas.validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        first = errors[0]
        field = ".".join(str(p) for p in first.absolute_path) or "(top level)"
        more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
        what = first.schema.get("description") if isinstance(first.schema, dict) else None
        hint = f" ({' '.join(what.split())})" if what and first.validator == "pattern" else ""
        raise CapeError(
            f"{source}: field `{field}`: {first.message}{hint}{more}. "
            f"Fix the value; {schemas.shown(schemas.CONFIG)} describes every key."
        )
    _check_finite(config, source)
    check_consistency(config, source, partial)
    return config


def _check_finite(value: Any, source: str, where: str = "") -> None:
    """No setting takes NaN or an infinity (YAML's ``.nan``, ``.inf``), which JSON schema's
    ``number`` admits and which would slip past every bound (``nan < 0`` is false)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise CapeError(
            f"{source}: field `{where}` is {value}, not a finite number; give a finite value "
            f"({schemas.shown(schemas.CONFIG)} describes every key)"
        )
    if isinstance(value, dict):
        for key, item in value.items():
            _check_finite(item, source, f"{where}.{key}" if where else str(key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _check_finite(item, source, f"{where}[{i}]")


def load_config(path: str | Path = DEFAULT_CONFIG) -> dict[str, Any]:
    """Read and validate a YAML config file (the default one also when run outside the repo)."""
    path = Path(path)
    if path == DEFAULT_CONFIG and not path.is_file():
        path = REPO_ROOT / DEFAULT_CONFIG
    config = read_config_file(path, "run from the repository root or pass --config PATH.")
    if not config:
        raise CapeError(f"{path}: the top level must be a mapping of sections")
    return validate_config(config, str(path))


def merged_config(files: Sequence[str | Path]) -> dict[str, Any]:
    """The config ``files`` merged in order as Snakemake merges ``--configfile`` (mappings key
    by key, any other value replaced; an empty file changes nothing), then validated (the
    schema's defaults filled): how ``cape question`` and ``cape replicates`` read the config
    they hand Snakemake."""
    merged: dict[str, Any] = {}
    for name in files:
        merge_config(merged, read_config_file(Path(name), "run from the repository root"))
    return validate_config(merged, " + ".join(map(str, files)))


def merge_config(into: dict[str, Any], other: Mapping[str, Any]) -> None:
    """``other`` merged into ``into`` as Snakemake merges a ``--configfile``: mappings key by
    key, any other value replaced (by a copy)."""
    for key, value in other.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            merge_config(into[key], value)
        else:
            into[key] = json.loads(json.dumps(value))


def read_config_file(path: Path, missing: str) -> dict[str, Any]:
    """The sections of the YAML config file ``path``, not yet validated ({} for an empty
    file): each way it can fail one ``CapeError`` line (``missing``: what to do when there is
    no such file)."""
    if not path.is_file():
        raise CapeError(f"config file {path} not found; {missing}")
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise CapeError(f"{path}: not a text file, so no YAML config; give a config file "
                        "such as config/smoke.yaml") from None  # fmt: skip
    except OSError as exc:
        raise CapeError(f"{path}: cannot be read ({exc.strerror})") from None
    import yaml  # here: a rule's job reads its config as JSON

    try:
        loaded = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise CapeError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(loaded, dict):
        raise CapeError(f"{path}: the top level must be a mapping of sections")
    return loaded


def config_from_args(
    config_path: str | None, config_json: str | None, spec: str | None = None
) -> dict[str, Any]:
    """The config a command works with: the sections of a job specification file (``spec``,
    how the workflow passes them) or given as JSON, else the config file."""
    fix = ""
    if spec is not None:  # given, even empty: never the config file instead (issue 61)
        fix = "; give the file the workflow wrote for this job under results/specs/"
        try:
            config_json = Path(spec).read_text()
        except (OSError, UnicodeDecodeError) as exc:
            said = getattr(exc, "strerror", None) or "not text"
            raise CapeError(
                f"--spec {spec}: cannot read the job specification ({said}){fix}"
            ) from None
    if config_json is not None:
        source = f"--spec {spec}" if spec is not None else "--config-json"
        if not config_json.strip():
            raise CapeError(f"{source} is empty, not a job specification{fix}")
        try:
            sections = json.loads(config_json)
        except json.JSONDecodeError as exc:
            raise CapeError(f"{source} is not valid JSON ({exc}){fix}") from exc
        if not isinstance(sections, dict):
            raise CapeError(f"{source} must be a JSON object of config sections{fix}")
        if not sections:
            raise CapeError(f"{source} holds no config section, so it is no job specification{fix}")
        checked_once(config_json, lambda: validate_config(sections, source, partial=True))
        return Sections(sections, source=source)  # a missing key: one line, not a traceback
    return load_config(config_path or DEFAULT_CONFIG)


class MissingSettingError(CapeError, KeyError):
    """A section or key a command reads that the sections it was given lack: one line, as every
    ``CapeError``; and a ``KeyError`` still, for code that asks for a key and falls back."""

    __str__ = Exception.__str__  # the message, not KeyError's quoted repr of it


class Sections(dict):
    """The config sections a job was given (``--spec`` or ``--config-json``), every mapping in
    them knowing where it came from: a section or key the command reads and they lack (a
    specification of another job, or one edited by hand) is refused in one line naming the
    source and the field (``MissingSettingError``), never a KeyError's traceback. The schema cannot
    require them: a rule passes only the parts of a section its job reads."""

    def __init__(self, *args: Any, source: str = "", where: str = "", **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.source, self.where = source, where
        for key, value in self.items():
            if isinstance(value, dict) and not isinstance(value, Sections):
                dict.__setitem__(self, key, Sections(value, source=source, where=f"{where}{key}."))

    def __missing__(self, key: Any) -> Any:
        fix = "give the file the workflow wrote for this job under results/specs/"
        if not self.where:
            raise MissingSettingError(f"{self.source} lacks the `{key}` section this command needs "
                                 f"(the specification of another job?); {fix}")  # fmt: skip
        raise MissingSettingError(f"{self.source}: field `{self.where}{key}` is missing, and this "
                             f"command reads it; {fix}")  # fmt: skip


def checked_once(what: str, check: Callable[[], Any], code: tuple[Path, ...] = ()) -> None:
    """``check()``, unless it passed before on this machine for the same ``what`` (the text
    that decides its outcome), the same config schema and the same checking code (this module
    and ``code``). The workflow hands thousands of jobs the same config sections, and importing
    jsonschema to check them would be a third of a short job's wall time (docs/trust.md). The
    marks are files named by that digest in a folder of this user's
    (``$TMPDIR/cape-<uid>/validated``); where none can be had, ``check()`` always runs."""
    marker = _marker(what, code)
    if marker is not None and marker.is_file():
        return
    check()
    if marker is not None:
        with contextlib.suppress(OSError):
            marker.touch()


def _marker(what: str, code: tuple[Path, ...]) -> Path | None:
    import hashlib
    import stat
    import tempfile

    digest = hashlib.sha256(what.encode())
    here = Path(__file__).parent
    checking = (Path(__file__), here / "layout" / "names.py", *(here / "schemas").glob("*.*"))
    try:
        for source in sorted({*checking, *code}):
            digest.update(source.read_bytes())
    except OSError:
        return None
    base = Path(tempfile.gettempdir()) / f"cape-{os.getuid()}"
    try:
        with contextlib.suppress(FileExistsError):
            os.mkdir(base, 0o700)
        info = os.lstat(base)
        if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid():
            return None  # another's, or not a folder: no marks
        if info.st_mode & 0o077:
            os.chmod(base, 0o700)  # ours, made under a lax umask: close it
        folder = base / "validated"
        with contextlib.suppress(FileExistsError):
            os.mkdir(folder, 0o700)
    except OSError:
        return None
    return folder / digest.hexdigest()


def section(config: dict[str, Any], name: str) -> Any:
    """``config[name]``, or a clear error saying which section a command needs."""
    try:
        return config[name]
    except KeyError:
        source = getattr(config, "source", None)
        if source is not None:  # the sections a job was given: those of another job?
            raise CapeError(
                f"{source} lacks the `{name}` section this command needs (the specification of "
                "another job?); give the file the workflow wrote for this job under results/specs/"
            ) from None
        raise CapeError(
            f"the configuration lacks the `{name}` section this command needs"
        ) from None
