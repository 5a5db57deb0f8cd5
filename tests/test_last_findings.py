"""Issue 61's findings, each through the real command (`cape`, `snakemake`): no refusal advises
deleting what the command did not write, an unwritable output folder is said to be one, no
`--spec` is ignored, `cape question --cores 0` is refused before anything runs, and a refusal
while Snakemake loads a job's specification is one line. (The SLURM scripts' findings are in
tests/test_slurm_scripts.py, the benchmark's in tests/test_benchmarks.py, the generated reads
in tests/test_generated_reads.py.)"""

from __future__ import annotations

import ast
import contextlib
import errno
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from commands import cape, one_message, snakemake
from conftest import workdir

from cape.config import REPO_ROOT

SRC = REPO_ROOT / "src"
RUN = Path("results/runs/truth/rep0/truth/truth/pid/eta0/seed0")


# --- 1. advice that destroys -------------------------------------------------------------------
RM = re.compile(r"(?<![\w./-])rm\s")
"""A shell `rm` in a message (`rm -r x`, `rm x`), not the letters of "form " or "confirm "."""
FOLDER_DELETED = re.compile(r"delete (the |this |its )?([\w']+ )?folder", re.IGNORECASE)
"""Advice to delete a whole folder, `rm` or not."""

ALLOWED = {
    ("cape/training/loop.py", "Checkpointing.load"): (
        "`rm <checkpoint>`: the resume checkpoint that `cape train` itself writes into its own "
        "--out folder while it trains (checkpoint-<fingerprint>.pt), named file by file; the "
        "command that reads it is the one that wrote it"
    ),
}
"""The messages allowed to advise removing something, each because what they name is the
command's own output: (path under src/, the function the string is in) → why."""


def _strings(path: Path) -> list[tuple[str, str, int]]:
    """Every string literal and f-string in ``path`` said to someone (docstrings aside: a
    statement that is only a string), with the function it is in and its line: a superset of
    the message templates, so that advice assembled from pieces (a ``fix`` variable, a helper's
    return value, an argument to ``check_record(..., fix)``) is read too."""
    tree = ast.parse(path.read_text())
    docstrings = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Expr)}
    found: list[tuple[str, str, int]] = []

    def visit(node: ast.AST, where: list[str]) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            where = [*where, node.name]
        if id(node) not in docstrings:
            if isinstance(node, ast.JoinedStr):
                found.append((ast.unparse(node), ".".join(where), node.lineno))
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                found.append((node.value, ".".join(where), node.lineno))
        for child in ast.iter_child_nodes(node):
            visit(child, where)

    visit(tree, [])
    return found


def _templates(path: Path) -> list[tuple[str, str, int]]:
    """The message templates of ``path``: each argument of a ``CapeError(...)`` call, as its
    source (an f-string's placeholders as written), with the function it is in."""
    tree = ast.parse(path.read_text())
    found: list[tuple[str, str, int]] = []

    def visit(node: ast.AST, where: list[str]) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            where = [*where, node.name]
        if isinstance(node, ast.Call):
            name = getattr(node.func, "id", getattr(node.func, "attr", None))
            if name == "CapeError":
                for arg in node.args:
                    found.append((ast.unparse(arg), ".".join(where), node.lineno))
        for child in ast.iter_child_nodes(node):
            visit(child, where)

    visit(tree, [])
    return found


def test_no_refusal_suggests_removing_what_the_command_did_not_write() -> None:
    """Every CapeError message template in src/ (the arguments of every ``CapeError(...)``),
    and every other string there a message can be assembled from: none holds a shell `rm` or
    advice to delete a folder, unless ALLOWED names its place and why what it names is the
    command's own output. How the test decides "the command's own": not from the text (a
    template's path is a placeholder), but by that reviewed list, so a new `rm` anywhere fails
    until someone says why it is safe."""
    files = sorted(SRC.rglob("*.py"))
    templates = [(f, *t) for f in files for t in _templates(f)]
    strings = [(f, *s) for f in files for s in _strings(f)]
    assert len(templates) > 150, len(templates)  # the collector sees the messages
    offending = []
    for path, text, where, line in templates + strings:
        key = (str(path.relative_to(SRC)), where)
        if (RM.search(text) or FOLDER_DELETED.search(text)) and key not in ALLOWED:
            offending.append(f"{key[0]}:{line} ({where}): {text[:120]}")
    assert not offending, "\n".join(sorted(set(offending)))
    used = {(str(p.relative_to(SRC)), w) for p, t, w, _ in strings if RM.search(t) or
            FOLDER_DELETED.search(t)}  # fmt: skip
    assert set(ALLOWED) <= used, set(ALLOWED) - used  # no stale entry


