"""The typed specifications (cape/specs): every field a job reads is a frozen dataclass or a
plain value, every default is the packaged schema's, and a name the config lacks is one check."""

from __future__ import annotations

import ast
import dataclasses
import importlib
import pkgutil
import typing

import pytest

import cape.specs
from cape.config import REPO_ROOT, schema_default
from cape.errors import CapeError
from cape.specs import Entry, entry_of


def _spec_classes() -> list[type]:
    classes = []
    for info in pkgutil.iter_modules(cape.specs.__path__):
        module = importlib.import_module(f"cape.specs.{info.name}")
        classes += [
            c
            for c in vars(module).values()
            if isinstance(c, type)
            and dataclasses.is_dataclass(c)
            and c.__module__ == module.__name__
        ]
    return classes


def _loose(hint: object) -> bool:
    """Whether a field's type lets a value through untyped: ``Any`` anywhere in it (a mapping
    of ``Any``, ...). A registered class's ``Entry`` is typed: its values are JSON's."""
    return hint is typing.Any or any(_loose(arg) for arg in typing.get_args(hint))


def test_every_field_of_every_spec_is_typed() -> None:
    classes = _spec_classes()
    assert len(classes) >= 15
    loose = []
    for cls in classes:
        assert cls.__dataclass_params__.frozen, cls  # type: ignore[attr-defined]
        hints = typing.get_type_hints(cls, localns=vars(cape.specs))  # JSON names itself
        loose += [f"{cls.__name__}.{name}: {h}" for name, h in hints.items() if _loose(h)]
    assert loose == []
    assert not _loose(Entry) and _loose(typing.Mapping[str, typing.Any])


def test_no_spec_restates_a_default() -> None:
    """A default is the schema's (``setting``, ``schema_default``): no ``.get(key, value)`` with a
    literal value (a number, a string, a truth value) in cape/specs."""
    restated = []
    for path in sorted((REPO_ROOT / "src" / "cape" / "specs").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "get"
                and len(node.args) == 2
                and isinstance(node.args[1], ast.Constant)
                and node.args[1].value is not None
            ):
                restated.append(f"{path.name}:{node.lineno}")
    assert restated == []


def test_a_setting_a_section_leaves_out_is_the_schemas(config: dict) -> None:
    from cape.specs.models import ModelsSpec
    from cape.specs.notebook import ScorecardSettings
    from cape.specs.run import RolloutSettings
    from cape.specs.study import StudySpec
    from cape.specs.training import TrainingSpec

    rollout = {k: v for k, v in config["rollout"].items() if k != "failure_window"}
    settings = RolloutSettings.from_config({"rollout": rollout})
    assert settings.failure_window == schema_default("rollout.failure_window")
    training = {
        k: v for k, v in config["training"].items() if k not in ("checkpoint_every", "replicates")
    }
    trimmed = {**config, "training": training}
    assert TrainingSpec.from_config(trimmed, "epm").checkpoint_every == schema_default(
        "training.checkpoint_every"
    )
    assert StudySpec.from_config(trimmed).replicates == schema_default("training.replicates")
    assert ModelsSpec.from_config({}).multistep_horizon == schema_default(
        "training.multistep_horizon"
    )
    assert ScorecardSettings() == ScorecardSettings.of({})
    assert ScorecardSettings().power == schema_default("scorecard.power")
    assert schema_default("study.studies.*.kind") == "closed_loop"


def test_a_grid_without_its_sections_is_one_error_and_a_notebook_may_lack_them(config) -> None:
    from cape.specs.notebook import NotebookSpec
    from cape.specs.study import StudySpec

    sections = {"study": config["study"], "controllers": config["controllers"]}
    with pytest.raises(CapeError, match="lacks the `disturbances` section"):
        StudySpec.from_config(sections)
    notebook = NotebookSpec.from_config(sections)
    assert notebook.study is not None
    assert notebook.study.replicates == schema_default("training.replicates")
    assert notebook.study.studies["learned"].controllers == tuple(
        config["study"]["studies"]["learned"]["controllers"]
    )
    assert notebook.health is None and notebook.scorecard is None and notebook.disturbances is None


def test_a_notebooks_nested_settings_are_typed(config: dict) -> None:
    from cape.specs.notebook import NotebookSpec, ScorecardSettings
    from cape.specs.run import DisturbancesSpec
    from cape.specs.training import HealthSettings, RmseBar

    spec = NotebookSpec.from_config(config)
    assert isinstance(spec.health, HealthSettings) and isinstance(spec.health.val_rmse_max, RmseBar)
    assert spec.health.applies_to("ddm") and not spec.health.applies_to("dpm")
    assert isinstance(spec.scorecard, ScorecardSettings)
    assert spec.scorecard.margins["mean_speed"] == 3.0
    assert isinstance(spec.disturbances, DisturbancesSpec)
    assert spec.disturbances.eta == tuple(config["disturbances"]["eta"])
    assert "eta" not in spec.disturbances.sources


def test_a_name_the_config_lacks_is_one_check(config: dict) -> None:
    from cape.specs.models import ModelsSpec
    from cape.specs.run import RunSpec
    from cape.specs.training import TrainingSpec

    with pytest.raises(CapeError, match=r"--model gpt: not in the config's `models` \(ddm, dpm"):
        TrainingSpec.from_config(config, "gpt")
    with pytest.raises(CapeError, match=r"--model gpt: not in the config's `models`"):
        ModelsSpec.from_config(config).entry("gpt")
    with pytest.raises(CapeError, match=r"--controller mpc: not in the config's `controllers`"):
        RunSpec.from_config(config, "mpc")
    assert entry_of({"a": 1}, "a", "--x", "xs") == 1
    said = [
        str(path.relative_to(REPO_ROOT))
        for path in (REPO_ROOT / "src" / "cape").rglob("*.py")
        if "not in the config's" in path.read_text()
    ]
    assert said == ["src/cape/specs/__init__.py"]
