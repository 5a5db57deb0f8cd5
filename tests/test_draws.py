"""A model's draws are its trainings that work (SPEC §4, revision 5): which training each draw
is, in what order a workflow is asked for trainings, the cap, the failure rate's interval, and
`cape check-training` / `cape draw` on real folders."""

from __future__ import annotations

import copy
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from cape.errors import CapeError
from cape.training.draws import choose_training, deciding_cap
from cape.training.outcome import Outcome, read_outcome, reliability


def _outcomes(passes: str) -> dict[int, Outcome]:
    """'PFP…' → training k's outcome (seed 10 + k: seeds need not start at 0)."""
    return {
        k: Outcome(10 + k, c == "P", () if c == "P" else ("bar",)) for k, c in enumerate(passes)
    }


def _asker(passes: str) -> tuple[list[int], object]:
    known = _outcomes(passes)
    asked: list[int] = []

    def outcome(k: int) -> Outcome:
        asked.append(k)
        return known[k]

    return asked, outcome


@pytest.mark.parametrize(
    ("passes", "draws"),
    [
        ("PPP", [0, 1, 2]),  # every training works: draw r is training r, as before
        ("PFPP", [0, 2, 3]),  # training 1 failed: replaced by the next seed
        ("FFPFPP", [2, 4, 5]),
    ],
)
def test_draw_r_is_the_r_plus_first_training_that_works(passes: str, draws: list[int]) -> None:
    for r, expected in enumerate(draws):
        _, outcome = _asker(passes)
        choice = choose_training(r, 6, outcome)
        assert (choice.index, choice.trained, choice.cap_reached) == (expected, True, False)
        assert [o.seed for o in choice.consulted] == [10 + k for k in range(expected + 1)]


def test_a_draws_first_question_is_its_own_training_so_draws_are_planned_side_by_side() -> None:
    """Asked of a workflow in which nothing is known yet, draw r asks first for training r (the
    earliest that could be its own), so R draws plan R trainings at once rather than one."""

    class PendingError(Exception):
        pass

    for r in range(4):
        first: list[int] = []

        def outcome(k: int, first: list[int] = first) -> Outcome:
            first.append(k)
            raise PendingError

        with pytest.raises(PendingError):
            choose_training(r, 8, outcome)
        assert first == [r]
    # once training 1 is known to have failed, draw 2 asks for training 3 next (its earliest)
    known = _outcomes("PF")
    asked: list[int] = []

    def partly(k: int) -> Outcome:
        asked.append(k)
        if k in known:
            return known[k]
        raise PendingError

    with pytest.raises(PendingError):
        choose_training(2, 8, partly)
    assert asked == [2]  # training 2 first: unknown
    known[2] = Outcome(12, True)
    asked.clear()
    with pytest.raises(PendingError):
        choose_training(2, 8, partly)
    assert asked[-1] == 3 and set(asked[:-1]) <= {0, 1, 2}


def test_the_deciding_cap_makes_the_same_choice_for_every_history() -> None:
    """For every pass/fail history of up to 8 trainings, every draw and every cap: the draw
    chosen under its deciding cap is the same (index, trained, trainings consulted, cap
    reached), and a draw that found its training keeps it under any larger cap."""
    import itertools

    for n in range(1, 9):
        for passes in itertools.product((True, False), repeat=n):
            outcomes = [Outcome(k, ok) for k, ok in enumerate(passes)]
            for cap in range(1, n + 1):
                for r in range(cap):
                    choice = choose_training(r, cap, outcomes.__getitem__)
                    least = deciding_cap(choice, cap)
                    assert least <= cap
                    assert choose_training(r, least, outcomes.__getitem__) == choice
                    if not choice.cap_reached:
                        for larger in range(cap, n + 1):
                            assert choose_training(r, larger, outcomes.__getitem__) == choice


def test_at_the_cap_the_failed_trainings_stand_in_flagged() -> None:
    """One training of four works (cap 4, three draws): draw 0 is it, draws 1 and 2 the first
    failed trainings in seed order, flagged as failed with the cap reached."""
    got = []
    for r in range(3):
        _, outcome = _asker("FPFF")
        choice = choose_training(r, 4, outcome)
        got.append((choice.index, choice.trained, choice.cap_reached))
    assert got == [(1, True, False), (0, False, True), (2, False, True)]
    with pytest.raises(CapeError, match=r"training\.max_trainings is 2"):
        choose_training(2, 2, _asker("PP")[1])


