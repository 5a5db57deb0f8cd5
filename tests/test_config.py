"""The study configuration: schema validation with clear errors, and the consistency rules."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from cape.config import REPO_ROOT, config_from_args, load_config, validate_config
from cape.errors import CapeError


def test_default_config_is_valid(config) -> None:
    assert config["data"]["steps"] == 1000
    assert set(config["data"]["tracks"]) == {"ETHZ", "ETHZMobil"}
    assert config["tracks"]["catalogue"]["ETHZMobil"]["width"] == 0.46


def _write(tmp_path: Path, cfg: dict) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_wrong_type_names_file_and_field(config, tmp_path: Path) -> None:
    bad = copy.deepcopy(config)
    bad["data"]["steps"] = "many"
    path = _write(tmp_path, bad)
    with pytest.raises(CapeError) as err:
        load_config(path)
    msg = str(err.value)
    assert str(path) in msg and "`data.steps`" in msg and "config.schema.yaml" in msg


def test_unknown_key_is_rejected(config) -> None:
    bad = copy.deepcopy(config)
    bad["data"]["lookahed"] = 0.3
    with pytest.raises(CapeError, match="lookahed"):
        validate_config(bad, "cfg.yaml")


def test_defaults_are_filled(config) -> None:
    cfg = copy.deepcopy(config)
    del cfg["tracks"]["download_timeout"]
    assert validate_config(cfg)["tracks"]["download_timeout"] == 30


def test_train_track_must_be_a_data_track(config) -> None:
    bad = copy.deepcopy(config)
    bad["data"]["train_track"] = "Monza"
    with pytest.raises(CapeError, match=r"`data.train_track` is 'Monza'"):
        validate_config(bad, "cfg.yaml")


def test_data_track_must_be_in_catalogue(config) -> None:
    bad = copy.deepcopy(config)
    del bad["tracks"]["catalogue"]["ETHZMobil"]
    with pytest.raises(CapeError, match=r"`data.tracks.ETHZMobil`.*tracks.catalogue"):
        validate_config(bad, "cfg.yaml")


def test_missing_file_and_bad_json_are_clear(tmp_path: Path) -> None:
    with pytest.raises(CapeError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    (tmp_path / "broken.yaml").write_text("data: [unclosed")
    with pytest.raises(CapeError, match="not valid YAML"):
        load_config(tmp_path / "broken.yaml")
    with pytest.raises(CapeError, match="not valid JSON"):
        config_from_args(None, "{nope")


def test_the_schemas_are_package_data_and_the_config_is_in_the_checkout() -> None:
    from cape.schemas import CONFIG, METRICS, load_schema

    assert load_schema(CONFIG)["type"] == "object"  # read from the package, not the checkout
    assert "failure" in load_schema(METRICS)["properties"]
    assert not (REPO_ROOT / "workflow" / "schemas").exists()  # one copy of each schema
    assert (REPO_ROOT / "config" / "config.yaml").is_file()


def test_the_paper_study_must_be_a_study_of_the_grid(config) -> None:
    bad = copy.deepcopy(config)
    bad["study"]["paper"] = "lerned"
    with pytest.raises(CapeError, match=r"`study.paper` names 'lerned'.*learned"):
        validate_config(bad, "cfg.yaml")
    own = copy.deepcopy(config)  # a grid of one's own: no paper study, no scorecard
    own["study"]["paper"] = None
    own["study"]["studies"] = {"mine": {"plants": ["truth"], "controllers": ["pid"]}}
    assert validate_config(own, "cfg.yaml")["study"]["paper"] is None  # ground_truth: unread
    car = copy.deepcopy(config)
    car["study"]["ground_truth"] = "learned"  # not a ground-truth study
    with pytest.raises(CapeError, match=r"`study.ground_truth` names 'learned'.*or set it to null"):
        validate_config(car, "cfg.yaml")
    old = copy.deepcopy(config)  # the key of earlier versions, refused with its new name
    old["study"]["real_car"] = old["study"].pop("ground_truth")
    with pytest.raises(CapeError, match=r"`study.real_car` was renamed `study.ground_truth`"):
        validate_config(old, "cfg.yaml")
    few = copy.deepcopy(config)  # a cap below the draws could never give them
    few["training"]["max_trainings"] = few["training"]["replicates"] - 1
    with pytest.raises(CapeError, match=r"`training.max_trainings` is 2, below"):
        validate_config(few, "cfg.yaml")
    own["study"]["studies"]["bikes"] = {"kind": "bicycle", "plants": ["epm-fixed"],
                                        "controllers": ["pid"]}  # fmt: skip
    with pytest.raises(CapeError, match=r"`study.studies.bikes.kind` is bicycle"):
        validate_config(own, "cfg.yaml")
