"""Shared fixtures: the verified track files and the two reproduced data sets."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from commands import cape, sampled_snakemake

from cape.config import REPO_ROOT, load_config
from cape.data.bayesrace import ProtocolSettings, generate_dataset
from cape.specs.tracks import DataSettings, ReferenceSettings
from cape.storage.integrity import sealed_arrays
from cape.tracks.fetch import obtain_tracks
from cape.tracks.raceline import build_raceline
from cape.tracks.track import load_raceline, load_track
from cape.vehicle.params import ACTUATOR_LIMITS, GROUND_TRUTH


@pytest.fixture(scope="session")
def config() -> dict:
    return load_config(REPO_ROOT / "config" / "config.yaml")


@pytest.fixture(scope="session")
def track_dir(tmp_path_factory: pytest.TempPathFactory, config: dict) -> Path:
    """The ten track files, obtained the way the workflow does (mirror first, then download)."""
    dest = tmp_path_factory.mktemp("bayesrace")
    mirror = config["tracks"]["mirror"]
    obtain_tracks(
        dest,
        mirror=(REPO_ROOT / mirror) if mirror else None,
        url_template=config["tracks"]["upstream_url"],
        log=lambda _msg: None,
    )
    return dest


@pytest.fixture(scope="session")
def datasets(track_dir: Path, config: dict) -> dict[str, dict[str, np.ndarray]]:
    """DYN-PP-ETHZ and DYN-PP-ETHZMobil, generated once for the whole test session."""
    out = {}
    for track, entry in config["data"]["tracks"].items():
        settings = ProtocolSettings.of(DataSettings.from_config(config), track)
        out[track] = generate_dataset(
            load_raceline(track_dir, entry["raceline"]), GROUND_TRUTH, settings
        )
    return out


@pytest.fixture(scope="session")
def setup(
    track_dir: Path, config: dict, datasets: dict, tmp_path_factory: pytest.TempPathFactory
) -> dict:
    """A config file pointing at the verified tracks, the reference raceline and the training
    data set (whose states bound a learned plant)."""
    root = tmp_path_factory.mktemp("safety")
    np.savez(root / "ethz.npz", **datasets["ETHZ"])
    cfg = copy.deepcopy(config)
    cfg["tracks"]["dir"] = str(track_dir)
    cfg["tracks"]["mirror"] = str(track_dir)
    cfg["training"]["compile"]["enabled"] = False  # two epochs: compiling costs more
    cfg["rollout"]["compile"]["enabled"] = False  # nothing compiled into the repository
    for name in ("nmpc", "anmpc", "rnmpc"):
        cfg["controllers"][name]["compile"]["enabled"] = False
    config_file = root / "config.yaml"
    config_file.write_text(yaml.safe_dump(cfg))
    rl = build_raceline(
        load_track(track_dir, "ETHZMobil", "ethzMobil", 0.46),
        ReferenceSettings.from_config(config),
        GROUND_TRUTH,
        ACTUATOR_LIMITS,
    )
    raceline = root / "line.npz"
    np.savez(raceline, **sealed_arrays({"x": rl.x, "y": rl.y, "speed": rl.speed}))
    return {"root": root, "config": config_file, "raceline": raceline, "cfg": cfg,
            "data": root / "ethz.npz"}  # fmt: skip


@pytest.fixture(scope="session")
def trained(setup: dict, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two one-epoch trainings of DPM: one that is no draw, one of replicate 1."""
    root = tmp_path_factory.mktemp("trained")
    folders = {}
    for label, extra in (("plain", []), ("rep1", ["--replicate", "1"])):
        folder = root / label / "dpm"
        made = cape("train", "--model", "dpm", "--data", str(setup["data"]), "--out", str(folder),
                    "--epochs", "1", *extra, "--config", str(setup["config"]))  # fmt: skip
        assert made.returncode == 0, made.stderr
        exported = cape("export-network", "--model", f"dpm={folder}")
        assert exported.returncode == 0, exported.stderr
        folders[label] = folder
    return folders


def workdir(tmp_path: Path, **track_overrides: object) -> Path:
    """A scratch working directory with its own config (absolute mirror path)."""
    work = tmp_path / "work"
    (work / "config").mkdir(parents=True)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    mirror = cfg["tracks"]["mirror"]
    cfg["tracks"]["mirror"] = str((REPO_ROOT / mirror).resolve()) if mirror else None
    cfg["tracks"].update(track_overrides)
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    return work


@pytest.fixture(scope="session")
def smoke_study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The whole workflow on the smoke slice, from nothing, once for the session's slow tests
    (tests/test_workflow.py, tests/test_benchmarks.py): the default target and the
    `replicates` target (two training replicates). Its config is config/config.yaml with
    config/smoke.yaml merged over it (``--configfile config/smoke.yaml``)."""
    work = workdir(tmp_path_factory.mktemp("smoke"))
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    # about 5 minutes on 2 idle cores; the timeout only guards against a hang
    result, threads = sampled_snakemake(
        "--cores", "2", "-d", str(work), "all", "replicates", "--configfile", "config/smoke.yaml",
        timeout=1800,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    SMOKE_THREADS.append(threads)  # the most threads snakemake's own process held
    return work


SMOKE_THREADS: list[int | None] = []
"""The most threads the smoke study's `snakemake` process held (tests/test_workflow.py)."""
