"""Never destroy, never mix (docs/trust.md): a user's files, a hand-edited or damaged result,
a bad grid, a full disk and an interrupted command, each through the real command line, each
ending in one message that names the file or key and the fix, a non-zero exit, nothing
destroyed and nothing that looks finished."""

from __future__ import annotations

import copy
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from commands import cape, one_message, rollout, rollout_args, snakemake

from cape.config import REPO_ROOT
from cape.layout.runs import RUN_FILES
from cape.schemas import CONFIG, METRICS, load_schema


@pytest.fixture(scope="module")
def a_run(setup: dict) -> Path:
    """One real run's folder (PID on the ground-truth car), laid out as the workflow's."""
    out = setup["root"] / "runs" / "truth" / "rep0" / "truth" / "truth" / "pid" / "eta0" / "seed0"
    result = rollout(setup, out)
    assert result.returncode == 0, result.stderr
    return out


# --- 1. an output folder is replaced only if it holds a previous run's own files ------------
def test_rollout_refuses_a_folder_it_did_not_write(setup: dict, tmp_path: Path) -> None:
    mine = tmp_path / "p"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    one_message(rollout(setup, mine), str(mine), "thesis.tex", "nothing was changed")
    assert (mine / "thesis.tex").read_text() == "x" and sorted(os.listdir(mine)) == ["thesis.tex"]
    assert sorted(os.listdir(tmp_path)) == ["p"]  # no temporary folder left beside it

    checkout = tmp_path / "checkout"  # `--out .` from a scratch copy of a checkout
    for name in (".git", "config", "results"):
        (checkout / name).mkdir(parents=True)
    (checkout / "config" / "config.yaml").write_text("mine")
    one_message(rollout(setup, Path("."), cwd=checkout), "the working folder")
    assert (checkout / "config" / "config.yaml").read_text() == "mine"

    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep")
    one_message(rollout(setup, a_file), "not a folder")
    assert a_file.read_text() == "keep"


def test_rollout_replaces_its_own_earlier_output(setup: dict, tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()  # an empty folder may be used
    for _ in range(2):  # the second time it replaces the first run's files
        result = rollout(setup, out)
        assert result.returncode == 0, result.stderr
        assert sorted(os.listdir(out)) == sorted(RUN_FILES)
    assert sorted(os.listdir(tmp_path)) == [".run.owner", "run"]  # nothing left aside


# --- 5, 10. a run's files are checked before they are aggregated ------------------------------
def aggregate(setup: dict, tmp_path: Path, studies: dict) -> subprocess.CompletedProcess:
    cfg = {
        "study": {"seeds": 1, "studies": studies},
        "disturbances": {"eta": ["0"]},
        "controllers": {"pid": {}},
        "training": {"replicates": 1},
    }
    return cape(
        "aggregate",
        "--root",
        str(setup["root"] / "runs"),
        "--out",
        str(tmp_path / "runs.parquet"),
        "--summary",
        str(tmp_path / "summary.parquet"),
        "--config-json",
        json.dumps(cfg),
    )


TRUTH = {"truth": {"plants": ["truth"], "controllers": ["pid"]}}


def test_an_intact_run_aggregates(setup: dict, a_run: Path, tmp_path: Path) -> None:
    result = aggregate(setup, tmp_path, TRUTH)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "runs.parquet").is_file() and (tmp_path / "summary.parquet").is_file()


def _damaged(a_run: Path, tmp_path: Path, edit) -> Path:
    """A copy of the runs root with the run damaged by ``edit(folder)``."""
    root = tmp_path / "runs"
    shutil.copytree(a_run.parents[6], root)
    folder = root / a_run.relative_to(a_run.parents[6])
    edit(folder)
    return folder


