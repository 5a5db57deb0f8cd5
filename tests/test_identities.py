"""An output's identity is what made it (issue 53): a training, a run and a table replaced by
another of the same kind with another identity is refused in one line, and nothing changes;
the same output again, or its files deleted first (as Snakemake deletes a job's outputs
before it reruns it), is written. Owner records are known by their content."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from commands import cape, one_message, rollout_args
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cape.cli import main

MODEL_FILES = ("model.pt", "meta.json", "loss.csv")
FAST = settings(max_examples=6, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip


def _bytes(folder: Path, names: tuple[str, ...]) -> dict[str, bytes]:
    return {n: (folder / n).read_bytes() for n in names}


@pytest.fixture(scope="module")
def training(setup: dict, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One one-epoch DPM training with seed 0, as `cape train` writes it."""
    folder = tmp_path_factory.mktemp("identity") / "trainings" / "dpm" / "seed0"
    argv = ["train", "--model", "dpm", "--data", str(setup["data"]), "--out", str(folder),
            "--epochs", "1", "--config", str(setup["config"])]  # fmt: skip
    assert main(argv) == 0
    return {"folder": folder, "argv": argv}


@FAST
@given(
    other=st.one_of(
        st.integers(1, 2**32 - 1).map(lambda s: ["--seed", str(s)]),
        st.integers(2, 5).map(lambda e: ["--epochs", str(e)]),
        st.integers(2, 8).map(lambda t: ["--threads", str(t)]),
        st.integers(0, 19).map(lambda r: ["--replicate", str(r)]),
    )
)
def test_a_training_is_not_replaced_by_another(training: dict, other: list[str], capsys) -> None:
    """Another seed, recipe (epochs), thread count or draw into a finished training's folder:
    refused before anything is read or trained, the folder unchanged."""
    folder = training["folder"]
    kept = _bytes(folder, MODEL_FILES)
    assert main([*training["argv"], *other]) == 2
    err = capsys.readouterr().err
    assert "holds trained model dpm seed 0 [" in err and "nothing was changed" in err, err
    assert _bytes(folder, MODEL_FILES) == kept


def test_the_same_training_again_is_written_and_its_files_deleted_free_the_folder(
    training: dict, setup: dict, capsys
) -> None:
    folder = training["folder"]
    kept = _bytes(folder, ("model.pt", "loss.csv"))
    assert main(training["argv"]) == 0  # the same training: its own output (from its checkpoint)
    assert "already trained" in capsys.readouterr().out
    assert _bytes(folder, ("model.pt", "loss.csv")) == kept
    for name in MODEL_FILES:  # as Snakemake deletes a job's outputs to rerun it
        (folder / name).unlink()
    assert main([*training["argv"], "--seed", "3"]) == 0  # the workflow's rerun: allowed
    assert json.loads((folder / "meta.json").read_text())["seed"] == 3