@pytest.mark.parametrize("where", [".", "mine", "mine/deeper"])
def test_aggregate_of_metrics_outside_a_run_folder_advises_no_rm(
    tmp_path: Path, where: str
) -> None:
    """A metrics.json at the working folder's root or in a user's folder: refused, saying it
    is no run folder of the workflow; no `rm -r .`, no `rm -r mine` (it said "delete the run
    folder (`rm -r .`)"). The user's folder is left as it was."""
    folder = tmp_path / where
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "notes.md").write_text("a user's notes")
    metrics = folder / "metrics.json"
    for text in ('{"study": "mine"}', '{"truncated": '):
        metrics.write_text(text)
        result = cape("aggregate", str(Path(where) / "metrics.json"), "--out", "runs.parquet",
                      "--summary", "cells.parquet", cwd=tmp_path)  # fmt: skip
        said = one_message(result, "not one of the workflow's run folders", "cape rollout --out")
        assert "rm " not in said and "delete" not in said, said
        assert (folder / "notes.md").read_text() == "a user's notes"
        assert not (tmp_path / "runs.parquet").exists()


def test_a_damaged_run_of_the_workflow_is_recomputed_not_deleted(tmp_path: Path) -> None:
    """A run folder of the workflow's layout: the fix is Snakemake's --force of its
    metrics.json (Snakemake replaces the rule's own files), not `rm -r` of the folder."""
    (tmp_path / RUN).mkdir(parents=True)
    (tmp_path / RUN / "metrics.json").write_text("{}")
    result = cape("aggregate", str(RUN / "metrics.json"), "--out", "runs.parquet", "--summary",
                  "cells.parquet", cwd=tmp_path)  # fmt: skip
    said = one_message(result, f"snakemake --cores 1 --force {RUN / 'metrics.json'}")
    assert "rm " not in said and "delete" not in said, said


# --- 2. an output folder that cannot be written ------------------------------------------------
def _immutable(folder: Path) -> bool:
    """``chattr +i`` on ``folder``, if this machine can (root on a file system with the
    attribute); then not even root may create a file in it."""
    if shutil.which("chattr") is None:
        return False
    done = subprocess.run(["chattr", "+i", str(folder)], capture_output=True)
    if done.returncode != 0:
        return False
    try:
        (folder / "probe").touch()
    except OSError:
        return True
    (folder / "probe").unlink()
    subprocess.run(["chattr", "-i", str(folder)], capture_output=True)
    return False


def test_an_immutable_output_folder_is_said_to_be_one(tmp_path: Path) -> None:
    """Through the real `cape aggregate`, into a folder made immutable (`chattr +i`; chmod
    stops no root, and the tests run as root in CI): one line saying the folder cannot be
    written, not "owner record … not a plain file; remove it". Skipped where chattr cannot."""
    locked = tmp_path / "locked"
    locked.mkdir()
    if not _immutable(locked):
        pytest.skip("chattr +i is not available here (test below: the same, in-process)")
    try:
        result = cape("aggregate", "metrics.json", "--out", str(locked / "runs.parquet"),
                      "--summary", str(locked / "cells.parquet"), cwd=tmp_path)  # fmt: skip
        said = one_message(result, f"its folder {locked} cannot be written", "nothing was changed")
        assert "owner record" not in said and "remove it" not in said, said
        assert list(locked.iterdir()) == []
    finally:
        subprocess.run(["chattr", "-i", str(locked)], capture_output=True)


@pytest.mark.parametrize("code", [errno.EPERM, errno.EACCES, errno.EROFS])
def test_an_unwritable_output_folder_is_said_to_be_one_in_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int
) -> None:
    """The same refusal where the folder's refusal is simulated: ``os.open`` of the owner
    record fails as in an immutable, another user's or a read-only folder."""
    import os

    from cape.errors import CapeError
    from cape.storage import ownership

    real = os.open

    def refused(path, flags, *args, **kwargs):
        if str(path).endswith(".owner"):
            raise OSError(code, os.strerror(code), str(path))
        return real(path, flags, *args, **kwargs)

    monkeypatch.setattr(ownership.os, "open", refused)
    out = ownership.Output(tmp_path / "table.csv", "table")
    with pytest.raises(CapeError, match="cannot be written") as refusal:
        ownership.claim([out], "test")
    assert "not a plain file" not in str(refusal.value) and "remove" not in str(refusal.value)
    assert list(tmp_path.iterdir()) == []