def _edit_json(name: str, change):
    def edit(folder: Path) -> None:
        record = json.loads((folder / name).read_text())
        change(record)
        (folder / name).write_text(json.dumps(record))

    return edit


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        (_edit_json("metrics.json", lambda m: m.update(success="yes")), ["field `success`"]),
        (_edit_json("metrics.json", lambda m: m.update(success=None)), ["field `success`"]),
        (_edit_json("metrics.json", lambda m: m.pop("plant")), ["'plant' is a required"]),
        (
            _edit_json("metrics.json", lambda m: m.pop("lap_time_penalised")),
            ["'lap_time_penalised' is a required"],
        ),
        (_edit_json("metrics.json", lambda m: m.update(lap_time=5.0)), ["checksum"]),
        (lambda f: (f / "metrics.json").write_text("{"), ["metrics.json: unreadable"]),
        (lambda f: (f / "timing.json").unlink(), ["timing.json: missing"]),
        (lambda f: (f / "timing.json").write_text("{"), ["timing.json: unreadable"]),
        (
            _edit_json("timing.json", lambda t: t.update(solve_ms_median="fast")),
            ["solve_ms_median"],
        ),
        (
            lambda f: (f / "timeseries.parquet").write_bytes(
                (f / "timeseries.parquet").read_bytes()[:5000]
            ),
            ["truncated, damaged"],
        ),
    ],
)
def test_a_damaged_or_edited_run_stops_the_aggregation(
    setup: dict, a_run: Path, tmp_path: Path, edit, needles, capsys
) -> None:
    """In this process (`cape`'s own entry point, ten variants: a subprocess each would cost
    seconds of imports); the real command is run on a copied run below."""
    from cape.cli import main

    folder = _damaged(a_run, tmp_path, edit)
    cfg = {
        "study": {"seeds": 1, "studies": TRUTH},
        "disturbances": {"eta": ["0"]},
        "controllers": {"pid": {}},
        "training": {"replicates": 1},
    }
    out = tmp_path / "out"
    code = main(
        [
            "aggregate",
            "--root",
            str(tmp_path / "runs"),
            "--out",
            str(out / "r.parquet"),
            "--summary",
            str(out / "s.parquet"),
            "--config-json",
            json.dumps(cfg),
        ]
    )
    captured = capsys.readouterr()
    one_message(subprocess.CompletedProcess([], code, captured.out, captured.err),
                str(folder), f"snakemake --cores 1 --force {folder / 'metrics.json'}",
                *needles)  # fmt: skip
    assert "rm " not in captured.err  # no advice to delete a folder (issue 61)
    assert not out.exists()  # nothing that looks finished


def test_a_run_copied_into_another_runs_folder_is_refused(
    setup: dict, a_run: Path, tmp_path: Path
) -> None:
    """A ground-truth run's metrics copied into the learned study's DPM/PID folder."""
    root = setup["root"] / "runs"
    fake = root / "learned" / "rep0" / "dpm" / "dpm" / "pid" / "eta0" / "seed0"
    shutil.copytree(a_run, fake)
    try:
        result = aggregate(
            setup, tmp_path, {"learned": {"plants": ["dpm"], "controllers": ["pid"]}}
        )
        one_message(
            result,
            str(fake / "metrics.json"),
            "another run",
            "study 'truth' (the folder says 'learned')",
        )
    finally:
        shutil.rmtree(root / "learned")


