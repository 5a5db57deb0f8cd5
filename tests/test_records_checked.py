"""Records are checked, not trusted (issue 53): a training's health record is read field by
field for its type, `cape draw` decides each consulted training's verdict again from the
record's numbers and the training's files under the bar, refuses trainings given twice or out
of seed order, and a changed record or bar re-decides the draws in the workflow."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from commands import cape, one_message, snakemake
from conftest import workdir

from cape.errors import CapeError
from cape.training.outcome import read_outcome

TARGETS = [f"results/models/rep{r}/dpm/model.pt" for r in (0, 1)]


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The workflow's draws 0 and 1 of DPM (one epoch each), made by the real `snakemake`:
    trainings seed0 and seed1, their health records, the two draws."""
    work = workdir(tmp_path_factory.mktemp("records"))
    config = work / "config" / "config.yaml"
    cfg = yaml.safe_load(config.read_text())
    cfg["models"]["dpm"]["train"]["epochs"] = 1
    cfg["training"]["compile"]["enabled"] = False
    config.write_text(yaml.safe_dump(cfg))
    made = snakemake("--cores", "2", "-d", str(work), *TARGETS, timeout=600)
    assert made.returncode == 0, made.stdout[-3000:] + made.stderr[-3000:]
    return work


def _trainings(tree: Path, tmp_path: Path) -> list[Path]:
    """A copy of the tree's two trainings (seed 0, seed 1), to edit."""
    copies = []
    for seed in (0, 1):
        copy = tmp_path / "trainings" / f"seed{seed}"
        shutil.copytree(tree / "results" / "trainings" / "dpm" / f"seed{seed}", copy)
        copies.append(copy)
    return copies


def _draw(out: Path, replicate: int, *folders: Path, config: Path | None = None):
    """`cape draw` of DPM under the cap 2, with config/config.yaml's bar (none for DPM, as in
    the tree's config) unless ``config`` is given."""
    trainings = [a for f in folders for a in ("--training", str(f))]
    options = ["--config", str(config)] if config else []
    return cape("draw", "--model", "dpm", "--replicate", str(replicate), "--max-trainings", "2",
                *trainings, "--out", str(out), *options)  # fmt: skip


def _edit(record: Path, **fields: object) -> None:
    """Edit a record and seal it again (a deliberate forgery the checksum cannot tell): what
    the checks of its fields and verdict must catch on their own."""
    from cape.storage.integrity import sealed_record

    data = json.loads(record.read_text())
    data.update(fields)
    record.write_text(json.dumps(sealed_record(data)))


def test_a_health_record_field_of_the_wrong_type_is_refused(tree: Path, tmp_path: Path) -> None:
    """`"trained": "no"` was a pass (`bool("no")`): through `cape draw` it is refused in one
    line naming the file, the field and the fix, nothing written; every other field is
    checked for its JSON type too."""
    seed0, _ = _trainings(tree, tmp_path)
    record = seed0 / "health.json"
    honest = record.read_text()
    _edit(record, trained="no")
    out = tmp_path / "draw"
    one_message(_draw(out, 0, seed0), str(record), "field 'trained' is the string \"no\"",
                "rebuild it: delete it and rerun snakemake")  # fmt: skip
    assert not out.exists()
    from cape.storage.integrity import sealed_record

    good = {k: v for k, v in json.loads(honest).items() if k != "sha256"}
    cases = {
        "seed": True,
        "format": "1",
        "reasons": "stalled",
        "val_rmse": {"vx": "0.1", "vy": 0.1, "omega": 0.1},
        "weights_sha256": "ab",
    }
    for name, value in cases.items():
        record.write_text(json.dumps(sealed_record({**good, name: value})))
        with pytest.raises(CapeError, match=rf"field '{name}' is .*rebuild it") as refused:
            read_outcome(record)
        assert str(record) in str(refused.value)
    for bad in (
        {**good, "reasons": [1]},
        {**good, "val_rmse": {"vx": 0.1, "vy": 0.1}},
        {k: v for k, v in good.items() if k != "seed"},
        {**good, "verdict": "ok"},
    ):
        record.write_text(json.dumps(sealed_record(bad)))
        with pytest.raises(CapeError, match="not a training's health record"):
            read_outcome(record)
    record.write_text(json.dumps(good))  # edited, its checksum dropped: a record no more
    with pytest.raises(CapeError, match=r"carries no checksum.*rebuild it"):
        read_outcome(record)
    record.write_text(honest.replace('"trained": true', '"trained": true, "trained": false'))
    with pytest.raises(CapeError, match="field 'trained' is given twice"):
        read_outcome(record)
    record.write_text(honest)
    assert read_outcome(record).trained and read_outcome(record).val_rmse["vx"] > 0


