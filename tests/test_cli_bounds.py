"""Every numeric option of ``cape`` has the bounds of the config key it overrides, read from
the packaged schema (issue 53, item 5); an option with no config key has its own (a seed
NumPy's 32 bits, a draw below ``training.replicates``' maximum, a count of cores at least 1).

Generated values (Hypothesis) go through the command line in-process (``cape.cli.main``, whose
check comes before any work); a handful of edge values go through the real ``cape`` command in
a subprocess. A value outside its bounds: exit status 2, one line naming the option and the
bound, no traceback, no file made (no output, no owner record). A value at the edge of its
bounds: parsed, and the command goes on to fail on something else (a missing file).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cape import schemas
from cape.cli import build_parser, main
from cape.cli.common import Bound, check_bounds
from cape.errors import CapeError

FAST = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip
SCHEMA = yaml.safe_load(schemas.schema_bytes(schemas.CONFIG))
"""The schema read here on its own, not through cape.cli.common."""


def _key(path: str) -> dict:
    node = SCHEMA
    for part in path.split("."):
        node = node["additionalProperties"] if part == "*" else node["properties"][part]
    return node


@dataclass(frozen=True)
class Option:
    """A bounded option: ``least`` ≤ value ≤ ``most`` (``above`` < value: exclusive), what the
    refusal names (``names``) and the command that takes it (``argv``, its other arguments:
    files that do not exist, so a value that passes fails soon after)."""

    command: str
    flag: str
    kind: type
    least: float | None
    most: float | None
    names: str
    above: float | None = None


def _schema_option(command: str, flag: str, key: str) -> Option:
    node = _key(key)
    types = node["type"] if isinstance(node["type"], list) else [node["type"]]
    return Option(command, flag, int if "integer" in types else float, node.get("minimum"),
                  node.get("maximum"), key.replace("*", "<name>"),
                  node.get("exclusiveMinimum"))  # fmt: skip


DRAWS = _key("training.replicates")["maximum"]
OPTIONS = [
    _schema_option("train", "--epochs", "models.*.train.epochs"),
    _schema_option("train", "--seed", "training.seed"),
    _schema_option("train", "--threads", "training.threads"),
    _schema_option("train", "--checkpoint-every", "training.checkpoint_every"),
    Option("train", "--replicate", int, 0, DRAWS - 1, "training.replicates"),
    Option("draw", "--replicate", int, 0, DRAWS - 1, "training.replicates"),
    _schema_option("draw", "--max-trainings", "training.max_trainings"),
    Option("rollout", "--seed", int, 0, 2**32 - 1, "32-bit"),
    Option("rollout", "--replicate", int, 0, DRAWS - 1, "training.replicates"),
    Option("aggregate", "--replicates", int, 0, DRAWS - 1, "training.replicates"),
    _schema_option("raceline", "--time-limit", "rollout.time_limit"),
    Option("question", "--cores", int, 1, 1_000_000, "cores"),
    Option("question", "--project-cores", int, 1, 1_000_000, "cores"),
]
IDS = [f"{o.command} {o.flag}" for o in OPTIONS]


def _argv(command: str, folder: Path) -> list[str]:
    """``command`` with its required arguments, every input missing (``--config`` too)."""
    missing = str(folder / "missing.yaml")
    return {
        "train": ["train", "--model", "dpm", "--data", str(folder / "none.npz"),
                  "--out", str(folder / "model"), "--config", missing],
        "draw": ["draw", "--model", "dpm", "--replicate", "0", "--training",
                 str(folder / "none"), "--max-trainings", "1", "--out", str(folder / "draw")],
        "rollout": ["rollout", "--plant", "truth", "--controller", "pid", "--eta", "0",
                    "--seed", "0", "--out", str(folder / "run"), "--config", missing],
        "aggregate": ["aggregate", "--out", str(folder / "runs.parquet"),
                      "--summary", str(folder / "summary.parquet"), "--config", missing],
        "raceline": ["raceline", "--track", "ETHZ", "--out", str(folder / "line.npz"),
                     "--config", missing],
        "question": ["question", "--dry-run", "--configfile", missing],
    }[command]  # fmt: skip


def _text(value: float) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def outside(option: Option) -> st.SearchStrategy[str]:
    """Values the option refuses: below, at an exclusive bound, above, non-finite."""
    parts = []
    if option.kind is int:
        if option.least is not None:
            parts.append(st.integers(max_value=int(option.least) - 1, min_value=-(2**70)))
        if option.most is not None:
            parts.append(st.integers(min_value=int(option.most) + 1, max_value=2**70))
    else:
        if option.least is not None:
            parts.append(st.floats(max_value=option.least, exclude_max=True, allow_nan=False))
        if option.above is not None:
            parts.append(st.floats(max_value=option.above, allow_nan=False))
        if option.most is not None:
            parts.append(st.floats(min_value=option.most, exclude_min=True, allow_nan=False))
        parts.append(st.sampled_from([math.nan, math.inf, -math.inf]))
    return st.one_of(parts).map(_text)


def inside(option: Option) -> st.SearchStrategy[str]:
    """Values the option accepts, its edges among them."""
    if option.kind is int:
        low, high = int(option.least), int(option.most)
        return st.one_of(st.sampled_from([low, high]), st.integers(low, high)).map(str)
    low = option.least if option.least is not None else option.above
    top = option.most if option.most is not None else 1e300
    edges = [top] + ([option.least] if option.least is not None else [math.ulp(0.0)])
    floats = st.floats(low, top, exclude_min=option.least is None, allow_nan=False)
    return st.one_of(st.sampled_from(edges), floats).map(_text)


def _refused(option: Option, value: str, err: str) -> None:
    """The one line a refusal is: the option, the value, the bound it crosses and where that
    is from."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    line = lines[0]
    assert line.startswith(f"cape {option.command}: error: {option.flag} "), err
    assert option.names in line, err
    number = option.kind(value)
    low = (f"of at least {option.least}" if option.least is not None
           else f"above {option.above}")  # fmt: skip
    if option.most is None:
        high = None
    elif option.names == "training.replicates":  # a draw: below the most draws
        high = f"below {int(option.most) + 1}"
    else:
        high = f"of at most {option.most}"
    if not math.isfinite(number):
        assert low in line and (high is None or high in line), err
    elif (option.least is not None and number < option.least) or (
        option.above is not None and number <= option.above
    ):
        assert low in line, err
    else:
        assert high is not None and high in line, err