def test_disk_full_is_one_message_and_nothing_half_written(
    setup: dict, a_run: Path, tmp_path: Path
) -> None:
    """`--out` on a full tmpfs (in a mount namespace of its own): `cape rollout` and
    `cape aggregate` each say so in one line, exit 2, and leave no file there."""
    if shutil.which("unshare") is None:
        pytest.skip("needs unshare (util-linux) to mount a small tmpfs")
    full = tmp_path / "full"
    full.mkdir()
    cfg = {
        "study": {"seeds": 1, "studies": TRUTH},
        "disturbances": {"eta": ["0"]},
        "controllers": {"pid": {}},
        "training": {"replicates": 1},
    }
    aggregate_args = [
        "cape",
        "aggregate",
        "--root",
        str(setup["root"] / "runs"),
        "--out",
        f"{full}/runs.parquet",
        "--summary",
        f"{full}/summary.parquet",
        "--config-json",
        json.dumps(cfg),
    ]
    rollout = rollout_args(setup, full / "run")
    script = (
        f"mount -t tmpfs -o size=64k cape-full {full} || exit 77; "
        f"dd if=/dev/zero of={full}/filler bs=4k 2>/dev/null; "
        f"{' '.join(map(_quote, rollout))}; echo rollout=$?; "
        f"{' '.join(map(_quote, aggregate_args))}; echo aggregate=$?; ls -A {full}"
    )
    done = subprocess.run(
        ["unshare", "--mount", "--map-root-user", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if done.returncode == 77 or "unshare:" in done.stderr:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()[:200]}")
    assert "rollout=2" in done.stdout and "aggregate=2" in done.stdout, done.stdout + done.stderr
    assert done.stdout.strip().splitlines()[-1] == "filler", done.stdout  # nothing else there
    errors = [line for line in done.stderr.splitlines() if line.startswith("cape ")]
    assert len(errors) == 2 and "Traceback" not in done.stderr, done.stderr
    assert all("the disk is full" in line for line in errors), errors


def _quote(arg: str) -> str:
    import shlex

    return shlex.quote(arg)


# --- 6. exported network and frozen Φ are tied to the weights they came from ----------------
def test_a_network_left_from_earlier_weights_is_refused(
    setup: dict, datasets: dict, tmp_path: Path
) -> None:
    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    folder = tmp_path / "models" / "dpm"
    train = (
        "train",
        "--model",
        "dpm",
        "--data",
        str(data),
        "--out",
        str(folder),
        "--epochs",
        "1",
        "--config",
        str(setup["config"]),
    )
    from cape.cli import main

    # trained, exported and frozen as the workflow does (in this process: torch is loaded)
    assert main([*train, "--seed", "0"]) == 0
    assert (
        main(["export-network", "--model", f"dpm={folder}", "--config", str(setup["config"])]) == 0
    )
    frozen = str(folder / "frozen_phi.json")
    freeze = ["freeze", "--model", f"dpm={folder}", "--data", str(data), "--out", frozen]
    assert main([*freeze, "--config", str(setup["config"])]) == 0
    # another training (here: another seed) over a finished one: refused, it is not the same
    one_message(cape(*train, "--seed", "1"), f"--out {folder}: holds trained model dpm seed 0",
                "nothing was changed")  # fmt: skip
    for name in ("model.pt", "meta.json", "loss.csv"):  # as Snakemake deletes them to retrain
        (folder / name).unlink()
    retrained = cape(*train, "--seed", "1")
    assert retrained.returncode == 0, retrained.stderr
    # another model into this model's folder: refused before anything is written
    kept = {n: (folder / n).read_bytes() for n in ("model.pt", "meta.json", "loss.csv")}
    other = cape(*[("ddm" if a == "dpm" else a) for a in train])
    one_message(other, f"--out {folder}: holds trained model dpm seed 1", "not trained model ddm",
                "nothing was changed")  # fmt: skip
    assert {n: (folder / n).read_bytes() for n in kept} == kept

    def run(plant: str) -> subprocess.CompletedProcess:
        args = rollout_args(setup, tmp_path / plant, plant=plant)
        return cape(*args[1:], "--models-dir", str(tmp_path / "models"))

    one_message(run("dpm"), "network.npz", "stale", "cape export-network")
    one_message(run("dpm-fixed"), "frozen_phi.json", "stale")
    assert not (tmp_path / "dpm").exists() and not (tmp_path / "dpm-fixed").exists()


# --- 6b. a run records the trained networks it used; a stale or misfiled run is refused ------
def test_a_run_is_tied_to_its_replicates_networks(
    setup: dict, datasets: dict, tmp_path: Path
) -> None:
    """A run labelled replicate 1 computed on replicate 0's network is refused by `cape
    rollout`; a replicate never trained is refused; a run whose network was retrained since is
    refused by the aggregation, naming the run, the model, both digests and the fix."""
    from cape.cli import main

    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    models = tmp_path / "models"
    folder = models / "rep0" / "dpm"
    config = ["--config", str(setup["config"])]
    train = ["train", "--model", "dpm", "--data", str(data), "--out", str(folder), "--epochs", "1",
             "--replicate", "0"]  # fmt: skip
    assert main([*train, *config]) == 0
    assert main(["export-network", "--model", f"dpm={folder}", *config]) == 0
    runs = tmp_path / "runs"
    out = runs / "learned" / "rep0" / "dpm" / "dpm" / "pid" / "eta0" / "seed0"
    base = rollout_args(setup, out, plant="dpm", study="learned")[1:]
    misfiled = cape(*base, "--replicate", "1", "--model", f"dpm={folder}")
    one_message(misfiled, "--replicate 1: the dpm model in", "is draw 0's")
    never = cape(*base, "--replicate", "5", "--models-dir", str(models / "rep5"))
    one_message(never, "rep5/dpm/meta.json: missing")
    assert not out.exists()
    made = cape(*base, "--model", f"dpm={folder}")
    assert made.returncode == 0, made.stderr
    recorded = json.loads((out / "metrics.json").read_text())["models"]["plant"]
    meta = json.loads((folder / "meta.json").read_text())
    assert recorded["weights_sha256"] == meta["weights_sha256"] and recorded["replicate"] == 0
    aggregate = ["aggregate", str(out / "metrics.json"), "--out", str(tmp_path / "runs.parquet"),
                 "--summary", str(tmp_path / "summary.parquet"), "--models-root", str(models),
                 *config]  # fmt: skip
    assert cape(*aggregate).returncode == 0
    for name in ("model.pt", "meta.json", "loss.csv"):  # as Snakemake deletes them to retrain
        (folder / name).unlink()
    assert cape(*train, "--seed", "1", *config).returncode == 0  # retrained
    stale = cape(*aggregate)
    one_message(stale, str(out), "plant model dpm", recorded["weights_sha256"][:12],
                json.loads((folder / "meta.json").read_text())["weights_sha256"][:12],
                f"snakemake --cores 1 --force {out / 'metrics.json'}")  # fmt: skip
    assert "rm " not in stale.stderr  # no advice to delete a folder (issue 61)


def test_a_model_table_is_tied_to_its_replicates_networks(
    setup: dict, datasets: dict, tmp_path: Path
) -> None:
    """Tables 1 and 4 record each row's replicate and weights digest (in the .csv, not in what a
    reader opens); the scorecard's reader refuses a table computed from another replicate's
    network or from weights retrained since, naming the table, the model and the fix."""
    from cape.cli import main
    from cape.errors import CapeError
    from cape.study.inputs import read_replicate_tables

    train_data, test_data = tmp_path / "ethz.npz", tmp_path / "mobil.npz"
    np.savez(train_data, **datasets["ETHZ"])
    np.savez(test_data, **datasets["ETHZMobil"])
    models = tmp_path / "models"
    config = ["--config", str(setup["config"])]
    for r in (0, 1):
        folder = str(models / f"rep{r}" / "dpm")
        train = ["train", "--model", "dpm", "--replicate", str(r), "--data", str(train_data)]
        assert main([*train, "--out", folder, "--epochs", "1", "--seed", str(r), *config]) == 0
    tables = tmp_path / "tables" / "rep0"
    openloop = ["openloop", "--train-data", str(train_data), "--test-data", str(test_data)]
    complexity = ["complexity", "--data", str(test_data)]
    for command, name in (
        (openloop, "table04_openloop_rmse"),
        (complexity, "table01_model_complexity"),
    ):
        csv, md = tables / f"{name}.csv", tables / f"{name}.md"
        made = cape(*command, "--model", f"dpm={models / 'rep0' / 'dpm'}", "--out", str(csv),
                    "--out", str(md), *config)  # fmt: skip
        assert made.returncode == 0, made.stderr
        assert "weights_sha256" not in md.read_text()
        assert read_replicate_tables([0], str(csv), models)[0]["replicate"].tolist() == [0]
        misfile = [*command, "--model", f"dpm={models / 'rep1' / 'dpm'}", "--out", str(csv),
                   *config]  # fmt: skip
        # over the table of draw 0: refused, a table of draw 1 is another table
        one_message(cape(*misfile), "holds", "of dpm draw 0", "not", "of dpm draw 1")
        csv.unlink()  # by hand: a table file misfiled is still caught by its reader
        misfiled = cape(*misfile)
        assert misfiled.returncode == 0, misfiled.stderr
        with pytest.raises(CapeError, match="computed from draw 1's network") as refused:
            read_replicate_tables([0], str(csv), models)
        assert str(csv) in str(refused.value) and f"snakemake --cores 2 {csv}" in str(refused.value)
    retrain = ["train", "--model", "dpm", "--data", str(train_data), "--out",
               str(models / "rep0" / "dpm"), "--replicate", "0", "--epochs", "1", "--seed", "7",
               *config]  # fmt: skip
    (tables / "table04_openloop_rmse.csv").unlink()
    assert cape(*openloop, "--model", f"dpm={models / 'rep0' / 'dpm'}", "--out",
                str(tables / "table04_openloop_rmse.csv"), *config).returncode == 0  # fmt: skip
    for name in ("model.pt", "meta.json", "loss.csv"):  # as Snakemake deletes them to retrain
        (models / "rep0" / "dpm" / name).unlink()
    assert cape(*retrain).returncode == 0
    with pytest.raises(CapeError, match=r"draw 0's is .*rep0/dpm .*stale"):
        read_replicate_tables([0], str(tables / "table04_openloop_rmse.csv"), models)


def test_the_kernel_environment_is_part_of_a_trainings_identity(
    setup: dict, datasets: dict, tmp_path: Path
) -> None:
    """MKL_CBWR set by hand draws another network: meta.json records it (it said `{}`), and the
    checkpoint's fingerprint holds it, so a checkpoint is never resumed under another setting."""
    from cape.specs.training import Kernels
    from cape.training.kernels import in_effect

    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    out = tmp_path / "dpm"
    result = subprocess.run(
        ["cape", "train", "--model", "dpm", "--data", str(data), "--out", str(out), "--epochs",
         "1", "--config", str(setup["config"])], capture_output=True, text=True, timeout=600,
        env={**os.environ, "MKL_CBWR": "COMPATIBLE"},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert json.loads((out / "meta.json").read_text())["kernels"] == {"MKL_CBWR": "COMPATIBLE"}
    pinned = Kernels(mkl_cbwr="AVX2")
    assert in_effect(pinned) == {"mkl_cbwr": "AVX2"}  # a pin shows once, as the pin


# --- 3. training resumes from its checkpoint, byte-identical ---------------------------------
@pytest.mark.slow
def test_a_killed_training_resumes_to_the_same_bytes(
    setup: dict, datasets: dict, tmp_path: Path, capsys
) -> None:
    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    cfg = copy.deepcopy(setup["cfg"])
    cfg["models"]["dpm"]["train"]["batch_size"] = 128  # a few steps an epoch: quick epochs
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(cfg))

    def train(out: Path, *extra: str) -> list[str]:
        return ["cape", "train", "--model", "dpm", "--data", str(data), "--out", str(out),
                "--epochs", "10", "--checkpoint-every", "0", "--config", str(config_file),
                *extra]  # fmt: skip

    from cape.cli import main

    assert main(train(tmp_path / "whole")[1:]) == 0  # uninterrupted (in this process)
    killed = tmp_path / "killed"
    process = subprocess.Popen(train(killed), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and process.poll() is None:
        checkpoints = list(killed.glob("checkpoint-*.pt"))
        if checkpoints and _epoch_of(checkpoints[0]) >= 3:
            break
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (killed / "model.pt").exists(), "killed too late: the training had finished"
    (checkpoint,) = killed.glob("checkpoint-*.pt")
    kept = _epoch_of(checkpoint)
    saved = tmp_path / checkpoint.name
    shutil.copy(checkpoint, saved)
    again = subprocess.run(train(killed), capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert f"resumed from {checkpoint} after epoch {kept}" in again.stdout
    for name in ("model.pt", "loss.csv"):
        assert (killed / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
    assert _epoch_of(checkpoint) == 10  # kept, at the last epoch
    import torch

    before = torch.load(saved, weights_only=True)["cpu_seconds"]  # the killed part's CPU
    after = json.loads((killed / "meta.json").read_text())["cpu_seconds"]
    assert 0 < before < after  # every part counted, not only the last

    # the outputs deleted, as Snakemake deletes a job's outputs it had not recorded as done:
    # the rerun rewrites them from the kept checkpoint, without training again
    whole = {n: (killed / n).read_bytes() for n in ("model.pt", "loss.csv", "meta.json")}
    for name in ("model.pt", "meta.json", "loss.csv"):
        (killed / name).unlink()
    started = time.perf_counter()
    third = subprocess.run(train(killed), capture_output=True, text=True, timeout=600)
    assert third.returncode == 0, third.stderr
    assert f"already trained: its outputs rewritten from {checkpoint} (epoch 10)" in third.stdout
    assert {n: (killed / n).read_bytes() for n in whole} == whole  # its record too
    assert time.perf_counter() - started < 60

    # another config (here: another seed) never resumes that checkpoint, nor removes it
    from cape.cli.models import _training_output
    from cape.storage.ownership import claimed

    other = tmp_path / "other"
    with claimed([_training_output(other, "dpm")], "test"):  # a training's folder, as
        other.mkdir()  # `cape train` claims it before it trains
    shutil.copy(saved, other / saved.name)
    assert main(train(other, "--seed", "1", "--epochs", "1")[1:]) == 0
    assert "resumed" not in capsys.readouterr().out
    assert (other / saved.name).read_bytes() == saved.read_bytes()


def test_a_checkpoint_of_another_training_is_refused(tmp_path: Path) -> None:
    """A checkpoint whose content was written for another fingerprint (copied or renamed by
    hand) is refused with the fix, never resumed."""
    from cape.errors import CapeError
    from cape.training.loop import CHECKPOINT_KEYS, Checkpointing

    path = tmp_path / "checkpoint.pt"
    Checkpointing(path, "a" * 64).save(dict.fromkeys(CHECKPOINT_KEYS, 0))
    assert Checkpointing(path, "a" * 64).load() is not None
    with pytest.raises(CapeError, match=r"checkpoint of another training .* not resumed; delete"):
        Checkpointing(path, "b" * 64).load()


def _epoch_of(checkpoint: Path) -> int:
    import torch

    for _ in range(20):  # it may be replaced while we read it
        try:
            return len(torch.load(checkpoint, weights_only=True)["losses"])
        except Exception:
            time.sleep(0.05)
    return 0


# --- 11, 13. a time limit no lap can meet; Ctrl-C and SIGTERM ---------------------------------
def test_a_time_limit_shorter_than_a_lap_is_refused(setup: dict, tmp_path: Path) -> None:
    cfg = copy.deepcopy(setup["cfg"])
    cfg["rollout"]["time_limit"] = 0.001
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(cfg))
    result = cape(*rollout_args(setup, tmp_path / "run", config=bad)[1:])
    one_message(result, "rollout.time_limit", "0.001", "ideal lap")
    line = tmp_path / "line.npz"
    result = cape(
        "raceline",
        "--track",
        "ETHZMobil",
        "--out",
        str(line),
        "--time-limit",
        "0.001",
        "--config",
        str(setup["config"]),
    )
    one_message(result, "rollout.time_limit")
    assert not line.exists() and not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("sig", "code", "word", "solver"),
    [
        (signal.SIGINT, 130, "interrupted", "sqp"),
        (signal.SIGTERM, 143, "terminated", "sqp"),
        # IPOPT solving every step: the signal lands inside it, where it would be swallowed
        # and CasADi would print a warning of its own
        (signal.SIGINT, 130, "interrupted", "ipopt"),
    ],
)
def test_an_interrupted_rollout_says_so_in_one_line(
    setup: dict, tmp_path: Path, sig, code, word, solver
):
    out = tmp_path / "run"
    # a crawl round the track (0.2 m/s: a lap of about a minute), so that the signal lands
    # mid-lap however fast the machine is
    cfg = copy.deepcopy(setup["cfg"])
    cfg["reference"].update(scale=0.1, v_min=0.1, v_max=0.2)
    cfg["rollout"]["time_limit"] = 120.0
    cfg["controllers"]["nmpc"]["solver"] = solver
    slow = tmp_path.parent / f"{tmp_path.name}-slow.yaml"
    slow.write_text(yaml.safe_dump(cfg))
    args = rollout_args(setup, out, config=slow, controller="nmpc", internal="truth", eta="2")
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)  # past the imports: in the run's set-up or its lap
    assert process.poll() is None, "the run ended before it could be interrupted"
    process.send_signal(sig)
    _, err = process.communicate(timeout=60)
    assert process.returncode == code, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and word in err, err
    assert sorted(os.listdir(tmp_path)) == []  # no run folder, no temporary folder


# --- 4, 7, 8, 12. the grid and the config, refused when the workflow starts ------------------
def _bad_config(tmp_path: Path, overlay: dict) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(overlay))
    return path


