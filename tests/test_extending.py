"""The worked example of docs/extending.md: a new model and a new controller, each one module,
added to the study by configuration alone."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cape.config import REPO_ROOT

EXAMPLES = REPO_ROOT / "examples"


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Snakemake's --configfile merge: mappings recursively, everything else replaced."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _repo_status() -> str:
    if not (REPO_ROOT / ".git").exists():
        return ""
    return subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def test_the_example_modules_register_their_names(config) -> None:
    from cape.controllers import controller_class
    from cape.models import model_class

    extension = yaml.safe_load((EXAMPLES / "extension.yaml").read_text())
    model = model_class("mlp", extension["models"]["mlp"])
    controller = controller_class("purepursuit", extension["controllers"]["purepursuit"])
    assert model.name == "mlp" and model.param_names == ("ax", "ay", "alpha")
    assert controller.name == "purepursuit" and not controller.needs_internal_model
    physics = model({**config["models"]["epm"], **extension["models"]["mlp"]}, 0.02)
    phi = np.array([2.0, -1.0, 5.0])
    nxt = physics.step_velocities(1.0, 0.1, 0.2, (0.0, 0.0), (0.3, 0.0), phi)
    assert nxt == pytest.approx((1.04, 0.08, 0.3))  # v + Ts·Φ, whatever the input


@pytest.mark.slow
def test_a_model_and_a_controller_added_by_config_alone_run_through_the_study(
    tmp_path: Path,
) -> None:
    import pandas as pd

    before = _repo_status()
    work = tmp_path / "work"
    # what a newcomer writes: two modules and a config, nothing in the repository
    (work / "mine").mkdir(parents=True)
    for module in ("velocity_mlp.py", "pure_pursuit.py"):
        shutil.copy(EXAMPLES / module, work / "mine" / module)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    for overlay in (REPO_ROOT / "config" / "smoke.yaml", EXAMPLES / "extension.yaml"):
        cfg = _merge(cfg, yaml.safe_load(overlay.read_text()))
    cfg["models"]["mlp"]["module"] = "mine/velocity_mlp.py"
    cfg["controllers"]["purepursuit"]["module"] = "mine/pure_pursuit.py"
    cfg["models"]["mlp"]["train"]["epochs"] = 2
    extension = {**cfg["study"]["studies"]["extension"], "eta": ["0", "1"]}
    cfg["study"]["studies"] = {"extension": extension}  # only the new names' slice
    cfg["study"]["paper"] = None  # not the paper's grid: no scorecard
    mirror = cfg["tracks"]["mirror"]
    cfg["tracks"]["mirror"] = str((REPO_ROOT / mirror).resolve()) if mirror else None
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))

    target = "results/notebooks/extension.html"
    result = subprocess.run(
        ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), "--cores", "2", "-d", str(work), target],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]

    runs = pd.read_parquet(work / "results" / "study" / "runs.parquet")
    cells = set(zip(runs["plant"], runs["controller"], runs["eta"], strict=True))
    expected = {
        (p, c, e) for p in ("mlp", "epm") for c in ("pid", "purepursuit") for e in (0.0, 1.0)
    }
    assert cells == expected
    assert (work / "results" / "models" / "rep0" / "mlp" / "network.npz").is_file()
    for name in ("fig03_tracking_error_sweep", "fig09_trajectories_eta0"):
        assert (work / "results" / "figures" / "extension" / f"{name}.png").stat().st_size > 0
    pure = runs[(runs["controller"] == "purepursuit") & (runs["plant"] == "epm")]
    assert pure["steps"].min() > 100  # it really drove

    # the files the newcomer touched: the two modules and the config, and no repository file
    written = sorted(
        str(p.relative_to(work))
        for p in work.rglob("*")
        if p.is_file()
        and p.relative_to(work).parts[0] not in ("results", "resources", ".snakemake")
        and "__pycache__" not in p.parts
    )
    assert written == ["config/config.yaml", "mine/pure_pursuit.py", "mine/velocity_mlp.py"]
    assert _repo_status() == before


@pytest.mark.slow
def test_a_disturbance_source_added_by_config_alone_reaches_the_runs_and_table_3(
    tmp_path: Path,
) -> None:
    import pandas as pd

    work = tmp_path / "work"
    (work / "mine").mkdir(parents=True)
    shutil.copy(EXAMPLES / "throttle_delay.py", work / "mine" / "throttle_delay.py")
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    for overlay in (REPO_ROOT / "config" / "smoke.yaml", EXAMPLES / "disturbance.yaml"):
        cfg = _merge(cfg, yaml.safe_load(overlay.read_text()))
    cfg["disturbances"]["throttle_delay"]["module"] = "mine/throttle_delay.py"
    cfg["study"]["studies"] = {
        "truth": {"plants": ["truth"], "internal": ["truth"], "controllers": ["pid"]}
    }
    cfg["study"]["paper"] = None
    mirror = cfg["tracks"]["mirror"]
    cfg["tracks"]["mirror"] = str((REPO_ROOT / mirror).resolve()) if mirror else None
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))

    run = "results/runs/truth/rep0/truth/truth/pid/eta{}/seed0/timeseries.parquet"
    targets = ["results/tables/table03_uncertainty_activation.csv", run.format(0), run.format(1)]
    snakefile = str(REPO_ROOT / "Snakefile")
    result = subprocess.run(
        ["snakemake", "-s", snakefile, "--cores", "2", "-d", str(work), *targets],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]

    table = pd.read_csv(work / targets[0], dtype=str).set_index("η")
    assert table.loc["0", "throttle delay (steps)"] == "–"
    assert table.loc["1", "throttle delay (steps)"] == "2"
    quiet = pd.read_parquet(work / targets[1])
    np.testing.assert_array_equal(quiet["T_applied"], quiet["T_cmd"])  # η = 0: no delay
    late = pd.read_parquet(work / targets[2])
    assert len(late) > 50
    np.testing.assert_array_equal(late["T_applied"].to_numpy()[2:], late["T_cmd"].to_numpy()[:-2])
    assert (late["T_applied"].to_numpy()[:2] == 0.0).all()
