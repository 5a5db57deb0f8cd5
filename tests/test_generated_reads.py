"""Generated damage (Hypothesis) to every file the question reads back, and to the workflow's
job specifications (issue 61): random bytes, truncations, a byte changed, and a value of the
wrong type put in (or a key taken out of) a valid file.

The property, for every case: the reader ends in a ``CapeError`` (one line) or in a clean
result, never in another exception. The generated cases run in-process through the function
that reads the file: ``QuestionState.read`` (results/question/looks.json), the merged config's
``validate_config`` then ``QuestionSettings.from_config``, ``Plan.from_config`` and
``stage_runs`` (results/question/stage.yaml, as the workflow's `question` target reads it),
``question_publish``'s ``read_folder``, ``rederive`` and ``differences`` (`cape question
--from`: looks.csv, and looks.json), and ``config_from_args`` then the job's typed
specification (`--spec`). A handful of cases go through the real command (`cape question`,
`snakemake -n question`), which must refuse them in one line and leave the file as it was.

The default run draws 60 cases per reader (derandomized: the same on every machine; about
30 s in all, the real commands included); ``pytest -m slow`` draws ten times as many, at
random.

The damage found by the first runs of these tests, which ended in a traceback, is pinned
through the real command at the end of this file (``test_found_...``).
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import signal
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from commands import cape
from conftest import workdir
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_question_rederive import _folder

from cape.config import REPO_ROOT
from cape.errors import CapeError

FAST = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip
SLOW = settings(max_examples=600, deadline=None, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip


class HungError(Exception):
    """A reader that had not answered within ``BOUND`` seconds."""


BOUND = 10.0  # s: one generated case; a reader takes milliseconds


def _hung(_signum: int, _frame: Any) -> None:
    raise HungError(f"no answer within {BOUND:g} s")


def holds(read: Callable[[], Any]) -> None:
    """The property: a clean result or a CapeError with a message (which every command prints
    as one line: ``cape.errors.one_line``), within ``BOUND`` seconds; any other exception
    fails the case."""
    previous = signal.signal(signal.SIGALRM, _hung)
    signal.setitimer(signal.ITIMER_REAL, BOUND)
    try:
        read()
    except CapeError as exc:
        assert str(exc).strip(), repr(exc)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# --- damage ------------------------------------------------------------------------------------
def _leaves(value: Any, where: tuple = ()) -> list[tuple]:
    if isinstance(value, dict) and value:
        return [w for k, v in value.items() for w in _leaves(v, (*where, k))] + [where]
    if isinstance(value, list) and value:
        return [w for i, v in enumerate(value) for w in _leaves(v, (*where, i))] + [where]
    return [where]


wrong_values = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(), st.sampled_from([0, -1, 1e999, -1e999, "", "x", "1", [], {}, [1], {"a": 1}]),
    st.text(max_size=6),
)  # fmt: skip


def _structured(data: Any, dump: Callable[[Any], str]) -> st.SearchStrategy[bytes]:
    """``data`` with one leaf (or branch) given a wrong value, or taken out, then dumped."""
    leaves = [w for w in _leaves(data) if w]

    def change(where: tuple, value: Any, remove: bool) -> bytes:
        copy = json.loads(json.dumps(data))
        target = copy
        for key in where[:-1]:
            target = target[key]
        if remove and isinstance(target, dict):
            del target[where[-1]]
        else:
            target[where[-1]] = value
        return dump(copy).encode()

    return st.builds(change, st.sampled_from(leaves), wrong_values, st.booleans())


def damaged(good: bytes, structured: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    """Random bytes, a truncation, one byte changed, or a structured change of ``good``."""
    cut = st.integers(0, max(len(good) - 1, 0)).map(lambda n: good[:n])
    flipped = st.tuples(st.integers(0, max(len(good) - 1, 0)), st.integers(0, 255)).map(
        lambda t: good[: t[0]] + bytes([t[1]]) + good[t[0] + 1 :]
    )
    return st.one_of(st.binary(max_size=300), cut, flipped, structured, structured)


def _json(value: Any) -> str:
    return json.dumps(value, indent=1)


def _yaml(value: Any) -> str:
    return yaml.safe_dump(value, sort_keys=False, allow_unicode=True)


def _csv_cells(good: bytes) -> st.SearchStrategy[bytes]:
    """A CSV with one cell replaced, or a line or a column's header dropped."""
    lines = good.decode().splitlines()

    def cell(row: int, column: int, value: str) -> bytes:
        cells = lines[row % len(lines)].split(",")
        cells[column % len(cells)] = value
        out = [*lines]
        out[row % len(lines)] = ",".join(cells)
        return ("\n".join(out) + "\n").encode()

    def drop(row: int) -> bytes:
        return (
            "\n".join(lines[: row % len(lines)] + lines[row % len(lines) + 1 :]) + "\n"
        ).encode()

    values = st.sampled_from(["", "nan", "inf", "-1", "x", "1e999", '"', "holds", "0", "2.5"])
    return st.one_of(st.builds(cell, st.integers(0, 200), st.integers(0, 30), values),
                     st.builds(drop, st.integers(0, 200)))  # fmt: skip