# --- generated values, in-process -------------------------------------------------------------
def _run(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, err.getvalue()


@pytest.mark.parametrize("option", OPTIONS, ids=IDS)
@FAST
@given(data=st.data())
def test_a_value_outside_the_bounds_is_refused_before_any_work(
    option: Option, data: st.DataObject
) -> None:
    value = data.draw(outside(option), label="value")
    with tempfile.TemporaryDirectory() as folder:
        code, err = _run([*_argv(option.command, Path(folder)), f"{option.flag}={value}"])
        assert code == 2, err
        _refused(option, value, err)
        assert os.listdir(folder) == [], "a refusal left files (an owner record?)"


@pytest.mark.parametrize("option", OPTIONS, ids=IDS)
@FAST
@given(data=st.data())
def test_a_value_within_the_bounds_is_accepted(option: Option, data: st.DataObject) -> None:
    value = data.draw(inside(option), label="value")
    argv = [*_argv(option.command, Path("/nonexistent")), f"{option.flag}={value}"]
    args = build_parser().parse_args(argv)
    check_bounds(args)  # no CapeError
    given = getattr(args, option.flag[2:].replace("-", "_"))
    parsed = given[-1] if isinstance(given, list) else given
    assert parsed == option.kind(value)


def test_every_numeric_option_is_bounded() -> None:
    """No option of any command parses a number without a bound (a new ``type=int`` would)."""
    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.choices and isinstance(a.choices, dict)]
    unbounded = [f"cape {name} {a.option_strings}"
                 for name, p in sub.choices.items() for a in p._actions
                 if a.type in (int, float)]  # fmt: skip
    assert not unbounded
    bounded = {(name, a.option_strings[0]) for name, p in sub.choices.items()
               for a in p._actions if isinstance(a.type, Bound)}  # fmt: skip
    assert bounded == {(o.command, o.flag) for o in OPTIONS}


def test_the_bounds_follow_the_schema(monkeypatch: pytest.MonkeyPatch) -> None:
    """One source of truth: a schema with another maximum is another bound."""
    import copy

    changed = copy.deepcopy(schemas.load_schema(schemas.CONFIG))
    changed["properties"]["training"]["properties"]["threads"]["maximum"] = 8
    monkeypatch.setattr(schemas, "load_schema", lambda name: changed)
    args = build_parser().parse_args([*_argv("train", Path("/nonexistent")), "--threads", "9"])
    with pytest.raises(CapeError, match=r"--threads 9: give a number of at most 8 \(.*threads"):
        check_bounds(args)


# --- the real command -------------------------------------------------------------------------
def _cape(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["cape", *args], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_cape_train_threads_100000_is_refused_and_leaves_nothing(tmp_path: Path) -> None:
    """It once ended in a segmentation fault in libgomp (exit 139), its owner record left."""
    out = tmp_path / "model"
    done = _cape("train", "--model", "dpm", "--data", str(tmp_path / "none.npz"), "--out",
                 str(out), "--threads", "100000", cwd=tmp_path)  # fmt: skip
    assert done.returncode == 2, done.stderr
    _refused(OPTIONS[IDS.index("train --threads")], "100000", done.stderr)
    assert "--threads 100000: give a number of at most 1024" in done.stderr
    assert not out.exists() and not (tmp_path / ".model.owner").exists()
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("option", OPTIONS, ids=IDS)
def test_the_real_command_refuses_just_beyond_the_bound(option: Option, tmp_path: Path) -> None:
    if option.most is not None:
        value = option.most + 1 if option.kind is int else math.nextafter(option.most, math.inf)
    else:
        value = option.least - 1 if option.least is not None else option.above
    text = _text(value)
    done = _cape(*_argv(option.command, tmp_path), f"{option.flag}={text}", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    _refused(option, text, done.stderr)
    assert os.listdir(tmp_path) == [], "a refusal left files (an owner record?)"


@pytest.mark.parametrize("command", ["train", "draw", "rollout", "aggregate", "raceline"])
def test_the_real_command_accepts_the_edges(command: str, tmp_path: Path) -> None:
    """Every option of the command at an edge of its bounds: the command fails on the missing
    file it is given, not on a bound, and leaves nothing behind."""
    edges = [f"{o.flag}={_text(o.most if o.most is not None else math.ulp(0.0))}"
             for o in OPTIONS if o.command == command]  # fmt: skip
    done = _cape(*_argv(command, tmp_path), *edges, cwd=tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "give a number" not in done.stderr and "invalid" not in done.stderr, done.stderr
    assert "missing.yaml" in done.stderr or "--training" in done.stderr, done.stderr
    assert os.listdir(tmp_path) == []
