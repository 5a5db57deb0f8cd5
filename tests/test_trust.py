"""Nothing silently wrong (docs/trust.md): damaged artefacts, bad names and values, and an
interrupted workflow each end in one clear message naming the file or key and the fix."""

from __future__ import annotations

import copy
import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import yaml

from cape.cli import main
from cape.config import REPO_ROOT, check_consistency
from cape.controllers import controller_class
from cape.controllers.base import validate_settings
from cape.errors import CapeError
from cape.numerics.compiled import cached_functions, compiled_functions
from cape.storage.integrity import sealed_arrays, sealed_record

TS = 0.02


def _flip_byte(path: Path, offset: int) -> None:
    """A damaged copy replaces the file (a new inode: a library this process has loaded keeps
    its mapping, as a damaged file on disk would meet a fresh process)."""
    data = bytearray(path.read_bytes())
    data[offset % len(data)] ^= 0xFF
    staged = path.with_name(path.name + ".damaged")
    staged.write_bytes(bytes(data))
    os.replace(staged, path)


# --- trained artefacts ----------------------------------------------------------------------
@pytest.fixture()
def model_folder(config, tmp_path: Path) -> Path:
    from cape.training.checkpoint import save_model
    from cape.training.loop import build_model

    model = build_model("dpm", config["models"]["dpm"], TS, seed=0)
    save_model(model, tmp_path, {"seed": 0})
    return tmp_path


def test_corrupted_weights_are_refused_not_exported_as_nan(model_folder: Path) -> None:
    from cape.training.checkpoint import export_network

    export_network(model_folder)  # intact: fine
    _flip_byte(model_folder / "model.pt", -200)  # inside the tensor data
    with pytest.raises(CapeError, match=r"model\.pt: does not match the checksum .* train it"):
        export_network(model_folder)


def test_a_changed_network_file_is_refused(model_folder: Path) -> None:
    from cape.models.network import load_network
    from cape.training.checkpoint import export_network

    path = export_network(model_folder)
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["layer0_weight"] = arrays["layer0_weight"] * 1.001  # a plausible-looking edit
    np.savez(path, **arrays)
    with pytest.raises(CapeError, match=r"network\.npz: its content does not match .* rebuild"):
        load_network(path)
    path.write_bytes(b"")  # empty
    with pytest.raises(CapeError, match=r"network\.npz: not a readable network"):
        load_network(path)


def test_meta_json_without_its_name_names_the_file(model_folder: Path) -> None:
    from cape.models.trained import load_physics

    meta = json.loads((model_folder / "meta.json").read_text())
    del meta["name"]
    (model_folder / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CapeError, match=r"meta\.json"):
        load_physics(model_folder)


def test_damaged_raceline_and_frozen_phi_are_refused(config, track_dir, tmp_path: Path) -> None:
    from cape.closedloop.setup import frozen_phi, load_reference
    from cape.specs.run import ReferenceSpec

    cfg = copy.deepcopy(config)
    cfg["tracks"]["dir"] = str(track_dir)
    reference = ReferenceSpec.from_config(cfg)
    line = tmp_path / "line.npz"
    theta = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    arrays = {"x": np.cos(theta), "y": np.sin(theta), "speed": np.ones(200)}
    np.savez(line, **sealed_arrays(arrays))
    load_reference(reference, str(line))  # intact: fine
    np.savez(line, **{**sealed_arrays(arrays), "x": arrays["x"] + 1e-3})
    with pytest.raises(CapeError, match=r"line\.npz: its content does not match .* rebuild"):
        load_reference(reference, str(line))
    line.write_bytes(b"garbage")
    with pytest.raises(CapeError, match=r"line\.npz: not a readable raceline"):
        load_reference(reference, str(line))

    from cape.training.checkpoint import save_model
    from cape.training.loop import build_model

    folder = tmp_path / "models" / "ddm"
    save_model(build_model("ddm", config["models"]["ddm"], TS, seed=0), folder, {"seed": 0})
    weights = json.loads((folder / "meta.json").read_text())["weights_sha256"]
    record = sealed_record(
        {"model": "ddm", "phi": {"Bf": 5.6, "Df": 0.19}, "weights_sha256": weights}
    )
    (folder / "frozen_phi.json").write_text(json.dumps(record))
    assert frozen_phi(tmp_path / "models", "ddm") == {"Bf": 5.6, "Df": 0.19}
    record["phi"]["Df"] = 0.9
    (folder / "frozen_phi.json").write_text(json.dumps(record))
    with pytest.raises(CapeError, match=r"frozen_phi\.json: its content does not match"):
        frozen_phi(tmp_path / "models", "ddm")
    (folder / "frozen_phi.json").write_text("{")
    with pytest.raises(CapeError, match=r"frozen_phi\.json: not readable JSON"):
        frozen_phi(tmp_path / "models", "ddm")