@pytest.mark.parametrize(
    ("overlay", "needles"),
    [
        ({"disturbances": {"eta": ["0", "1", "1.0"]}}, ["disturbances.eta[2]", "'1.0'", "once"]),
        (
            {"study": {"studies": {"ablation": {"eta": ["1.0"]}}}},
            ["study.studies.ablation.eta[0]", "spell"],
        ),
        (
            {
                "study": {
                    "studies": {"../../../escape": {"plants": ["truth"], "controllers": ["pid"]}}
                }
            },
            ["../../../escape", "does not match"],
        ),
        ({"study": {"studies": {"a/b": {"plants": ["truth"], "controllers": ["pid"]}}}}, ["a/b"]),
        (
            {"study": {"studies": {"x" * 301: {"plants": ["truth"], "controllers": ["pid"]}}}},
            ["does not match"],
        ),
        ({"study": {"studies": {"learned": {"plants": ["epm", "epm"]}}}}, ["non-unique"]),
        ({"study": {"seeds": 1000000}}, ["study.seeds", "maximum"]),
        ({"study": {"seeds": 1000}}, ["1,176,000 runs", "study.max_runs"]),
        (
            {"models": {"dpm": {"module": "no_such_module"}}},
            ["models.dpm.module", "no_such_module"],
        ),
    ],
)
def test_the_workflow_refuses_a_bad_grid_before_planning(tmp_path: Path, overlay, needles) -> None:
    started = time.perf_counter()
    result = snakemake(
        "-n", "--cores", "1", "--configfile", str(_bad_config(tmp_path, overlay)), timeout=120
    )
    out = result.stdout + result.stderr
    assert result.returncode != 0, out[-2000:]
    for needle in needles:
        assert needle in out, (needle, out[-3000:])
    assert time.perf_counter() - started < 120  # refused, not planned (no 7 GB dry run)