def test_a_verdict_that_does_not_follow_from_its_numbers_is_refused(
    tree: Path, tmp_path: Path
) -> None:
    """A failed training (DPM under a bar it cannot meet) whose record is hand-edited to
    `"trained": true` was made draw 0; a working one edited to `false` was skipped. The draw
    decides each consulted verdict again from the record's RMSE and loss.csv under the bar,
    and refuses the record in one line; the honest records draw as before."""
    # a working training (DPM has no bar in config/config.yaml) edited to failed: refused,
    # not skipped
    seed0, seed1 = _trainings(tree, tmp_path / "working")
    _edit(seed0 / "health.json", trained=False, reasons=["stalled"])
    one_message(
        _draw(tmp_path / "skipped", 0, seed0, seed1),
        f"{seed0 / 'health.json'}: says failed (stalled), but",
        "its verdict does not follow from its numbers; delete it and rerun snakemake",
    )
    assert not (tmp_path / "skipped").exists()
    # failed trainings, under a bar DPM cannot meet
    seed0, seed1 = _trainings(tree, tmp_path)
    strict = tmp_path / "strict.yaml"
    cfg = yaml.safe_load((tree / "config" / "config.yaml").read_text())
    cfg["training"]["health"]["models"] = ["dpm"]
    cfg["training"]["health"]["val_rmse_max"] = {"vx": 1e-9, "vy": 1e-9, "omega": 1e-9}
    strict.write_text(yaml.safe_dump(cfg))
    data = tree / "results" / "data" / "DYN-PP-ETHZ.npz"
    for folder in (seed0, seed1):
        (folder / "health.json").unlink()
        checked = cape("check-training", "--model", f"dpm={folder}", "--data", str(data),
                       "--out", str(folder / "health.json"), "--config", str(strict))  # fmt: skip
        assert checked.returncode == 0, checked.stderr
        assert not read_outcome(folder / "health.json").trained
    out = tmp_path / "draw"
    honest = _draw(out, 0, seed0, seed1, config=strict)
    assert honest.returncode == 0, honest.stderr  # both failed: the cap's stand-in, flagged
    assert not json.loads((out / "meta.json").read_text())["draw"]["trained"]
    record = seed0 / "health.json"
    _edit(record, trained=True, reasons=[])
    forged = _draw(tmp_path / "forged", 0, seed0, seed1, config=strict)
    one_message(
        forged,
        f"{record}: says trained, but its numbers and",
        "its verdict does not follow from its numbers; delete it and rerun snakemake",
    )
    assert not (tmp_path / "forged").exists()


def test_every_consulted_record_is_about_its_own_weights(tree: Path, tmp_path: Path) -> None:
    """Draw 1 consults trainings 0 and 1; seed0's record replaced by seed1's (its seed edited
    to 0) judged other weights, and only the chosen training's record was compared."""
    seed0, seed1 = _trainings(tree, tmp_path)
    from cape.storage.integrity import sealed_record

    other = json.loads((seed1 / "health.json").read_text())
    (seed0 / "health.json").write_text(json.dumps(sealed_record({**other, "seed": 0})))
    one_message(
        _draw(tmp_path / "draw", 1, seed0, seed1),
        f"{seed0 / 'health.json'}: is about other weights than {seed0 / 'model.pt'}",
    )


