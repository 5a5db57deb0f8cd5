"""Inputs generated to break the ``cape`` commands (Hypothesis), each invocation through the
real command line in a sandbox folder (docs/trust.md).

The property, for every invocation: it exits 0, or it exits 2 with one line on stderr and no
traceback; and no file outside its own output changes (a digest of every file and link in the
sandbox before and after; a refusal or failure changes nothing at all; the one exception is a
new file in the compiled-code cache, results/solvers, which is content-addressed). Generated: the
commands' options (η, seed, names, tracks, run lists) and every leaf of the config (wrong
types, NaN, ±inf, negatives, huge numbers, empty and unicode strings), and as ``--out`` new
paths, paths with spaces and unicode, a user's file, empty and non-empty folders, another
command's output, a symbolic link, a file's child, ``/``, ``.`` and names too long for the
file system. The default run draws a few dozen invocations (derandomized: the same on every
machine); ``pytest -m slow`` draws many more, at random.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cape.layout import paths

FAST = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip
SLOW = settings(max_examples=120, deadline=None, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip
TIMEOUT = 120.0  # s: one invocation; more is a hang
CACHE = Path(paths.SOLVERS)
"""The compiled-code cache: content-addressed files any command may add (never replace)."""


@dataclass
class Sandbox:
    """A folder of everything a user might point a command at."""

    root: Path
    config: Path
    setup: dict
    trained: dict


@pytest.fixture(scope="module")
def sandbox(setup: dict, trained: dict, tmp_path_factory: pytest.TempPathFactory) -> Sandbox:
    root = tmp_path_factory.mktemp("sandbox")
    (root / "notes.md").write_text("a user's notes")
    (root / "mine").mkdir()
    (root / "mine" / "thesis.tex").write_text("a user's thesis")
    (root / "empty").mkdir()
    (root / "with space").mkdir()
    (root / "link").symlink_to(root / "notes.md")
    made = subprocess.run(["cape", "rollout", "--plant", "truth", "--controller", "pid", "--eta",
                           "0", "--seed", "0", "--out", str(root / "a run"), "--raceline",
                           str(setup["raceline"]), "--config", str(setup["config"])],
                          capture_output=True, text=True)  # fmt: skip
    assert made.returncode == 0, made.stderr
    config = root.parent / f"{root.name}-config.yaml"  # outside: not the commands' to change
    shutil.copy(setup["config"], config)
    return Sandbox(root, config, setup, trained)


def _tree(root: Path) -> dict[str, str]:
    """Every file and symbolic link under ``root`` → its digest (or link target)."""
    found = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder) / name
            rel = str(path.relative_to(root))
            if path.is_symlink():
                found[rel] = "link → " + os.readlink(path)
            elif path.is_file():
                found[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def _outputs_of(args: list[str], root: Path) -> list[Path]:
    """The outputs an invocation names (``--out``, ``--summary``, ``--figure``), resolved
    against the sandbox, and each one's owner record."""
    outs = []
    for flag, value in itertools.pairwise(args):
        if flag in ("--out", "--summary", "--figure", "--phi-out", "--curves-out"):
            path = Path(os.path.abspath(root / value))
            outs += [path, path.parent / f".{path.name}.owner"]
    return outs


def _inside(path: Path, outputs: list[Path]) -> bool:
    return any(Path(os.path.abspath(path)).is_relative_to(o) for o in outputs)


def check_invocation(box: Sandbox, args: list[str]) -> None:
    """The property: exit 0 with changes only in its own outputs, or exit 2 with one line
    and nothing changed."""
    top = set(os.listdir("/"))
    before = _tree(box.root)
    try:
        done = subprocess.run(["cape", *args], cwd=box.root, capture_output=True, text=True,
                              timeout=TIMEOUT)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail(f"cape {' '.join(args)}: no answer within {TIMEOUT} s")
    after = _tree(box.root)
    said = f"cape {' '.join(map(repr, args))}\nstdout: {done.stdout[-800:]}\nstderr: {done.stderr}"
    assert "Traceback" not in done.stderr, said
    assert done.returncode in (0, 2), said
    assert set(os.listdir("/")) == top, said
    changed = {p for p in before.keys() | after.keys() if before.get(p) != after.get(p)}
    if done.returncode == 2:
        assert len(done.stderr.strip().splitlines()) == 1, said
        assert not changed, f"{said}\nchanged: {sorted(changed)}"
        return
    outputs = _outputs_of(args, box.root)
    added_to_cache = {p for p in changed - before.keys() if Path(p).is_relative_to(CACHE)}
    stray = [p for p in changed - added_to_cache if not _inside(box.root / p, outputs)]
    assert not stray, f"{said}\nchanged outside its outputs: {sorted(stray)}"


# --- strategies ------------------------------------------------------------------------------
nasty_text = st.one_of(
    st.sampled_from(["", " ", "x y", "../up", "/", ".", "..", "-1", "nan", "inf", "1e999",
                     "１", "é", "名前", "a\tb", "0x10", "None", "true", "[]", "{}"]),
    # argv holds neither NUL nor lone surrogates (not text in any encoding)
    st.text(st.characters(exclude_characters="\x00", exclude_categories=("Cs",)), max_size=12),
)  # fmt: skip
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, -1, 1, 5, 5.0001, 1e19, 2**63, 2**64, -(2**63)]),
)
leaf_values = st.one_of(st.none(), st.booleans(), numbers, nasty_text,
                        st.lists(numbers, max_size=3), st.just({}), st.just([]))  # fmt: skip


def _as_text(value: Any) -> str:
    return value if isinstance(value, str) else repr(value)


option_values = st.one_of(nasty_text, numbers.map(_as_text))

