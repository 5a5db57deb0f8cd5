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


def _build(work: Path, cfg: dict[str, Any], target: str) -> None:
    """Write ``cfg`` as the scratch folder's config (the track mirror made absolute) and build
    ``target`` there through the real `snakemake`."""
    mirror = cfg["tracks"]["mirror"]
    cfg["tracks"]["mirror"] = str((REPO_ROOT / mirror).resolve()) if mirror else None
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    result = subprocess.run(
        ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), "--cores", "2", "-d", str(work), target],
        capture_output=True,
        text=True,
        timeout=1500,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]


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


def test_the_tuned_ddm_is_ddms_class_under_its_own_name_and_recipe(config) -> None:
    """config/examples/ddm_tuned.yaml, merged over the config as Snakemake's --configfile does:
    the config validates, `ddm_tuned` builds DDM's physics and network (the same parameter
    count) under its own name, trains with its own recipe, and the bar applies to it."""
    import copy

    import torch

    from cape.config import validate_config
    from cape.training.loop import build_model

    overlay = yaml.safe_load((REPO_ROOT / "config/examples/ddm_tuned.yaml").read_text())
    merged = validate_config(_merge(copy.deepcopy(config), overlay), "ddm_tuned.yaml")
    tuned, ddm = merged["models"]["ddm_tuned"], merged["models"]["ddm"]
    assert tuned["train"] == {"lr": 1.44e-4, "batch_size": 2, "epochs": 400}
    assert "ddm_tuned" in merged["training"]["health"]["models"]
    torch.set_num_threads(1)
    a = build_model("ddm_tuned", tuned, 0.02, seed=0)
    b = build_model("ddm", ddm, 0.02, seed=0)
    assert a.physics.name == "ddm_tuned" and b.physics.name == "ddm"
    assert type(a.physics) is type(b.physics)
    assert sum(p.numel() for p in a.parameters()) == sum(p.numel() for p in b.parameters())
    for (n, p), (m, q) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert n == m and torch.equal(p, q)  # one class, one seed: the same initial network


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
    _build(work, cfg, "results/notebooks/extension.html")

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


@pytest.mark.slow
def test_a_model_added_by_its_module_and_entry_takes_its_place_in_table_9(tmp_path: Path) -> None:
    """The worked example of config/examples/ (EPM's network, DDM's physics), as a newcomer adds
    a model: its module in a folder of theirs and the overlay's entry, nothing else. Through the
    real `snakemake`, table 9 places it in both studies (learned plants; the ground-truth plant,
    inside the adaptive NMPC) against the reference model, with its effect, verdict, open-loop RMSE
    and complexity; the reference is named as such."""
    import pandas as pd

    work = tmp_path / "work"
    (work / "mine").mkdir(parents=True)
    shutil.copy(EXAMPLES / "epm_network_ddm_physics.py", work / "mine" / "hybrid.py")
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    overlay = REPO_ROOT / "config" / "examples" / "epm_network_ddm_physics.yaml"
    for path in (REPO_ROOT / "config" / "smoke.yaml", overlay):
        cfg = _merge(cfg, yaml.safe_load(path.read_text()))
    cfg["models"]["epmnet"]["module"] = "mine/hybrid.py"
    cfg["models"]["epmnet"]["train"]["epochs"] = 2
    cfg["training"]["health"]["models"] = ["ddm"]  # two epochs pass no bar: as config/smoke.yaml
    one = {"controllers": ["anmpc"], "eta": ["0", "1"], "replicates": "all"}
    cfg["study"]["studies"] = {  # the slice table 9 reads: both studies, the adaptive NMPC
        "learned": {"plants": ["epm", "epmnet"], **one},
        "truth": {"plants": ["truth"], "internal": ["epm", "epmnet"], **one},
    }
    target = "results/tables/table09_leaderboard.csv"
    _build(work, cfg, target)
    table = pd.read_csv(work / target)
    assert set(table["study"]) == {
        "learned plants (the paper's study)",
        "the ground-truth plant (the simulated true car)",
    }
    for _, rows in table.groupby("study"):
        rows = rows.set_index("model")
        assert set(rows.index) == {"epm", "epmnet"}  # every model the study ran, the new one too
        assert sorted(rows["rank"]) == [1, 2]
        assert rows.loc["epm", "verdict vs reference"] == "the reference"
        new = rows.loc["epmnet"]
        assert new["verdict vs reference"] in ("lower", "higher", "inconclusive")
        assert np.isfinite(new["effect vs reference"])
        assert new["test_rmse_omega"] > 0 and new["params_M"] > 0
    glance = (work / "results" / "RESULTS.md").read_text()
    assert "## Table 9: where each model stands" in glance and "epmnet" in glance
    assert (work / "results" / "figures" / "fig14_leaderboard.png").stat().st_size > 0