def test_trainings_given_twice_or_out_of_seed_order_are_refused(tree: Path, tmp_path: Path) -> None:
    """`--training A --training A` made draw 1 draw 0's network, and seeds out of order another
    training than the (r + 1)-th that works: refused in one line, nothing written."""
    seed0, seed1 = _trainings(tree, tmp_path)
    twin = tmp_path / "twin"
    shutil.copytree(seed0, twin)
    out = tmp_path / "draw"
    cases = {
        (seed0, seed0): f"--training {seed0}: given twice",
        (seed0, tmp_path / "trainings" / ".." / "trainings" / "seed0"): "given twice",
        (seed0, twin): f"--training {twin}: holds the weights of --training {seed0}",
        (seed1, seed0): f"--training {seed0}: seed 0 does not follow seed 1",
    }
    for folders, message in cases.items():
        one_message(_draw(out, 1, *folders), message)
        assert not out.exists()
    made = _draw(out, 1, seed0, seed1)
    assert made.returncode == 0, made.stderr
    assert json.loads((out / "meta.json").read_text())["seed"] == 1


def _planned(result) -> set[tuple[str, str]]:
    """(rule, wildcards) of each job a dry run plans."""
    jobs, rule = set(), None
    for line in result.stdout.splitlines():
        words = line.split()
        if len(words) == 2 and words[1].endswith(":") and words[0].endswith(("rule", "checkpoint")):
            rule = words[1][:-1]
        elif rule and line.strip().startswith("wildcards:"):
            jobs.add((rule, line.split(":", 1)[1].strip()))
            rule = None
    return jobs


def test_a_changed_record_or_bar_re_decides_the_draws(tree: Path, tmp_path: Path) -> None:
    """seed0's record hand-edited to `"trained": false`: draw 1 now needs training 2's record,
    not yet made, and `snakemake -n` planned nothing for it (a checkpoint target among a
    job's inputs exempts it from every rerun trigger). Now the dry run plans both draws and
    training 2; the real run refuses the record (the draw checks it); deleted, the workflow
    rebuilds it and both draws are as before. A changed bar plans the checks and draws
    again."""
    work = tmp_path / "work"
    shutil.copytree(tree, work, symlinks=True)
    record = work / "results" / "trainings" / "dpm" / "seed0" / "health.json"
    honest = record.read_text()
    run = ("--cores", "2", "-d", str(work), *TARGETS)
    nothing = snakemake("-n", *run)
    assert "Nothing to be done" in nothing.stdout + nothing.stderr, nothing.stdout[-2000:]

    _edit(record, trained=False, reasons=["stalled"])
    dry = snakemake("-n", *run)
    assert dry.returncode == 0, dry.stdout[-3000:] + dry.stderr[-3000:]
    planned = _planned(dry)
    assert {("draw", "replicate=0, model=dpm"), ("draw", "replicate=1, model=dpm"),
            ("train", "model=dpm, training_seed=2")} <= planned, dry.stdout[-3000:]  # fmt: skip

    refused = snakemake(*run, timeout=600)
    assert refused.returncode != 0
    log = (work / "results" / "logs" / "draw" / "rep0" / "dpm.log").read_text()
    assert "its verdict does not follow from its numbers; delete it and rerun snakemake" in log

    record.unlink()
    again = snakemake(*run, timeout=600)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert record.read_text() == honest
    for r in (0, 1):
        meta = json.loads(
            (work / "results" / "models" / f"rep{r}" / "dpm" / "meta.json").read_text()
        )
        assert meta["seed"] == r and meta["draw"]["trained"]
    assert "Nothing to be done" in snakemake("-n", *run).stdout

    stricter = work / "config" / "stricter.yaml"
    stricter.write_text(yaml.safe_dump({"training": {"health": {"stall": {"min_drop": 0.5}}}}))
    bar = _planned(snakemake("-n", *run, "--configfile", str(stricter)))
    assert {("draw", "replicate=0, model=dpm"), ("draw", "replicate=1, model=dpm"),
            ("training_health", "model=dpm, training_seed=0")} <= bar, bar  # fmt: skip


