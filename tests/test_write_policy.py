"""One write policy, one way to read a file, nothing dropped without a word (docs/trust.md):
the examples of issue 43, each through the real ``cape`` command. Each failed before: a
user's file or another command's output replaced, a value dropped in silence, or a traceback."""

from __future__ import annotations

import fcntl
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from commands import cape, one_message, rollout, rollout_args


def _openloop(setup: dict, trained: dict, *out: Path) -> subprocess.CompletedProcess:
    outs = [a for p in out for a in ("--out", str(p))]
    return cape("openloop", "--model", f"dpm={trained['plain']}", "--train-data",
                str(setup["data"]), "--test-data", str(setup["data"]), *outs,
                "--config", str(setup["config"]))  # fmt: skip


# --- destroys ---------------------------------------------------------------------------------
def test_a_table_never_replaces_a_users_file(setup: dict, trained: dict, tmp_path: Path) -> None:
    notes = tmp_path / "notes.md"
    notes.write_text("my notes")
    one_message(_openloop(setup, trained, notes), str(notes), "CAPE did not write")
    assert notes.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.md"]  # no owner record left


def test_a_table_never_replaces_another_table(setup: dict, trained: dict, tmp_path: Path) -> None:
    table = tmp_path / "table.md"
    made = cape("complexity", "--model", f"dpm={trained['plain']}", "--data", str(setup["data"]),
                "--out", str(table), "--config", str(setup["config"]))  # fmt: skip
    assert made.returncode == 0, made.stderr
    before = table.read_bytes()
    one_message(_openloop(setup, trained, table), "holds complexity table", "open-loop error")
    assert table.read_bytes() == before
    again = _openloop(setup, trained, tmp_path / "openloop.md")  # its own: replaced
    assert again.returncode == 0, again.stderr
    assert _openloop(setup, trained, tmp_path / "openloop.md").returncode == 0


def test_a_network_never_replaces_another_models(trained: dict, tmp_path: Path) -> None:
    out = tmp_path / "network.npz"  # not the model folder's own network.npz
    first = cape("export-network", "--model", f"dpm={trained['plain']}", "--out", str(out))
    assert first.returncode == 0, first.stderr
    before = out.read_bytes()
    other = cape("export-network", "--model", f"dpm={trained['rep1']}", "--out", str(out))
    one_message(other, "holds network dpm [", "not network dpm of replicate 1 [")
    assert out.read_bytes() == before
    same = cape("export-network", "--model", f"dpm={trained['plain']}", "--out", str(out))
    assert same.returncode == 0, same.stderr