def test_cape_refuses_a_study_name_that_is_not_an_identifier(setup: dict, tmp_path: Path) -> None:
    result = rollout(setup, tmp_path / "run", study="../escape")
    one_message(result, "--study '../escape'")
    assert sorted(os.listdir(tmp_path)) == []


def test_the_name_pattern_is_the_schemas(config: dict) -> None:
    from cape.layout.names import NAME_PATTERN

    schema = load_schema(CONFIG)
    assert schema["$defs"]["name"]["pattern"] == NAME_PATTERN


def test_the_failure_reasons_are_the_schemas() -> None:
    from cape.closedloop.rollout import FAILURES

    schema = load_schema(METRICS)
    assert set(schema["properties"]["failure"]["enum"]) == {None, *FAILURES}


# --- 2. Snakemake's locks: removed only when provably stale ----------------------------------
def _fake_lock(directory: Path) -> Path:
    lock = directory / ".snakemake" / "locks" / "0.output.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    lock.write_text("results/x\n")
    return lock


def _record(directory: Path, **changes) -> Path:
    from dataclasses import asdict, replace

    from cape.storage.locks import RECORDS, Process

    me = Process.me()
    assert me is not None
    proc = replace(me, **changes)
    path = directory / RECORDS / f"{proc.host}-{proc.pid}-{proc.started}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(asdict(proc)))
    return path