@pytest.mark.parametrize("edit", ["verdict", "string", "not json"])
def test_a_record_edited_by_hand_stops_its_draw_in_one_line(
    tree: Path, tmp_path: Path, edit: str
) -> None:
    """A sealed record edited in place (its checksum left as it was), or one that is no
    record: the planner does not print a traceback (it printed an InputFunctionException with
    7 `File` lines); it plans the draw, whose log says what is wrong and the fix."""
    work = tmp_path / "work"
    shutil.copytree(tree, work, symlinks=True)
    record = work / "results" / "trainings" / "dpm" / "seed0" / "health.json"
    text = record.read_text()
    edited = {"verdict": text.replace('"trained": true', '"trained": false'),
              "string": text.replace('"trained": true', '"trained": "no"'),
              "not json": "trained: yes\n"}[edit]  # fmt: skip
    assert edited != text
    record.write_text(edited)
    run = ("--cores", "2", "-d", str(work), *TARGETS)
    dry = snakemake("-n", *run)
    out = dry.stdout + dry.stderr
    assert dry.returncode == 0 and 'File "' not in out and "Traceback" not in out, out[-3000:]
    assert ("draw", "replicate=0, model=dpm") in _planned(dry)
    failed = snakemake(*run, timeout=600)
    assert failed.returncode != 0
    assert 'File "' not in failed.stdout + failed.stderr
    log = (work / "results" / "logs" / "draw" / "rep0" / "dpm.log").read_text()
    named = "results/trainings/dpm/seed0/health.json"
    assert named in log and "delete it and rerun snakemake" in log, log
    assert record.read_text() == edited  # never rewritten behind the user's back


def test_outputs_made_from_one_training_are_not_replaced_by_anothers(
    tree: Path, tmp_path: Path
) -> None:
    """The workflow's draw 0 re-made by hand from another training or under another cap, a
    training's health record written from another training, a draw's frozen Φ from another
    draw's weights: each refused in one line, the output as it was (they were accepted)."""
    work = tmp_path / "work"
    shutil.copytree(tree, work, symlinks=True)
    trainings = work / "results" / "trainings" / "dpm"
    models = work / "results" / "models"
    draw0 = models / "rep0" / "dpm"
    kept = (draw0 / "meta.json").read_bytes()
    for given, cap in (([trainings / "seed1"], "2"), ([trainings / "seed0"], "3")):
        options = [a for f in given for a in ("--training", str(f))]
        other = cape("draw", "--model", "dpm", "--replicate", "0", *options, "--max-trainings",
                     cap, "--out", str(draw0))  # fmt: skip
        one_message(other, "holds trained model dpm of replicate 0 [seeds 0", "nothing was")
    assert (draw0 / "meta.json").read_bytes() == kept

    data = work / "results" / "data" / "DYN-PP-ETHZ.npz"
    record = trainings / "seed1" / "health.json"
    honest = record.read_bytes()
    check = cape("check-training", "--model", f"dpm={trainings / 'seed0'}", "--data", str(data),
                 "--out", str(record))  # fmt: skip
    one_message(check, f"--out {record}: holds health record dpm [", "nothing was changed")
    assert record.read_bytes() == honest

    frozen = draw0 / "frozen_phi.json"
    made = cape("freeze", "--model", f"dpm={draw0}", "--data", str(data), "--out", str(frozen))
    assert made.returncode == 0, made.stderr
    mine = frozen.read_bytes()
    other = cape("freeze", "--model", f"dpm={models / 'rep1' / 'dpm'}", "--data", str(data),
                 "--out", str(frozen))  # fmt: skip
    one_message(other, "holds frozen parameters dpm of replicate 0 [", "not frozen parameters "
                "dpm of replicate 1 [")  # fmt: skip
    assert frozen.read_bytes() == mine