# --- 3. no --spec ignored -----------------------------------------------------------------------
SPEC_COMMANDS = {
    "tracks": [],
    "data": ["--track", "ETHZ", "--out", "o/d.npz"],
    "plot-tracks": ["--data", "d.npz", "--out", "o/f.pdf"],
    "raceline": ["--track", "ETHZMobil", "--out", "o/r.npz"],
    "train": ["--model", "dpm", "--data", "d.npz", "--out", "o/m"],
    "check-training": ["--model", "dpm", "--data", "d.npz", "--out", "o/h.json"],
    "draw": ["--model", "dpm", "--replicate", "0", "--training", "t", "--max-trainings", "1",
             "--out", "o/m"],
    "freeze": ["--model", "dpm=m", "--data", "d.npz", "--out", "o/phi.json"],
    "export-network": ["--model", "dpm=m", "--out", "o/n.npz"],
    "openloop": ["--model", "dpm=m", "--train-data", "d.npz", "--test-data", "d.npz", "--out",
                 "o/t.csv"],
    "complexity": ["--model", "dpm=m", "--data", "d.npz", "--out", "o/t.csv"],
    "plot-models": ["--model", "dpm=m", "--data", "d.npz", "--phi-out", "o/a.pdf",
                    "--curves-out", "o/b.pdf"],
    "build-solver": ["--controller", "nmpc", "--internal", "truth", "--out", "o/s.so"],
    # the workflow's rollout command (rules/rollouts.smk), its spec the file given
    "rollout": ["--study", "truth", "--plant", "truth", "--controller", "pid", "--internal",
                "truth", "--eta", "0", "--seed", "0", "--replicate", "0", "--out", "o/run",
                "--raceline", "r.npz"],
    "plot-rollout": ["--run", "r", "--out", "o/f.pdf"],
    "aggregate": ["m.json", "--out", "o/a.parquet", "--summary", "o/b.parquet"],
}  # fmt: skip
"""Every command that takes --spec, with required arguments that are read after the spec."""


def test_every_command_that_takes_spec_is_listed() -> None:
    import argparse

    from cape.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    taking = {name for name, p in sub.choices.items()
              if any("--spec" in a.option_strings for a in p._actions)}  # fmt: skip
    assert taking == set(SPEC_COMMANDS)