def test_locks_of_a_run_that_has_ended_are_removed(tmp_path: Path) -> None:
    from cape.storage.locks import _start_time, clear_stale_locks

    ended = subprocess.Popen(["sleep", "0"])
    started = _start_time(ended.pid)
    ended.wait()  # gone: its PID may be reused, but not with its start time
    lock, record = _fake_lock(tmp_path), _record(tmp_path, pid=ended.pid, started=started or 1)
    said: list[str] = []
    assert clear_stale_locks(tmp_path, said.append) == [lock]
    assert not lock.exists() and not record.exists() and "resuming" in said[0]


@pytest.mark.parametrize(
    ("changes", "why"),
    [
        ({}, "a snakemake run works in this folder"),  # this very process: alive
        ({"pid_namespace": "pid:[1]"}, "another host or PID namespace"),
        ({"host": "node17"}, "another host or PID namespace"),
        (None, "no record says which run wrote them"),
    ],
)
def test_locks_that_may_belong_to_a_living_run_are_left(tmp_path: Path, changes, why) -> None:
    from cape.storage.locks import clear_stale_locks

    lock = _fake_lock(tmp_path)
    if changes is not None:
        _record(tmp_path, **changes)
    said: list[str] = []
    assert clear_stale_locks(tmp_path, said.append) == []
    assert lock.exists() and why in said[0] and "snakemake --unlock" in said[0]