def test_a_run_never_replaces_another_runs_folder(setup: dict, tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert rollout(setup, out).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    one_message(rollout(setup, out, controller="rise"), "holds run truth/rep0/truth/truth/pid",
                "nothing was changed")  # fmt: skip
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_two_writers_of_one_output_cannot_both_win(setup: dict, tmp_path: Path) -> None:
    """Another writer holds the output (its owner record locked): refused at once."""
    from cape.storage.ownership import owner_record

    out = tmp_path / "run"
    record = owner_record(out)
    with open(record, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        one_message(rollout(setup, out), "another command is writing it right now")
    assert not out.exists()
    assert rollout(setup, out).returncode == 0  # released: the next writer goes ahead


def test_file_outputs_are_checked_too(setup: dict, tmp_path: Path) -> None:
    mine = tmp_path / "mine.npz"
    mine.write_bytes(b"mine")
    result = cape("data", "--track", "ETHZ", "--out", str(mine), "--config", str(setup["config"]))
    one_message(result, str(mine), "CAPE did not write")
    assert mine.read_bytes() == b"mine"


# --- silent -----------------------------------------------------------------------------------
def test_a_rescue_cpu_limit_beyond_the_os_is_refused(setup: dict, tmp_path: Path) -> None:
    cfg = json.loads(json.dumps(setup["cfg"]))
    cfg["controllers"]["nmpc"]["fatrop"]["cpu_s"] = 1.0e19
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    result = cape(*rollout_args(setup, tmp_path / "run", config=path, controller="nmpc")[1:])
    one_message(result, "cpu_s", "3600")
    assert not (tmp_path / "run").exists()


def test_a_rescue_workers_own_error_is_told_not_counted_as_a_limit() -> None:
    from cape.controllers.guard import Guarded, WorkerError

    def broken(_request: object) -> object:
        raise OverflowError("cannot convert float infinity to integer")

    guarded = Guarded(broken, cpu_s=5.0)
    with pytest.raises(WorkerError, match="OverflowError"):
        guarded(1)
    assert guarded.limited == 0
    assert Guarded(lambda r: r + 1, cpu_s=5.0)(1) == 2


@pytest.mark.parametrize("place", ["/", "."])
def test_train_never_writes_into_root_or_the_working_folder(
    setup: dict, tmp_path: Path, place: str
) -> None:
    (tmp_path / "mine.txt").write_text("mine")
    missing = str(tmp_path / "missing.npz")  # were it not refused first, nothing would train
    result = cape("train", "--model", "dpm", "--data", missing, "--out", place,
                  "--epochs", "1", "--config", str(setup["config"]), cwd=tmp_path)  # fmt: skip
    one_message(result, "never an output")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]
    assert not Path("/model.pt").exists()


def test_a_plant_is_bounded_by_its_models_own_training_data(
    setup: dict, trained: dict, datasets: dict, tmp_path: Path
) -> None:
    test_track = tmp_path / "ethzmobil.npz"
    np.savez(test_track, **datasets["ETHZMobil"])
    args = rollout_args(setup, tmp_path / "run", plant="dpm", study="learned")[1:]
    args[args.index("--training-data") + 1] = str(test_track)
    models = ["--model", f"dpm={trained['plain']}"]
    one_message(cape(*args, *models), "is not the data set the plant's model was trained on")
    right = rollout_args(setup, tmp_path / "run", plant="dpm", study="learned")[1:]
    made = cape(*right, *models)
    assert made.returncode == 0, made.stderr
    timing = json.loads((tmp_path / "run" / "timing.json").read_text())
    digest = hashlib.sha256(Path(setup["data"]).read_bytes()).hexdigest()
    assert timing["envelope_data"] == {"path": str(setup["data"]), "sha256": digest}


def test_a_model_named_twice_is_refused(setup: dict, trained: dict, tmp_path: Path) -> None:
    args = rollout_args(setup, tmp_path / "run", plant="dpm", study="learned")[1:]
    twice = ["--model", f"dpm={trained['plain']}", "--model", f"dpm={trained['rep1']}"]
    one_message(cape(*args, *twice), "names 'dpm' a second time")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("key", ["label", "color"])
def test_two_models_drawn_alike_are_refused(setup: dict, tmp_path: Path, key: str) -> None:
    cfg = json.loads(json.dumps(setup["cfg"]))
    cfg["models"]["ddm"][key] = cfg["models"]["dpm"][key].upper()
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    one_message(rollout(setup, tmp_path / "run", config=path), f"models.dpm.{key}", "the same as")


# --- tracebacks -------------------------------------------------------------------------------
def test_an_unknown_suffix_is_refused_before_any_work(
    setup: dict, trained: dict, tmp_path: Path
) -> None:
    one_message(_openloop(setup, trained, tmp_path / "table.txt"), ".csv, .md, .tex")


@pytest.mark.parametrize("command", ["train", "openloop"])
def test_an_npz_that_is_no_data_set_is_one_line(
    setup: dict, trained: dict, tmp_path: Path, command: str
) -> None:
    wrong = str(setup["raceline"])  # an .npz, but a raceline
    if command == "train":
        args = ["train", "--model", "dpm", "--data", wrong, "--out", str(tmp_path / "m")]
    else:
        args = ["openloop", "--model", f"dpm={trained['plain']}", "--train-data", wrong,
                "--test-data", wrong, "--out", str(tmp_path / "t.md")]  # fmt: skip
    one_message(cape(*args, "--config", str(setup["config"])), wrong, "'dstates'", "cape data")
    assert sorted(tmp_path.iterdir()) == []


def test_a_bad_value_in_config_json_is_one_line(setup: dict, tmp_path: Path) -> None:
    cfg = json.loads(json.dumps(setup["cfg"]))
    cfg["rollout"]["plant_envelope"] = "abc"
    args = rollout_args(setup, tmp_path / "run", plant="dpm", study="learned")[1:]
    at = args.index("--config")
    args[at : at + 2] = ["--config-json", json.dumps(cfg)]
    one_message(cape(*args), "--config-json", "rollout.plant_envelope")


def test_the_policy_module_runs_without_the_cli(tmp_path: Path) -> None:
    """``claimed`` for scripts: the record is written, and a failure leaves nothing."""
    code = (
        "import sys; from pathlib import Path; from cape.storage.ownership import Output, claimed\n"
        f"out = Path({str(tmp_path / 'x.json')!r})\n"
        "try:\n"
        "    with claimed([Output(out, 'thing', suffixes=('.json',))], 'test'):\n"
        "        raise RuntimeError('fails')\n"
        "except RuntimeError: pass\n"
        "print(sorted(p.name for p in out.parent.iterdir()))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.strip() == "[]", done.stderr


# --- the policy's own corners (cape.storage.ownership, in process) ----------------------------
def test_a_model_folder_is_the_models_only_by_its_owner_record(tmp_path: Path) -> None:
    """Snakemake deletes a training's model.pt, meta.json and loss.csv before it reruns it; the
    folder, with what other rules or a killed training left, stays the training's by its owner
    record. A folder of files without one is refused in one line that says what to do."""
    from cape.cli.models import _training_output
    from cape.errors import CapeError
    from cape.storage.ownership import claimed

    folder = tmp_path / "seed0"
    with claimed([_training_output(folder, "dpm")], "test"):
        folder.mkdir()
        (folder / "model.pt").write_bytes(b"x")
    (folder / "model.pt").unlink()
    (folder / "health.json").write_text("{}")
    (folder / "checkpoint-0123456789abcdef.pt").write_bytes(b"x")
    with claimed([_training_output(folder, "dpm")], "test"):
        pass
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "health.json").write_text("{}")
    with (
        pytest.raises(CapeError, match=r"no owner record.*CAPE replaces only what it wrote"),
        claimed([_training_output(tmp_path / "other", "dpm")], "test"),
    ):
        pass


def test_a_refusal_of_one_output_changes_no_other(tmp_path: Path) -> None:
    from cape.errors import CapeError
    from cape.storage.ownership import Output, claimed

    (tmp_path / "b.md").write_text("mine")
    outs = [Output(tmp_path / "a.md", "table"), Output(tmp_path / "b.md", "table", option="-o")]
    with pytest.raises(CapeError, match=r"b\.md"), claimed(outs, "test"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.md"]


def test_a_failure_leaves_no_empty_folder_and_no_record(tmp_path: Path) -> None:
    from cape.storage.ownership import Output, claimed

    out = tmp_path / "new" / "deeper" / "run"
    with pytest.raises(RuntimeError), claimed([Output(out, "run", "x", folder=True)], "test"):
        out.mkdir()
        raise RuntimeError("the lap failed")
    assert sorted(tmp_path.iterdir()) == []


def test_an_owner_record_is_never_followed_through_a_link(tmp_path: Path) -> None:
    from cape.errors import CapeError
    from cape.storage.ownership import Output, claimed, owner_record

    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    owner_record(tmp_path / "out.md").symlink_to(victim)
    with (
        pytest.raises(CapeError, match="not a plain file"),
        claimed([Output(tmp_path / "out.md", "table")], "test"),
    ):
        pass
    assert victim.read_text() == "keep"


def test_a_forked_worker_does_not_keep_the_lock(tmp_path: Path) -> None:
    from cape.controllers.guard import Guarded
    from cape.storage.ownership import Output, claim, release

    out = [Output(tmp_path / "run", "run", "x", folder=True)]
    claim(out, "test")
    worker = Guarded(lambda r: r, cpu_s=5.0)
    assert worker(3) == 3  # a worker forked while the output is held, still alive
    release()
    claim(out, "test")  # the worker's copy of the descriptor holds no lock
    release()
    worker.close()


def test_a_file_system_without_locks_still_gets_its_outputs(tmp_path: Path, monkeypatch) -> None:
    """flock fails with ENOLCK on some cluster mounts: the outputs are written all the same."""
    import errno
    import fcntl

    from cape.storage.ownership import Output, claimed, owner_record

    def no_locks(_fd: int, _op: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    out = tmp_path / "t.md"
    with claimed([Output(out, "table")], "test"):
        out.write_text("x")
    assert json.loads(owner_record(out).read_text())["kind"] == "table"