# --- the question's own files --------------------------------------------------------------------
QUESTION_FILES = ["config/config.yaml", "config/question.yaml"]


@pytest.fixture(scope="module")
def question(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A working folder for `cape question`, its design, a looks.json of three looks, the
    first stage's stage.yaml, and a published question folder (looks.csv, looks.json,
    values.csv) that re-derives."""
    from cape.config import merged_config
    from cape.specs.study import StudySpec
    from cape.study.question.plan import Plan, QuestionSettings, run_overrides
    from cape.study.question.state import QuestionState

    work = workdir(tmp_path_factory.mktemp("question"))
    shutil.copy(REPO_ROOT / "config" / "question.yaml", work / "config" / "question.yaml")
    config = merged_config([str(work / f) for f in QUESTION_FILES])
    settings_ = QuestionSettings.from_config(config)
    study = StudySpec.from_config(config)
    design = settings_.identity(dict(study.models))
    lines = [{"stage": k + 1, "look at draws": n, "wall_s": 12.5 * (k + 1), "most seeds": 5}
             for k, n in enumerate(settings_.stages[:2])]  # fmt: skip
    looks = QuestionState(design, [5] * settings_.stages[1], lines, {3: 4.0}).as_json()
    n = settings_.stages[0]
    plan = Plan(dict.fromkeys(settings_.models, n), tuple([settings_.seeds] * n))
    stage = _yaml(run_overrides(study, settings_, plan))
    published = _folder(tmp_path_factory.mktemp("published"))
    return {"work": work, "config": config, "design": design, "looks": looks.encode(),
            "stage": stage.encode(), "published": published}  # fmt: skip


def _looks_json(question: dict, budget: settings) -> Callable[..., None]:
    from cape.study.question.state import QuestionState

    good = question["looks"]

    def check(text: bytes) -> None:
        path = question["work"] / "looks-generated.json"
        path.write_bytes(text)
        holds(lambda: QuestionState.read(question["design"], str(path)))
        assert path.read_bytes() == text  # read, never rewritten

    for change in FOUND_LOOKS_JSON.values():  # the damage found once, tried every time
        check = example(text=_json(change(json.loads(good))).encode())(check)
    return budget(given(text=damaged(good, _structured(json.loads(good), _json)))(check))


def _stage_yaml(question: dict, budget: settings) -> Callable[..., None]:
    """The stage's file merged over the question's config as Snakemake merges --configfile
    (a file that is no YAML mapping is Snakemake's own refusal, before the workflow is read:
    not the project's to word), then what the workflow does with it."""
    from cape.config import merge_config, validate_config
    from cape.study.question.plan import Plan, QuestionSettings, stage_runs
    from cape.workflow.start import SOURCE

    good = question["stage"]

    def read(text: bytes) -> None:
        try:
            loaded = yaml.safe_load(text.decode())
        except (UnicodeDecodeError, yaml.YAMLError):
            return  # Snakemake refuses it itself (its own message)
        if not isinstance(loaded, dict):
            return
        merged = json.loads(json.dumps(question["config"]))
        merge_config(merged, loaded)
        config = validate_config(merged, SOURCE)
        plan = (config.get("question") or {}).get("plan")
        if plan:
            stage_runs(QuestionSettings.from_config(config, SOURCE), Plan.from_config(plan))

    def check(text: bytes) -> None:
        holds(lambda: read(text))

    return budget(given(text=damaged(good, _structured(yaml.safe_load(good), _yaml)))(check))


def _published(question: dict, budget: settings, name: str) -> Callable[..., None]:
    """`cape question --from`: one of the published folder's files damaged."""
    from cape.study.question import publish

    folder = question["published"]
    good = (folder / name).read_bytes()
    structured = (
        _structured(json.loads(good), _json) if name.endswith(".json") else _csv_cells(good)
    )

    def rederive() -> None:
        state, values, published = publish.read_folder(folder)
        publish.differences(publish.rederive(state, values), published)

    @budget
    @given(text=damaged(good, structured))
    def check(text: bytes) -> None:
        (folder / name).write_bytes(text)
        try:
            holds(rederive)
        finally:
            (folder / name).write_bytes(good)

    return check


# --- the job specifications ----------------------------------------------------------------------
def _spec_readers() -> dict[str, tuple[str, Callable[[Any], Any]]]:
    """A job's specification as the workflow writes it, and what its command builds from it."""
    from cape.config import load_config
    from cape.specs.run import RunSpec
    from cape.specs.study import StudySpec
    from cape.specs.tracks import TracksSpec
    from cape.specs.training import TrainingSpec
    from cape.study.grid import study_grid
    from cape.workflow.job_files import JobFiles

    job = JobFiles(load_config(REPO_ROOT / "config" / "config.yaml"))
    with tempfile.TemporaryDirectory() as tmp, contextlib.chdir(tmp):  # results/specs/ there
        written = {
            "rollout": job.write_rollout("pid", "truth", "truth"),
            "train": job.write_training("dpm", 0),
            "aggregate": job.write_grid(),
        }
        text = {name: Path(path).read_text() for name, path in written.items()}
    return {
        "rollout": (text["rollout"],
                    lambda c: (RunSpec.from_config(c, "pid"), TracksSpec.from_config(c))),
        "train": (text["train"], lambda c: TrainingSpec.from_config(c, "dpm")),
        "aggregate": (text["aggregate"], lambda c: study_grid(StudySpec.from_config(c))),
    }  # fmt: skip


def _spec(job: str, budget: settings, tmp: Path) -> Callable[..., None]:
    from cape.config import config_from_args

    text, build = _spec_readers()[job]
    good = text.encode()

    @budget
    @given(data=damaged(good, _structured(json.loads(good), _json)))
    def check(data: bytes) -> None:
        path = tmp / f"{job}.json"
        path.write_bytes(data)
        holds(lambda: build(config_from_args(None, None, str(path))))

    return check


@pytest.fixture
def no_marks(monkeypatch: pytest.MonkeyPatch) -> None:
    """No "validated once" marks for the generated specifications (cape.config.checked_once):
    each is checked, and none is left in the user's temporary folder."""
    import cape.config

    monkeypatch.setattr(cape.config, "_marker", lambda what, code: None)


# --- the generated tests -------------------------------------------------------------------------
def test_looks_json(question: dict) -> None:
    _looks_json(question, FAST)()


def test_stage_yaml(question: dict) -> None:
    _stage_yaml(question, FAST)()


@pytest.mark.parametrize("name", ["looks.csv", "looks.json"])
def test_published_question(question: dict, name: str) -> None:
    _published(question, FAST, name)()


@pytest.mark.parametrize("job", ["rollout", "train", "aggregate"])
def test_job_spec(job: str, tmp_path: Path, no_marks: None) -> None:
    _spec(job, FAST, tmp_path)()


@pytest.mark.slow
def test_looks_json_many(question: dict) -> None:
    _looks_json(question, SLOW)()


@pytest.mark.slow
def test_stage_yaml_many(question: dict) -> None:
    _stage_yaml(question, SLOW)()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["looks.csv", "looks.json"])