@pytest.mark.slow
def test_a_second_snakemake_never_removes_a_running_ones_locks(tmp_path: Path) -> None:
    """`python -m snakemake` works; a plain `snakemake` on the same targets, and one in another
    PID namespace (what another node of a shared file system looks like), start beside it:
    neither removes its locks, and the first run's outputs all survive."""
    work = tmp_path / "work"
    (work / "config").mkdir(parents=True)
    cfg = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    cfg["tracks"]["mirror"] = str((REPO_ROOT / cfg["tracks"]["mirror"]).resolve())
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg))
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    targets = ["results/notebooks/setup.ipynb", "results/data/DYN-PP-ETHZ.npz",
               "results/data/DYN-PP-ETHZMobil.npz"]  # fmt: skip
    common = [*targets, "-s", str(REPO_ROOT / "Snakefile"), "-d", str(work), "--cores", "1",
              "--configfile", "config/smoke.yaml"]  # fmt: skip
    module = [sys.executable, "-m", "snakemake", *common]
    first = subprocess.Popen(module, cwd=work, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)  # fmt: skip
    locks = work / ".snakemake" / "locks"
    deadline = time.time() + 120
    while time.time() < deadline and not list(locks.glob("*.lock")):
        assert first.poll() is None, first.communicate()[0][-3000:]
        time.sleep(0.05)
    held = sorted(locks.glob("*.lock"))
    assert held
    second = subprocess.run(["snakemake", *common], cwd=work, capture_output=True, text=True,
                            timeout=300)  # fmt: skip
    said = second.stdout + second.stderr
    assert second.returncode != 0 and "left in place" in said, said
    assert "removed Snakemake's locks" not in said, said
    if shutil.which("unshare"):
        other = subprocess.run(["unshare", "--pid", "--fork", "--mount-proc", "snakemake", "-n",
                                *common], cwd=work, capture_output=True, text=True,
                               timeout=300)  # fmt: skip
        if "unshare:" not in other.stderr:
            said = other.stdout + other.stderr
            assert "removed Snakemake's locks" not in said, said
    still_running = first.poll() is None
    assert not still_running or sorted(locks.glob("*.lock")) == held
    out, _ = first.communicate(timeout=600)
    assert first.returncode == 0, out[-3000:]
    for target in [*targets, "results/figures/fig01_block_diagram.pdf",
                   "results/tables/table02_controller_parameters.csv"]:  # fmt: skip
        assert (work / target).is_file(), target


def test_train_refuses_a_folder_with_a_model_it_did_not_write(setup: dict, tmp_path: Path) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "model.pt").write_bytes(b"my own network")
    result = cape("train", "--model", "dpm", "--data", str(tmp_path / "unused.npz"), "--out",
                  str(mine), "--config", str(setup["config"]))  # fmt: skip
    one_message(result, str(mine), "model.pt", "CAPE did not write")
    assert (mine / "model.pt").read_bytes() == b"my own network"


@pytest.mark.parametrize("option", [["--epochs", "0"], ["--threads", "0"], ["--seed", "-1"]])
def test_train_refuses_counts_that_make_no_model(option: list[str], tmp_path: Path, capsys) -> None:
    """`--epochs 0` once saved an untrained model with an infinite validation loss."""
    from cape.cli import main

    code = main(["train", "--model", "dpm", "--data", "unused.npz", "--out", str(tmp_path / "m"),
                 *option])  # fmt: skip
    assert code == 2 and f"{' '.join(option)}: give a number" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()