@pytest.fixture(scope="module")
def run(setup: dict, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One PID lap on the ground-truth car, as `cape rollout` writes it."""
    out = tmp_path_factory.mktemp("identity-run") / "truth" / "pid" / "eta0" / "seed0"
    made = cape(*rollout_args(setup, out)[1:])
    assert made.returncode == 0, made.stderr
    return {"out": out}


@FAST
@given(kp=st.floats(0.1, 10.0).filter(lambda k: abs(k - 2.2) > 1e-9))
def test_a_run_is_not_replaced_by_the_same_run_with_other_settings(
    setup: dict, run: dict, tmp_path_factory: pytest.TempPathFactory, kp: float
) -> None:
    """The same plant, controller, η and seed with another heading gain into a run's folder:
    refused (issue 53 found a hand run with heading.kp 0.5 entering the tables)."""
    cfg = copy.deepcopy(setup["cfg"])
    cfg["controllers"]["pid"]["heading"]["kp"] = kp
    config = tmp_path_factory.mktemp("gains") / "config.yaml"
    config.write_text(yaml.safe_dump(cfg))
    kept = _bytes(run["out"], ("metrics.json", "timing.json"))
    refused = cape(*rollout_args(setup, run["out"], config=config)[1:])
    one_message(refused, "holds run truth/", "[settings ", "not run truth/", "nothing was changed")
    assert _bytes(run["out"], ("metrics.json", "timing.json")) == kept


def test_the_same_run_again_is_its_own_output(setup: dict, run: dict) -> None:
    again = cape(*rollout_args(setup, run["out"])[1:])
    assert again.returncode == 0, again.stderr


@pytest.mark.parametrize("change", ["another draw", "other data"])
def test_a_table_is_not_replaced_by_one_made_from_other_inputs(
    setup: dict, datasets: dict, tmp_path: Path, change: str
) -> None:
    """Table 1 of draw 0 over-written by one of draw 1's network, or of another data set:
    refused (issue 53 found table 4 replaced by a hand `cape openloop`)."""
    models = tmp_path / "models"
    for r in (0, 1):
        assert main(["train", "--model", "dpm", "--replicate", str(r), "--data", str(setup["data"]),
                     "--out", str(models / f"rep{r}" / "dpm"), "--epochs", "1", "--seed", str(r),
                     "--config", str(setup["config"])]) == 0  # fmt: skip
    data = tmp_path / "mobil.npz"
    np.savez(data, **datasets["ETHZMobil"])
    table = tmp_path / "tables" / "table01_model_complexity.md"
    command = ["complexity", "--out", str(table), "--config", str(setup["config"])]
    made = cape(*command, "--model", f"dpm={models / 'rep0' / 'dpm'}", "--data", str(data))
    assert made.returncode == 0, made.stderr
    kept = table.read_bytes()
    if change == "another draw":
        other = ["--model", f"dpm={models / 'rep1' / 'dpm'}", "--data", str(data)]
    else:
        shifted = {k: v for k, v in datasets["ETHZMobil"].items()}
        shifted["time"] = shifted["time"] + 1.0
        np.savez(tmp_path / "other.npz", **shifted)
        other = ["--model", f"dpm={models / 'rep0' / 'dpm'}", "--data", str(tmp_path / "other.npz")]
    one_message(cape(*command, *other), "holds complexity table of dpm draw 0 [", "nothing was")
    assert table.read_bytes() == kept
    again = cape(*command, "--model", f"dpm={models / 'rep0' / 'dpm'}", "--data", str(data))
    assert again.returncode == 0, again.stderr  # the same inputs: its own output


@pytest.mark.parametrize("content", ["my notes\n", "{}", '{"kind": 1}', "[]", "\x00\xff"])
def test_a_users_file_named_like_an_owner_record_is_never_overwritten(
    tmp_path: Path, content: str
) -> None:
    """An owner record is recognised by its content, not its name: a file of the user's
    called `.t.md.owner` makes the claim of `t.md` fail, and stays as it was."""
    from cape.errors import CapeError
    from cape.storage.ownership import Output, claimed

    record = tmp_path / ".t.md.owner"
    record.write_bytes(content.encode("utf-8", "surrogateescape"))
    with (
        pytest.raises(CapeError, match=r"not an owner record CAPE wrote.*rename"),
        claimed([Output(tmp_path / "t.md", "table")], "test"),
    ):
        pass
    assert record.read_bytes() == content.encode("utf-8", "surrogateescape")
    assert not (tmp_path / "t.md").exists()


def test_a_users_owner_named_file_stops_the_real_command(setup: dict, tmp_path: Path) -> None:
    """Through the real `cape`: the issue's `cape openloop --out out/t.md` case, with a command
    that needs no trained model (`cape plot-tracks` claims its figure the same way)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / ".t.png.owner").write_text("mine\n")
    result = cape("plot-tracks", "--data", f"ETHZ={setup['data']}", "--out", str(out / "t.png"),
                  "--config", str(setup["config"]))  # fmt: skip
    one_message(result, ".t.png.owner", "not an owner record CAPE wrote")
    assert (out / ".t.png.owner").read_text() == "mine\n"
    assert sorted(p.name for p in out.iterdir()) == [".t.png.owner"]


def test_a_table_of_runs_is_not_replaced_by_one_of_other_runs(
    setup: dict, run: dict, tmp_path: Path
) -> None:
    other = tmp_path / "truth" / "pid" / "eta0" / "seed1"
    made = cape(*rollout_args(setup, other, seed="1")[1:])
    assert made.returncode == 0, made.stderr
    tables = ["--out", str(tmp_path / "runs.parquet"), "--summary", str(tmp_path / "cells.parquet"),
              "--config", str(setup["config"])]  # fmt: skip
    first = cape("aggregate", str(run["out"] / "metrics.json"), *tables)
    assert first.returncode == 0, first.stderr
    kept = (tmp_path / "runs.parquet").read_bytes()
    refused = cape("aggregate", str(other / "metrics.json"), *tables)
    one_message(refused, "holds table of runs of 1 runs [", "nothing was changed")
    assert (tmp_path / "runs.parquet").read_bytes() == kept
    again = cape("aggregate", str(run["out"] / "metrics.json"), *tables)
    assert again.returncode == 0, again.stderr


def test_an_output_recorded_before_identities_is_refused_saying_so(tmp_path: Path) -> None:
    """An owner record from before records had a format names a table with no identity: what
    it holds cannot be told from it, and the refusal says so (it read "holds table of runs,
    not table of runs of 61 runs"); deleted, the output is written."""
    from cape.errors import CapeError
    from cape.storage.ownership import Output, claimed

    out = tmp_path / "runs.parquet"
    out.write_bytes(b"old table")
    (tmp_path / ".runs.parquet.owner").write_text(
        json.dumps({"kind": "table of runs", "identity": "", "written_by": "cape aggregate"})
    )
    new = Output(out, "table of runs", "of 61 runs [74e2]")
    with (
        pytest.raises(CapeError, match="an earlier CAPE recorded without what made it"),
        claimed([new], "test"),
    ):
        pass
    assert out.read_bytes() == b"old table"
    out.unlink()
    with claimed([new], "test"):
        out.write_bytes(b"new table")
    record = json.loads((tmp_path / ".runs.parquet.owner").read_text())
    assert record["format"] == "cape-owner/1" and record["identity"] == "of 61 runs [74e2]"