def test_published_question_many(question: dict, name: str) -> None:
    _published(question, SLOW, name)()


@pytest.mark.slow
@pytest.mark.parametrize("job", ["rollout", "train", "aggregate"])
def test_job_spec_many(job: str, tmp_path: Path, no_marks: None) -> None:
    _spec(job, SLOW, tmp_path)()


# --- a handful through the real command ----------------------------------------------------------
def _refused_unchanged(result: Any, path: Path, before: bytes) -> str:
    """`cape`'s refusal: exit 2, one line, no traceback, the file as it was."""
    said = result.stderr
    assert result.returncode == 2 and "Traceback" not in said, said
    assert len(said.strip().splitlines()) == 1, said
    assert path.read_bytes() == before
    return said


def _looks_cases(good: bytes) -> dict[str, bytes]:
    state = json.loads(good)
    wrong = json.loads(good)
    wrong["seeds"] = "five"
    no_wall = json.loads(good)
    del no_wall["looks"][0]["wall_s"]
    running = json.loads(good)
    running["looks"][0] = {"stage": "x"}
    other = {**state, "design": {**state["design"], "alpha": 0.5}}
    return {"truncated": good[: len(good) // 2], "bytes": b"\x00\xff\x80{",
            "wrong type": _json(wrong).encode(), "a look without wall_s": _json(no_wall).encode(),
            "a stage that is no number": _json(running).encode(),
            "another design": _json(other).encode()}  # fmt: skip


@pytest.mark.parametrize("case", ["truncated", "bytes", "wrong type", "a look without wall_s",
                                  "a stage that is no number", "another design"])  # fmt: skip
def test_cape_question_refuses_a_damaged_looks_json(question: dict, case: str) -> None:
    work = question["work"]
    path = work / "results" / "question" / "looks.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = _looks_cases(question["looks"])[case]
    path.write_bytes(text)
    try:
        said = _refused_unchanged(cape("question", "--dry-run", cwd=work), path, text)
        assert str(Path("results/question/looks.json")) in said, said
    finally:
        path.unlink()


STAGE_CASES = {
    "seeds of the wrong type": lambda s: s.replace("- 5\n", "- five\n", 1),
    "a draw count of zero": lambda s: re.sub(r"(draws:\n\s+\w+: )\d+", r"\g<1>0", s, count=1),
    "a plan that is no mapping": lambda s: s[: s.index("  plan:")] + "  plan: 5\n",
    "truncated inside a list": lambda s: s[: s.index("- rise") + len("- ri")],
    # the "stage.yaml without first_draws" (a KeyError with frames), in today's plan
    "a plan without its draws": lambda s: re.sub(r"    draws:\n(      .*\n)+", "", s),
    "a plan without its seeds": lambda s: re.sub(r"    seeds:\n(    - .*\n)+", "", s),
    # refused while Snakemake read question.smk: "CapeError in file …" with its frames
    "a draw count of 10¹²": lambda s: re.sub(r"(draws:\n\s+\w+: )\d+", r"\g<1>1000000000000",
                                             s, count=1),
    "seeds for fewer draws than planned": lambda s: re.sub(r"(draws:\n\s+\w+: )\d+",
                                                           r"\g<1>4", s, count=1),
}  # fmt: skip
"""Damage to results/question/stage.yaml, each a function of the good file's text."""


@pytest.mark.parametrize("case", STAGE_CASES)
def test_snakemake_question_refuses_a_damaged_stage_yaml(question: dict, case: str) -> None:
    """The documented command (`snakemake … question --configfile … stage.yaml`) with the
    stage's file damaged: the project's refusal, one line on stderr (exit status 1, as every
    refusal while Snakemake reads the workflow), none of Snakemake's frames, the file as it
    was. (A stage.yaml that is no YAML mapping at all is refused by Snakemake itself before the
    workflow is read, with its own traceback: out of the project's reach.)"""
    from commands import snakemake

    work = question["work"]
    path = work / "results" / "question" / "stage.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = STAGE_CASES[case](question["stage"].decode())
    assert text != question["stage"].decode()
    path.write_text(text)
    try:
        result = snakemake("-n", "question", "--configfile", *QUESTION_FILES,
                           "results/question/stage.yaml", cwd=work)  # fmt: skip
        out = result.stdout + result.stderr
        assert result.returncode == 1, out
        reason = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
        assert len(reason) == 1, out
        assert "Traceback" not in out and not [
            line for line in out.splitlines() if line.strip().startswith('File "')
        ], out
        assert path.read_text() == text
    finally:
        path.unlink()


def test_cape_question_from_refuses_a_changed_decision_in_one_line(question: dict) -> None:
    folder = question["published"]
    path = folder / "looks.csv"
    good = path.read_bytes()
    text = good.replace(b",holds,", b",fails,", 1)
    assert text != good
    path.write_bytes(text)
    try:
        _refused_unchanged(cape("question", "--from", str(folder)), path, text)
    finally:
        path.write_bytes(good)


# --- what the generated cases found, each through the real command --------------------------------
FOUND_LOOKS_JSON = {
    "seeds of 1e999": lambda s: {**s, "seeds": [1e999]},  # int(inf): OverflowError
    "stopped a list": lambda s: {**s, "stopped": [1.0]},  # .items(): AttributeError
    "a design key set to null": lambda s: {**s, "design": {**s["design"], "unknown": None}},
}
"""Damage to results/question/looks.json that `cape question` ended in a traceback (the last
one an IndexError: two designs that differ only by a key set to null had no changed key)."""


@pytest.mark.parametrize("case", FOUND_LOOKS_JSON)
def test_found_looks_json_damage_is_one_line(question: dict, case: str) -> None:
    work = question["work"]
    path = work / "results" / "question" / "looks.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = _json(FOUND_LOOKS_JSON[case](json.loads(question["looks"]))).encode()
    path.write_bytes(text)
    try:
        said = _refused_unchanged(cape("question", "--dry-run", cwd=work), path, text)
        assert str(Path("results/question/looks.json")) in said, said
        if case == "a design key set to null":
            assert "`unknown` was null, now (absent)" in said, said
    finally:
        path.unlink()


def _estimate_no_number(good: bytes) -> bytes:
    """The first row's estimate replaced by "x" (the claim is quoted and holds commas)."""
    header, first, *rest = good.decode().splitlines()
    claim, fields = first.rsplit('",', 1)
    cells = fields.split(",")
    cells[header.split(",").index("estimate") - 1] = "x"
    return "\n".join([header, f'{claim}",' + ",".join(cells), *rest, ""]).encode()


def _row_twice(good: bytes) -> bytes:
    lines = good.decode().splitlines()
    return "\n".join([*lines, lines[1], ""]).encode()


FOUND_LOOKS_CSV = {
    "no claim column": (lambda good: good.replace(b"claim,", b"", 1), "lacks the column(s) claim"),
    "an estimate that is no number": (_estimate_no_number, "`estimate` is 'x', not a number"),
    "a row twice": (_row_twice, "is there twice"),
}
"""Damage to a published looks.csv that `cape question --from` ended in a KeyError or a
ValueError (or, for a repeated row, a TypeError), with the words of its refusal now."""


@pytest.mark.parametrize("change", FOUND_LOOKS_CSV)
def test_found_looks_csv_damage_is_one_line(question: dict, change: str) -> None:
    folder = question["published"]
    path = folder / "looks.csv"
    good = path.read_bytes()
    damage, words = FOUND_LOOKS_CSV[change]
    text = damage(good)
    assert text != good
    path.write_bytes(text)
    try:
        said = _refused_unchanged(cape("question", "--from", str(folder)), path, text)
        assert str(path) in said and words in said, said
    finally:
        path.write_bytes(good)


FOUND_DESIGNS = {
    # a Monte Carlo over 10¹² draws per path: `cape question --from` never answered
    "a look at 10¹² draws": (lambda d: {**d, "stages": [d["stages"][0], 10**12]},
                             "is greater than the maximum of 200"),
    # 100·ln(1 + m/100) of m = −100: a math domain error outside rederive's try
    "a margin of −100 %": (lambda d: {**d, "margins": {**d["margins"], "mean_speed": -100.0}},
                           "mean_speed"),
    "looks that do not increase": (lambda d: {**d, "stages": [d["stages"][1], d["stages"][0]]},
                                   "must increase"),
    "a seed count of 1e999": (lambda d: {**d, "seeds": 1e999}, "not of its type"),
}  # fmt: skip
"""A published looks.json's design that `cape question --from` ended in a traceback, or never
answered, with the words of its refusal now."""


@pytest.mark.parametrize("case", FOUND_DESIGNS)
def test_found_design_damage_is_refused_at_once(question: dict, case: str) -> None:
    folder = question["published"]
    path = folder / "looks.json"
    good = path.read_bytes()
    state = json.loads(good)
    change, words = FOUND_DESIGNS[case]
    state["design"] = change(state["design"])
    text = _json(state).encode()
    path.write_bytes(text)
    try:
        said = _refused_unchanged(cape("question", "--from", str(folder), timeout=60), path, text)
        assert "its design is not one `cape question` records" in said and words in said, said
    finally:
        path.write_bytes(good)


def test_found_a_binary_configfile_is_one_line(question: dict) -> None:
    """`cape question --configfile` of a file that is no text (here: bytes that are no UTF-8)
    ended in a UnicodeDecodeError's traceback."""
    work = question["work"]
    path = work / "config" / "binary.yaml"
    text = bytes(range(256))
    path.write_bytes(text)
    try:
        said = _refused_unchanged(cape("question", "--dry-run", "--configfile", str(path),
                                       cwd=work), path, text)  # fmt: skip
        assert "not a text file" in said, said
    finally:
        path.unlink()