# --- training.kernels: a pin in the config is the environment variable it names -------------
def test_a_kernel_pin_in_the_config_trains_as_the_environment_variable_does(
    setup: dict, datasets: dict, tmp_path: Path
) -> None:
    """`training.kernels.mkl_cbwr: AVX2` gives the same weights as MKL_CBWR=AVX2 set by hand
    (the pin reaches MKL, set before PyTorch loads) and is recorded in meta.json; whether it
    differs from the CPU's own path depends on the CPU, so that is not asserted."""
    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    cfg = copy.deepcopy(setup["cfg"])
    cfg["models"]["dpm"]["train"]["batch_size"] = 128
    plain, pinned = tmp_path / "plain.yaml", tmp_path / "pinned.yaml"
    plain.write_text(yaml.safe_dump(cfg))
    cfg["training"]["kernels"] = {"mkl_cbwr": "AVX2"}
    pinned.write_text(yaml.safe_dump(cfg))
    env = {k: v for k, v in os.environ.items() if k != "MKL_CBWR"}

    def train(out: str, config: Path, **extra: str) -> dict:
        args = ["cape", "train", "--model", "dpm", "--data", str(data), "--out",
                str(tmp_path / out), "--epochs", "2", "--config", str(config)]  # fmt: skip
        done = subprocess.run(args, capture_output=True, text=True, env={**env, **extra})
        assert done.returncode == 0, done.stderr
        return json.loads((tmp_path / out / "meta.json").read_text())

    by_config = train("config", pinned)
    by_hand = train("hand", plain, MKL_CBWR="AVX2")
    assert by_config["weights_sha256"] == by_hand["weights_sha256"]
    # both record what chose the kernels: the pin, or the variable set by hand (issue 29)
    assert by_config["kernels"] == {"mkl_cbwr": "AVX2"}
    assert by_hand["kernels"] == {"MKL_CBWR": "AVX2"}


def test_a_kernel_pin_is_refused_once_pytorch_is_loaded(monkeypatch) -> None:
    """MKL and ATen read their variables when PyTorch loads: later, a pin would silently not
    apply, so it is an error naming the key."""
    import torch  # noqa: F401  (loaded, as in any process that has trained)

    from cape.errors import CapeError
    from cape.specs.training import Kernels
    from cape.training.kernels import pin_before_torch

    monkeypatch.delenv("MKL_CBWR", raising=False)
    with pytest.raises(CapeError, match=r"training\.kernels: PyTorch is already loaded"):
        pin_before_torch(Kernels(mkl_cbwr="AVX2"))
    pin_before_torch(Kernels())  # nothing pinned: nothing to refuse


def test_a_plain_install_works_outside_the_checkout(setup: dict, tmp_path: Path) -> None:
    """`pip install .` (not editable) into a folder of its own: from outside the checkout,
    `cape --help`, a rollout with a config file and the config's validation all work, reading
    the schemas from the installed package (never REPO_ROOT/workflow)."""
    target, elsewhere, source = tmp_path / "site", tmp_path / "elsewhere", tmp_path / "source"
    elsewhere.mkdir()
    # a copy of what the package is built from: the build leaves nothing in the checkout
    shutil.copytree(REPO_ROOT / "src", source / "src", ignore=shutil.ignore_patterns("*.egg-info"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(REPO_ROOT / name, source / name)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
         "--target", str(target), str(source)],
        capture_output=True, text=True, timeout=300, cwd=elsewhere,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    assert (target / "cape" / "schemas" / "config.schema.yaml").is_file()
    env = {**os.environ, "PYTHONPATH": str(target)}

    def installed(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "cape.cli", *args], cwd=elsewhere, env=env,
                              capture_output=True, text=True, timeout=300)  # fmt: skip

    where = subprocess.run([sys.executable, "-c", "import cape; print(cape.__file__)"],
                           cwd=elsewhere, env=env, capture_output=True, text=True)  # fmt: skip
    assert where.stdout.strip().startswith(str(target)), where.stdout + where.stderr
    assert installed("--help").returncode == 0
    out = tmp_path / "run"
    made = installed(*rollout_args(setup, out)[1:])
    assert made.returncode == 0, made.stderr[-2000:]
    assert json.loads((out / "metrics.json").read_text())["success"] is True
    bad = tmp_path / "bad.yaml"
    study = {**setup["cfg"]["study"], "seeds": -1}
    bad.write_text(yaml.safe_dump({**setup["cfg"], "study": study}))
    refused = installed(*rollout_args(setup, tmp_path / "none", config=bad)[1:])
    one_message(refused, "study.seeds", "cape/schemas/config.schema.yaml")