out_paths = st.one_of(
    st.sampled_from(["new-out", "with space/out", "名前/out", "notes.md", "mine", "empty",
                     "a run", "link", "notes.md/child", ".", "/", "", "x" * 300, "mine/thesis.tex",
                     "deep/er/out", ".hidden"]),
    nasty_text,
)  # fmt: skip


def _with_suffix(suffixes: list[str]) -> st.SearchStrategy[str]:
    return st.tuples(out_paths, st.sampled_from(suffixes)).map(lambda t: t[0] + t[1])


def _leaves(value: Any, where: tuple = ()) -> list[tuple]:
    if isinstance(value, dict):
        return [leaf for k, v in value.items() for leaf in _leaves(v, (*where, k))]
    if isinstance(value, list) and value:
        return [leaf for i, v in enumerate(value) for leaf in _leaves(v, (*where, i))]
    return [where]


def _set(config: Any, where: tuple, value: Any) -> Any:
    config = json.loads(json.dumps(config))
    target = config
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = value
    return config


# --- the invocations ------------------------------------------------------------------------
def rollout_invocation(box: Sandbox) -> st.SearchStrategy[list[str]]:
    inputs = ["--raceline", str(box.setup["raceline"]), "--training-data", str(box.setup["data"]),
              "--config", str(box.config)]  # fmt: skip

    def invocation(plant: str, controller: str, eta: str, seed: str, out: str, study: str):
        named = {"--plant": plant, "--controller": controller, "--eta": eta, "--seed": seed,
                 "--out": out, "--study": study}  # fmt: skip
        return ["rollout", *[a for item in named.items() for a in item], *inputs]

    return st.builds(
        invocation,
        st.one_of(st.sampled_from(["truth", "dpm", "ddm-fixed"]), nasty_text),
        st.one_of(st.sampled_from(["pid", "rise"]), nasty_text),
        st.one_of(st.sampled_from(["0", "1.0", "5"]), option_values),
        st.one_of(st.sampled_from(["0", "1"]), option_values),
        out_paths,
        st.one_of(st.just("adhoc"), nasty_text),
    )


def config_leaf_invocation(box: Sandbox) -> st.SearchStrategy[list[str]]:
    """A rollout with one leaf of the config replaced by a generated value."""
    folder = box.config.parent  # beside the sandbox: not the commands' to change
    config = yaml.safe_load(box.config.read_text())
    leaves = [w for w in _leaves(config) if w]

    def invocation(where: tuple, value: Any, as_json: bool) -> list[str]:
        bad = _set(config, where, value)
        run = ["rollout", "--plant", "truth", "--controller", "pid", "--eta", "1", "--seed", "0",
               "--out", "leaf-run", "--raceline", str(box.setup["raceline"])]  # fmt: skip
        if as_json:
            return [*run, "--config-json", json.dumps(bad)]
        path = folder / f"{box.root.name}-generated.yaml"
        path.write_text(yaml.safe_dump(bad, allow_unicode=True))
        return [*run, "--config", str(path)]

    return st.builds(invocation, st.sampled_from(leaves), leaf_values, st.booleans())


def _outs(outs: list[str]) -> list[str]:
    return [a for o in outs for a in ("--out", o)]


def command_invocation(box: Sandbox) -> st.SearchStrategy[list[str]]:
    """The other commands' options and outputs: data, openloop, export-network, aggregate."""
    cfg = ["--config", str(box.config)]
    model = f"dpm={box.trained['plain']}"
    sets = ["--train-data", str(box.setup["data"]), "--test-data", str(box.setup["data"])]
    run = str(box.root / "a run" / "metrics.json")
    data = st.builds(
        lambda track, out: ["data", "--track", track, "--out", out, *cfg],
        st.one_of(st.sampled_from(["ETHZ", "ETHZMobil"]), nasty_text),
        st.one_of(_with_suffix([".npz", ".csv"]), out_paths),
    )
    table_outs = st.one_of(_with_suffix([".md", ".csv", ".tex", ".txt"]), out_paths)
    openloop = st.builds(
        lambda name, outs: ["openloop", "--model", name, *sets, *_outs(outs), *cfg],
        st.one_of(st.just(model), nasty_text, st.just(f"{model}x"), st.just(f"epm={model[4:]}")),
        st.lists(table_outs, min_size=1, max_size=3),
    )
    export = st.builds(
        lambda name, out: ["export-network", "--model", name, "--out", out],
        st.one_of(st.just(model), nasty_text),
        st.one_of(_with_suffix([".npz", ".json"]), out_paths),
    )
    aggregate = st.builds(
        lambda runs, out, summary: ["aggregate", *runs, "--out", out, "--summary", summary, *cfg],
        st.lists(st.one_of(st.just(run), st.just("notes.md"), nasty_text), min_size=1, max_size=3),
        st.one_of(_with_suffix([".parquet"]), out_paths),
        st.one_of(_with_suffix([".parquet"]), out_paths),
    )
    return st.one_of(data, openloop, export, aggregate)


# --- the tests ------------------------------------------------------------------------------
def _property(strategy: Callable[[Sandbox], st.SearchStrategy], budget: settings):
    @budget
    @given(data=st.data())
    def check(sandbox: Sandbox, data: st.DataObject) -> None:
        check_invocation(sandbox, data.draw(strategy(sandbox)))

    return check


test_rollout_options = _property(rollout_invocation, FAST)
test_other_commands = _property(command_invocation, FAST)
test_config_leaves = _property(config_leaf_invocation, FAST)
test_rollout_options_many = pytest.mark.slow(_property(rollout_invocation, SLOW))
test_other_commands_many = pytest.mark.slow(_property(command_invocation, SLOW))
test_config_leaves_many = pytest.mark.slow(_property(config_leaf_invocation, SLOW))
