"""Shared fixtures: the verified track files and the two reproduced data sets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cape.config import REPO_ROOT, load_config
from cape.data.bayesrace import ProtocolSettings, generate_dataset
from cape.tracks.fetch import obtain_tracks
from cape.tracks.track import load_raceline
from cape.vehicle.params import GROUND_TRUTH


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
        settings = ProtocolSettings.from_config(config["data"], track)
        out[track] = generate_dataset(
            load_raceline(track_dir, entry["raceline"]), GROUND_TRUTH, settings
        )
    return out