def test_a_damaged_compiled_library_is_refused_not_loaded(tmp_path: Path) -> None:
    x = ca.SX.sym("x")
    functions = {"double": ca.Function("trust_double", [x], [2 * x])}
    settings = {"enabled": True, "cache": str(tmp_path), "compiler": "gcc", "flags": ["-O0"]}
    loaded, library = compiled_functions("trust", functions, settings, "fingerprint-1")
    assert library is not None and float(loaded["double"](3.0)) == 6.0
    again = cached_functions({"double": "trust_double"}, "fingerprint-1", settings)
    assert again is not None and float(again[0]["double"](4.0)) == 8.0
    _flip_byte(library, len(library.read_bytes()) // 2)
    with pytest.raises(CapeError, match=r"\.so: its content does not match .* rebuilds it"):
        cached_functions({"double": "trust_double"}, "fingerprint-1", settings)
    library.with_name(library.name + ".sha256").unlink()
    with pytest.raises(CapeError, match="no checksum recorded"):
        cached_functions({"double": "trust_double"}, "fingerprint-1", settings)


def test_a_damaged_compiled_phi_is_refused_not_loaded(config, tmp_path: Path) -> None:
    from cape.models.network import load_network, save_network
    from cape.training.loop import build_model

    spec = {**config["models"]["ddm"], "gru": {"hidden": 2, "layers": 1}}
    spec["head"] = {"width": 8, "layers": 1, "activation": "mish"}
    save_network(tmp_path / "network.npz", build_model("ddm", spec, TS, seed=0).network_arrays())
    settings = {"enabled": True, "cache": str(tmp_path), "compiler": "gcc", "flags": ["-O0"]}
    network = load_network(tmp_path / "network.npz", settings)
    window = np.zeros((network.history, 7))
    network.phi(window)
    assert network.library is not None
    _flip_byte(network.library, network.library.stat().st_size // 2)
    with pytest.raises(CapeError, match=r"phi_\w+\.so: its content does not match .* rebuilds it"):
        load_network(tmp_path / "network.npz", settings).phi(window)


# --- names and values -----------------------------------------------------------------------
@pytest.mark.parametrize("eta", ["nan", "inf", "1e9", "-0.5", "abc"])
def test_eta_outside_its_range_is_refused(eta: str, capsys) -> None:
    code = main(["rollout", "--plant", "truth", "--controller", "pid", "--eta", eta,
                 "--seed", "0", "--out", "unused"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "--eta" in err and eta in err and "[0, 5]" in err


def test_a_negative_seed_is_refused(capsys) -> None:
    code = main(["rollout", "--plant", "truth", "--controller", "pid", "--eta", "1",
                 "--seed", "-1", "--out", "unused"])  # fmt: skip
    assert code == 2 and "--seed -1" in capsys.readouterr().err


def test_a_bad_internal_model_is_named_as_such(capsys) -> None:
    code = main(["rollout", "--plant", "truth", "--controller", "pid", "--internal", "epn",
                 "--eta", "1", "--seed", "0", "--out", "unused"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "--internal epn" in err and "--plant" not in err


@pytest.mark.parametrize(
    ("controller", "edit", "message"),
    [
        ("pid", lambda s: s["heading"].update(kii=0.1), r"controllers\.pid\.heading.*'kii'"),
        ("pid", lambda s: s["speed"].pop("kp"), r"controllers\.pid\.speed.*'kp' is a required"),
        ("nmpc", lambda s: s.update(horizn=15), r"controllers\.nmpc.*'horizn'"),
        ("nmpc", lambda s: s.update(horizon=0), r"controllers\.nmpc\.horizon.*minimum"),
        ("rise", lambda s: s.update(ks="fast"), r"controllers\.rise\.ks.*not of type"),
        ("rnmpc", lambda s: s["robust"].pop("m0"), r"controllers\.rnmpc\.robust.*'m0'"),
    ],
)
def test_a_misspelt_or_bad_controller_key_is_named(config, controller, edit, message) -> None:
    settings = copy.deepcopy(config["controllers"][controller])
    validate_settings(controller_class(controller, settings), controller, settings)  # fine
    edit(settings)
    with pytest.raises(CapeError, match=message):
        validate_settings(controller_class(controller, settings), controller, settings)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("plants", ["epn"], r"study\.studies\.learned\.plants` names 'epn'"),
        ("controllers", ["pdi"], r"study\.studies\.learned\.controllers` names 'pdi'"),
        ("internal", ["truht"], r"study\.studies\.learned\.internal` names 'truht'"),
        ("eta", ["7"], r"study\.studies\.learned\.eta\[0\]`: η '7' is outside"),
    ],
)
def test_unknown_names_in_the_grid_are_refused(config, key, value, message) -> None:
    cfg = copy.deepcopy(config)
    cfg["study"]["studies"]["learned"][key] = value
    with pytest.raises(CapeError, match=message):
        check_consistency(cfg)


def _snakemake(*args: str, cwd: Path = REPO_ROOT, **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["snakemake", "-s", str(REPO_ROOT / "Snakefile"), *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300, **kw)  # fmt: skip


def test_snakemake_refuses_an_unknown_grid_name_even_with_results_present(tmp_path) -> None:
    """The check runs when the workflow is parsed: stale results cannot hide the error."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"study": {"studies": {"learned": {"plants": ["epn"]}}}}))
    result = _snakemake("-n", "--cores", "1", "--configfile", str(bad))
    out = result.stdout + result.stderr
    assert result.returncode != 0
    assert "names 'epn'" in out and "Traceback" not in out.split("names 'epn'")[0][-2000:]


@pytest.mark.parametrize(
    ("overlay", "message"),
    [
        ({"training": {"health": {"models": ["ddm", "epn"]}}},
         "`training.health.models[1]` names 'epn', which the config does not define"),
        ({"training": {"checkpoint_every": float("nan")}},
         "`training.checkpoint_every` is nan, not a finite number"),
        ({"rollout": {"penalty": {"lap_time": float("inf")}}},
         "`rollout.penalty.lap_time` is inf, not a finite number"),
    ],
)  # fmt: skip
def test_snakemake_refuses_a_misspelt_health_model_and_non_finite_numbers(
    tmp_path: Path, overlay: dict, message: str
) -> None:
    """A misspelt model in the health checks flagged nothing without a word; .nan turned
    checkpoints off; both are errors when the workflow is parsed."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(overlay))
    result = _snakemake("-n", "--cores", "1", "--configfile", str(bad))
    out = result.stdout + result.stderr
    assert result.returncode != 0 and message in out, out[-3000:]


def test_cape_train_refuses_a_non_finite_checkpoint_interval(tmp_path: Path) -> None:
    result = subprocess.run(
        ["cape", "train", "--model", "dpm", "--data", str(tmp_path / "none.npz"), "--out",
         str(tmp_path / "m"), "--checkpoint-every", "nan"], capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "--checkpoint-every nan: give a number of at least 0" in result.stderr
    assert not (tmp_path / "m").exists()


# --- interruption ----------------------------------------------------------------------------
def _planned_rollouts(dry_run_output: str) -> dict[str, str]:
    """The rollout jobs a dry run plans, as {metrics.json path: Snakemake's reason}."""
    plan = {}
    for block in dry_run_output.split("rule rollout:")[1:]:
        output = re.search(r"output: (\S+metrics\.json)", block)
        reason = re.search(r"reason: (.*)", block)
        assert output and reason, block
        plan[output.group(1)] = reason.group(1)
    return plan


@pytest.mark.slow
def test_a_training_snakemake_did_not_record_is_rewritten_not_retrained(tmp_path: Path) -> None:
    """`snakemake` killed with SIGKILL (itself, not its job) as a training writes its model:
    the rerun deletes the outputs of the job it never recorded and runs it again, which
    rewrites them from the training's kept checkpoint in seconds, byte-identical."""
    work = tmp_path / "work"
    (work / "config").mkdir(parents=True)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    cfg["tracks"]["mirror"] = str((REPO_ROOT / cfg["tracks"]["mirror"]).resolve())
    cfg["models"]["dpm"]["train"]["epochs"] = 3
    cfg["training"]["compile"] = {"enabled": False}
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    folder = work / "results" / "trainings" / "dpm" / "seed0"
    target = str((folder / "model.pt").relative_to(work))
    command = ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), "--cores", "1", "-d", str(work),
               target]  # fmt: skip
    first = subprocess.Popen(command, cwd=REPO_ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.time() + 600
    while time.time() < deadline and first.poll() is None and not (folder / "model.pt").exists():
        time.sleep(0.01)
    first.send_signal(signal.SIGKILL)  # snakemake alone: its job runs on to its end
    first.wait()
    assert (folder / "model.pt").exists(), "snakemake ended before the training wrote its model"
    time.sleep(5)  # the orphaned `cape train` exits
    written = {n: (folder / n).read_bytes() for n in ("model.pt", "meta.json", "loss.csv")}
    plan = _snakemake("-n", "--cores", "1", "-d", str(work), target).stdout
    assert "rule train:" in plan, plan  # Snakemake never recorded it: the job is run again
    again = subprocess.run(command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    log = (work / "results" / "logs" / "train" / "dpm" / "seed0.log").read_text()
    assert "already trained: its outputs rewritten from" in log, log
    benchmark = (work / "results" / "benchmarks" / "train" / "dpm" / "seed0.tsv").read_text()
    seconds = float(benchmark.splitlines()[1].split("\t")[0])
    assert seconds < 30, benchmark  # the rewrite: imports and the write, no epoch
    assert {n: (folder / n).read_bytes() for n in written} == written  # byte-identical


@pytest.mark.slow
def test_the_documented_command_resumes_after_kill_9(tmp_path: Path) -> None:
    """`snakemake --cores 2` killed with SIGKILL mid-run: the same command, with no extra flag,
    finishes the work, redoes no run Snakemake had recorded as finished, and leaves no
    half-written run. A job killed between writing its folder and Snakemake recording it is
    one Snakemake marks incomplete: it is redone whole, and only such jobs (at most one per
    core) are."""
    work = tmp_path / "work"
    (work / "config").mkdir(parents=True)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    cfg["tracks"]["mirror"] = str((REPO_ROOT / cfg["tracks"]["mirror"]).resolve())
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = [f"results/runs/truth/rep0/truth/truth/pid/eta{eta}/seed{seed}/metrics.json"
            for eta in ("0", "1", "2") for seed in range(3)]  # fmt: skip
    command = ["snakemake", "-s", str(REPO_ROOT / "Snakefile"), "--cores", "2", "-d", str(work),
               *runs]  # fmt: skip
    log = tmp_path / "first.log"
    with log.open("w") as sink:
        first = subprocess.Popen(command, cwd=REPO_ROOT, stdout=sink, stderr=subprocess.STDOUT,
                                 start_new_session=True)  # fmt: skip
        deadline = time.time() + 240
        while time.time() < deadline:  # until Snakemake has recorded one rollout as done
            steps = re.findall(r"(\d+) of (\d+) steps", log.read_text())
            if steps and int(steps[-1][0]) >= int(steps[-1][1]) - len(runs) + 1:
                break
            time.sleep(0.05)
        os.killpg(first.pid, signal.SIGKILL)  # snakemake and its running jobs, mid-run
        first.wait()
    finished = {r: (work / r).stat().st_mtime_ns for r in runs if (work / r).exists()}
    assert 0 < len(finished) < len(runs), log.read_text()[-3000:]
    for run in runs:  # a run's files appear together or not at all
        folder = (work / run).parent
        assert (folder / "metrics.json").exists() == (folder / "timing.json").exists()
    plan = _planned_rollouts(_snakemake("-n", "--cores", "2", "-d", str(work), *runs).stdout)
    redone = {r for r, reason in plan.items() if r in finished}
    reasons = {r: plan[r] for r in redone}
    # Snakemake's words for an output its markers call incomplete: forced under the profile's
    # rerun-incomplete, never "updated input" or "code changed"
    incomplete = ("Forced execution", "Incomplete output files")
    assert all(why.startswith(incomplete) for why in reasons.values()), reasons
    assert len(redone) <= 2 and len(redone) < len(finished), reasons  # only the jobs in flight
    assert set(plan) == (set(runs) - set(finished)) | redone
    again = subprocess.run(command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stdout + again.stderr
    assert all((work / r).exists() for r in runs)
    kept = {r: (work / r).stat().st_mtime_ns for r in finished if r not in redone}
    assert kept == {r: t for r, t in finished.items() if r not in redone}  # none redone