def _specs(folder: Path) -> dict[str, tuple[Path, str]]:
    """An empty spec, a truncated one (a real rollout spec cut in half), a foreign one (the
    YAML config itself, not a job's JSON), each with the words its refusal holds."""
    from cape.config import load_config
    from cape.workflow.job_files import JobFiles

    with contextlib.chdir(folder):  # the job file is written under results/specs/ there
        job = JobFiles(load_config(REPO_ROOT / "config" / "config.yaml"))
        whole = Path(job.write_rollout("pid", "truth", "truth")).read_text()
    config = (REPO_ROOT / "config" / "config.yaml").read_text()
    made = {"empty": ("", "is empty"), "truncated": (whole[: len(whole) // 2], "not valid JSON"),
            "foreign": (config, "not valid JSON")}  # fmt: skip
    out = {}
    for name, (text, words) in made.items():
        path = folder / f"{name}.json"
        path.write_text(text)
        out[name] = (path, words)
    return out


KINDS = ("empty", "truncated", "foreign")


def _kinds(command: str) -> tuple[str, ...]:
    """The spec damage tried on ``command``: all three on the rollout (the finding's command),
    the empty spec (which every command ignored) on each other: every command reads its spec
    through the same ``cape.config.config_from_args``, and a cape process is 2 s of CPU."""
    return KINDS if command == "rollout" else ("empty",)


@pytest.mark.parametrize("command", SPEC_COMMANDS)
def test_an_empty_truncated_or_foreign_spec_is_refused(tmp_path: Path, command: str) -> None:
    """Each refused in one line naming the spec, exit 2, nothing written, the spec unchanged:
    an empty one used to be ignored, and the command ran with config/config.yaml (the
    workflow's rollout compiled 4 solver libraries the smoke spec turns off)."""
    for name, (path, words) in _specs(tmp_path).items():
        if name not in _kinds(command):
            continue
        before = path.read_bytes()
        result = cape(command, *SPEC_COMMANDS[command], "--spec", str(path), cwd=tmp_path)
        one_message(result, f"--spec {path}", words)
        assert path.read_bytes() == before, name
        assert not (tmp_path / "o").exists(), name


def test_a_spec_of_no_sections_or_of_another_job_is_refused(tmp_path: Path) -> None:
    """The rollout given `{}` or the tracks job's spec: one line naming the spec (the other
    job's lacks the rollout's sections), nothing run."""
    empty, other = tmp_path / "none.json", tmp_path / "tracks.json"
    empty.write_text("{}\n")
    other.write_text(json.dumps({"tracks": {"dir": "resources/bayesrace"}}))
    for path, words in ((empty, "holds no config section"), (other, "another job")):
        result = cape("rollout", *SPEC_COMMANDS["rollout"], "--spec", str(path), cwd=tmp_path)
        one_message(result, f"--spec {path}", words)
        assert not (tmp_path / "o").exists()


# --- 4. cape question --cores 0 -----------------------------------------------------------------
@pytest.mark.parametrize("cores", ["0", "-2", "1000001"])
def test_question_refuses_a_count_of_cores_that_runs_nothing(tmp_path: Path, cores: str) -> None:
    """`--cores 0` started Snakemake with "Provided cores: 0", which waits forever: refused
    in one line with the bound --project-cores has, before any file is written."""
    work = workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "question.yaml", work / "config" / "question.yaml")
    result = cape("question", "--cores", cores, "--dry-run", cwd=work)
    one_message(result, f"--cores {cores}", "a count of cores")
    assert not (work / "results").exists()
    fine = cape("question", "--cores", "1", "--dry-run", cwd=work)
    assert fine.returncode == 0, fine.stderr


# --- 9. a refusal inside a specification's load, under Snakemake ---------------------------------
def test_a_refusal_while_snakemake_loads_a_spec_is_one_line(tmp_path: Path) -> None:
    """A job's specification file that the workflow did not write (here: replaced by hand):
    the refusal raised while Snakemake plans (a rule's params) is its one line on stderr, exit
    status 1, none of Snakemake's InputFunctionException frames; the file is left as it was."""
    work = workdir(tmp_path)
    planned = snakemake("-n", "-d", str(work), "tracks")
    assert planned.returncode == 0, planned.stderr[-2000:]
    (spec,) = (work / "results" / "specs" / "tracks").iterdir()
    spec.write_text('{"tracks": {"dir": "elsewhere"}}\n')
    for args in (("-n",), ("--cores", "1")):
        result = snakemake(*args, "-d", str(work), "tracks")
        out = result.stdout + result.stderr
        assert result.returncode == 1, out
        reason = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
        assert len(reason) == 1 and str(spec.relative_to(work)) in reason[0], out
        assert "which the workflow did not write" in reason[0], out
        assert "Traceback" not in out and "InputFunctionException" not in out, out
        assert not [line for line in out.splitlines() if line.strip().startswith('File "')], out
        assert spec.read_text() == '{"tracks": {"dir": "elsewhere"}}\n'
    assert not list((work / ".snakemake" / "locks").glob("*"))  # the folder is not left locked


# --- a started snakemake is stopped with its jobs (cape question, scheduler_threads.py) ----------
def test_stop_ends_a_process_and_the_jobs_it_started_in_sessions_of_their_own() -> None:
    """``cape.processes.stop``, shared by `cape question` and
    benchmarks/scheduler_threads.py: a parent in its own session whose child is in another
    session (as Snakemake starts its jobs), the child ignoring SIGTERM: both end, the child by
    SIGKILL after the grace."""
    import time

    from cape.processes import descendants, stop

    proc = subprocess.Popen(
        ["bash", "-c", "setsid bash -c 'trap \"\" TERM; sleep 60' & wait"],
        start_new_session=True,
    )
    deadline = time.monotonic() + 10
    while not descendants(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    jobs = descendants(proc.pid)
    assert jobs, jobs  # the sleep in its own session, deaf to SIGTERM
    start = time.monotonic()
    stop(proc, grace=1.0)
    assert proc.returncode is not None and time.monotonic() - start < 10
    time.sleep(0.2)
    left = [pid for pid in jobs if Path(f"/proc/{pid}").exists()
            and "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()]  # fmt: skip
    assert not left, left


# --- `--configfile` last in every documented command ---------------------------------------------
DOCS = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]


def _documented_snakemake() -> list[tuple[str, list[str]]]:
    """Every `snakemake …` command of the README and docs/ (a line of a code block or inline
    code, continued lines joined), split into words, its comment left out."""
    import shlex

    found = []
    for doc in DOCS:
        text = doc.read_text().replace("\\\n", " ")
        for line in text.splitlines():
            for command in re.findall(r"(?:^|`)\s*(snakemake [^`#]*)", line):
                with contextlib.suppress(ValueError):  # an unbalanced quote: prose
                    found.append((f"{doc.name}: {command.strip()}", shlex.split(command)))
    return found


def test_the_documented_commands_put_configfile_last() -> None:
    """`snakemake -n --configfile config/smoke.yaml all replicates` reads the targets as config
    files and ends in Snakemake's FileNotFoundError, raised while Snakemake reads its command
    line, before the workflow (and any of the project's code) is read: no hint can be given
    there. So every command the README and docs/ give puts its targets before `--configfile`:
    the words after it are config files, up to the next option."""
    commands = _documented_snakemake()
    with_files = [c for c in commands if "--configfile" in c[1]]
    assert len(with_files) >= 5, commands  # the reader sees the commands
    wrong = []
    for shown, words in with_files:
        at = words.index("--configfile") + 1
        while at < len(words) and not words[at].startswith("-"):
            if not words[at].endswith((".yaml", ".yml", ".json")):
                wrong.append(f"{shown}  ({words[at]!r} would be read as a config file)")
            at += 1
    assert not wrong, "\n".join(wrong)
    readme = (REPO_ROOT / "README.md").read_text()
    assert "`--configfile` goes last" in readme


# --- verdicts.interval refuses what it cannot summarise -------------------------------------------
def test_interval_refuses_an_infinite_or_overflowing_effect() -> None:
    """{draw 0: 1e308, draw 1: −1e308} gave an estimate of 0 within [−inf, inf] and only
    RuntimeWarnings; an infinite value was left out without a word. Both are refused by the
    function itself (a ValueError and a CapeError: one line where a command meets it), with no
    warning; a missing value (NaN) is still left out. Table 9 screens such values first and
    says which run is unusable (tests/test_small_findings.py)."""
    import math
    import warnings

    from cape.errors import CapeError
    from cape.study.stats.verdicts import UnusableEffectsError, equivalence_p, interval

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning fails the test
        for effects, words in (
            ({0: [1e308], 1: [-1e308]}, "1e+308 cannot be summarised"),
            ({0: [1e200, -1e200, 3.0]}, "1e+200 cannot be summarised"),
            ({0: [1e308, 1e308], 1: [1.0]}, "1e+308 cannot be summarised"),
            ({0: [1.0, math.inf], 1: [3.0]}, "draw 0's effect inf is not a finite number"),
            ({0: [1.0], 1: [-math.inf, 2.0]}, "draw 1's effect -inf is not a finite number"),
        ):
            with pytest.raises(UnusableEffectsError, match=re.escape(words)) as refused:
                interval(effects)
            assert isinstance(refused.value, ValueError) and isinstance(refused.value, CapeError)
        with pytest.raises(UnusableEffectsError):
            equivalence_p({0: [math.inf], 1: [1.0]}, 1.0, 2)
        kept = interval({0: [1.0, math.nan], 1: [3.0, None]})  # type: ignore[list-item]
        assert kept.estimate == 2.0 and kept.values == 2


# --- question.seeds.least is never lowered without a word ----------------------------------------
def test_the_least_seeds_a_later_draw_gets_is_kept() -> None:
    """`question.seeds.least` above the study's seeds (here 8 over 5) was lowered to them (or to
    the measured most) without a word. Now the most a later draw may get is at least the
    least, and where no cost is measured the later draws get the least, saying so."""
    from cape.study.question.looks import next_seeds
    from cape.study.question.plan import QuestionSettings
    from cape.study.question.report import Cost, most_seeds

    margins = {"lap_time_penalised": 0.2}
    settings = QuestionSettings(("epm", "dpm"), (3, 6), 0.05, 2.0, margins, "truth", ("0",), 5,
                                8, 1000, 0.05, None)  # fmt: skip
    # a draw costs two seeds' runs (60 s against 10 s × 3 NMPCs): the measured most is 5
    cheap_draws = Cost(trainings={"epm": [60.0], "dpm": [60.0]}, draws={"epm": 1, "dpm": 1},
                       runs_s=10.0, runs=1)  # fmt: skip
    assert most_seeds(settings, cheap_draws) == 8  # was 5: the study's, below the least
    assert most_seeds(settings, Cost()) == 8  # nothing measured
    chosen, _, said = next_seeds([], settings.design(), 0, {"epm": 3, "dpm": 3}, Cost(), settings,
                                 most=6)  # fmt: skip
    assert chosen == 8 and "`question.seeds.least`'s 8" in said, said
    # a published stage's most (cape question --reuse), below the least
    chosen, _, said = next_seeds([], settings.design(), 0, {"epm": 3, "dpm": 3}, cheap_draws,
                                 settings, most=6)  # fmt: skip
    assert chosen == 8 and "of 8 … 8" in said, said