def test_the_failure_rate_has_its_clopper_pearson_interval() -> None:
    """4 failures of 9 trainings: 0.444, exact 95 % interval [0.137, 0.788] (the Clopper–Pearson
    bounds, beta quantiles: B(0.025; 4, 6) and B(0.975; 5, 5))."""
    from scipy import stats

    rel = reliability([Outcome(s, s not in (1, 2, 5, 7)) for s in range(9)])
    assert (rel.tried, rel.failed) == (9, 4)
    assert rel.rate == pytest.approx(4 / 9)
    assert rel.low == pytest.approx(stats.beta.ppf(0.025, 4, 6))
    assert rel.high == pytest.approx(stats.beta.ppf(0.975, 5, 5))
    assert rel.low == pytest.approx(0.137, abs=1e-3) and rel.high == pytest.approx(0.788, abs=1e-3)
    none = reliability([Outcome(0, True), Outcome(1, True)])
    assert none.rate == 0 and none.low == 0 and none.high == pytest.approx(1 - 0.025**0.5)
    assert np.isnan(reliability([]).rate)


def test_a_health_record_that_is_not_one_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "health.json"
    path.write_text("{")
    with pytest.raises(CapeError, match=r"health\.json: unreadable"):
        read_outcome(path)
    path.write_text(json.dumps({"format": 1, "seed": 3}))
    with pytest.raises(CapeError, match="carries no checksum"):
        read_outcome(path)
    from cape.storage.integrity import sealed_record

    path.write_text(json.dumps(sealed_record({"format": 1, "seed": 3})))
    with pytest.raises(CapeError, match="not a training's health record"):
        read_outcome(path)
    record = Outcome(3, False, ("stalled",), {"vx": 1e-3, "vy": 2e-3, "omega": 3e-3}, "ab" * 32)
    path.write_text(json.dumps(record.to_dict()))
    assert read_outcome(path) == record


def cape(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["cape", *args], capture_output=True, text=True, timeout=300)


@pytest.fixture
def config_file(config: dict, track_dir: Path, tmp_path: Path) -> Path:
    cfg = copy.deepcopy(config)
    cfg["tracks"]["dir"] = cfg["tracks"]["mirror"] = str(track_dir)
    cfg["training"]["compile"]["enabled"] = False  # one epoch: compiling costs more
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_check_training_and_draw_through_the_command(
    config_file: Path, datasets: dict, tmp_path: Path
) -> None:
    """Two one-epoch DPM trainings through the real `cape`: `check-training` writes each one's
    health (DPM has no bar; one epoch is too short to stall, so both work) and `cape draw`
    makes draw 1 from the second, its meta.json naming the draw, its weights the training's;
    a draw folder of another replicate is refused, nothing changed."""
    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    config = ["--config", str(config_file)]
    folders = []
    for seed in (0, 1):
        folder = tmp_path / "trainings" / "dpm" / f"seed{seed}"
        made = cape("train", "--model", "dpm", "--seed", str(seed), "--data", str(data),
                    "--out", str(folder), "--epochs", "1", *config)  # fmt: skip
        assert made.returncode == 0, made.stderr
        health = cape("check-training", "--model", f"dpm={folder}", "--data", str(data),
                      "--out", str(folder / "health.json"), *config)  # fmt: skip
        assert health.returncode == 0, health.stderr
        assert read_outcome(folder / "health.json").trained
        folders.append(folder)
    out = tmp_path / "models" / "rep1" / "dpm"
    args = ["draw", "--model", "dpm", "--replicate", "1", "--max-trainings", "2"]
    trainings = [a for f in folders for a in ("--training", str(f))]
    made = cape(*args, *trainings, "--out", str(out))
    assert made.returncode == 0, made.stderr
    meta = json.loads((out / "meta.json").read_text())
    assert meta["replicate"] == 1 and meta["seed"] == 1 and meta["draw"]["index"] == 1
    assert [t["seed"] for t in meta["draw"]["trainings"]] == [0, 1]
    assert (out / "model.pt").read_bytes() == (folders[1] / "model.pt").read_bytes()
    before = (out / "meta.json").read_bytes()
    other = cape(*args[:4], "0", *args[5:], *trainings, "--out", str(out))
    assert other.returncode == 2, other.stderr
    assert "holds trained model dpm of replicate 1 [seeds" in other.stderr
    assert "not trained model dpm of replicate 0 [seeds" in other.stderr
    assert (out / "meta.json").read_bytes() == before
    short = cape(*args, "--training", str(folders[0]), "--out", str(tmp_path / "x"))
    assert short.returncode == 2 and "needs training 1's health" in short.stderr
