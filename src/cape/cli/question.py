"""``cape question``: the ground-truth question answered in stages (SPEC §10, revision 6).

Stage by stage it writes the plan (results/question/stage.yaml), runs Snakemake's ``question``
target with it (the trainings, draws, solvers and runs the stage's rows read, nothing else),
looks at every open row (``cape.study.question.looks``), and adds draws only to the models of rows
still open, until every row is settled or the last stage is looked at. Killed, it resumes: a
rerun goes through the stages again, Snakemake redoes only what is missing, and the looks are
the same (they are computed from the runs). The report: results/question/RESULTS.md, looks.csv
and looks.json, after every stage. How to read it: docs/question.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from cape.cli.common import CORES, _claim, command
from cape.errors import CapeError
from cape.layout import paths

DEFAULT_FILES = ("config/config.yaml", "config/question.yaml")
STOP_GRACE = 60.0  # s: how long a stopped stage's Snakemake gets to end its jobs before SIGKILL


def _arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--configfile",
        nargs="+",
        metavar="FILE",
        default=[],
        help="config files merged over config/config.yaml and config/question.yaml, in order "
        "(as Snakemake's --configfile)",
    )
    p.add_argument(
        "--no-question-config",
        action="store_true",
        help="do not merge config/question.yaml (the question's models then come from the "
        "other files)",
    )
    p.add_argument(
        "--cores",
        type=CORES,
        default=2,
        metavar="N",
        help="Snakemake's --cores for each stage (%(default)s)",
    )
    p.add_argument(
        "--project-cores",
        type=CORES,
        default=64,
        metavar="N",
        help="the cluster size the report projects the wall time to the cap on, beside two "
        "cores (%(default)s: e.g. 32 nodes of 2 cores through the SLURM profile)",
    )
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="print the first stage's plan and Snakemake command, run nothing",
    )
    p.add_argument(
        "--from",
        dest="rederive",
        metavar="FOLDER",
        help="run nothing: re-decide every look of a published question (FOLDER: its "
        "values.csv and looks.json) and check them against its looks.csv",
    )
    p.add_argument(
        "--reuse",
        metavar="FOLDER",
        help="continue from a published question (e.g. docs/results/question): a draw whose "
        "values it holds on the planned seeds is not run again, and its chosen seeds are kept",
    )
    p.add_argument(
        "--publish",
        metavar="FOLDER",
        help="run nothing: copy the last look's report, tables, figure and per-seed values from "
        "results/question/ into FOLDER, with provenance.json (e.g. docs/results/question)",
    )
    p.add_argument(
        "snakemake_args",
        nargs=argparse.REMAINDER,
        help="after `--`: passed to every Snakemake run (e.g. -- --workflow-profile "
        "workflow/profiles/slurm)",
    )


def merged_config(files: Sequence[str]) -> dict[str, Any]:
    """The files merged in order as Snakemake merges --configfile (mappings key by key, any
    other value replaced), then validated (the schema's defaults filled)."""
    import yaml

    from cape.config import validate_config

    merged: dict[str, Any] = {}
    for name in files:
        path = Path(name)
        if not path.is_file():
            raise CapeError(f"config file {path} not found; run from the repository root")
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            raise CapeError(f"{path}: not a text file, so no YAML config; give a config file "
                            "such as config/smoke.yaml") from None  # fmt: skip
        except OSError as exc:
            raise CapeError(f"{path}: cannot be read ({exc.strerror})") from None
        try:
            loaded = yaml.safe_load(text) or {}
        except yaml.YAMLError as exc:
            raise CapeError(f"{path}: not valid YAML ({exc})") from exc
        if not isinstance(loaded, dict):
            raise CapeError(f"{path}: the top level must be a mapping of sections")
        _merge(merged, loaded)
    return validate_config(merged, " + ".join(files))


def _merge(into: dict[str, Any], other: Mapping[str, Any]) -> None:
    for key, value in other.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = json.loads(json.dumps(value))


def _snakemake(
    files: Sequence[str],
    cores: int,
    extra: Sequence[str],
    log: Path,
    what: str,
    target: str = "question",
) -> None:
    """Run ``target`` (the stage's runs) with the config ``files``; Snakemake's output goes to
    ``log``, its progress to the terminal every tenth. A failure is one CapeError naming
    the log."""
    cmd = [sys.executable, "-m", "snakemake", "-s", snakefile(), target, "--configfile", *files]
    if not any(a.startswith(("--cores", "-c")) for a in extra):
        cmd += ["--cores", str(cores)]
    cmd += list(extra)
    log.parent.mkdir(parents=True, exist_ok=True)
    # appended, line by line: a resumed stage keeps its earlier attempts; `tail -f` follows it
    with open(log, "a", buffering=1) as out:
        out.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')}\n$ " + shlex.join(cmd) + "\n")
        out.flush()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # its progress as it happens, not at exit
        # its own session: stopping the command (SIGTERM, Ctrl-C) stops Snakemake and its jobs
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            env=env,
            start_new_session=True,
        )
        assert proc.stdout is not None
        try:
            shown = -1
            for line in proc.stdout:
                out.write(line)
                done = re.search(r"(\d+) of (\d+) steps \((\d+)%\) done", line)
                if done and (int(done[3]) // 10 > shown or done[1] == done[2]):
                    shown = int(done[3]) // 10
                    print(f"  {what}: {done[0]}", flush=True)
            status = proc.wait()
        except BaseException:  # stopped: Snakemake and its jobs with it, then the next run resumes
            from cape.processes import stop

            stop(proc, grace=STOP_GRACE)
            raise
    if status != 0:
        raise CapeError(
            f"{what}: Snakemake failed (exit {status}); its output, with the failed job and its "
            f"log, is in {log}. Fix that, then run `cape question` again: it resumes"
        )


def snakefile() -> str:
    """The workflow's Snakefile: the working folder's, else the checkout's the package is in."""
    from cape.config import REPO_ROOT

    here = Path("Snakefile")
    return str(here if here.is_file() else REPO_ROOT / "Snakefile")


@command(
    "question",
    "the ground-truth question in stages: draws added until every row is settled",
    _arguments,
)
def cmd_question(args: argparse.Namespace) -> None:
    if args.rederive:
        return _rederive(Path(args.rederive))
    if args.publish:
        return _publish(args, Path(args.publish))
    from cape.specs.study import StudySpec
    from cape.storage.io import write_text
    from cape.storage.ownership import Output
    from cape.study.claims.leaderboard import recipe
    from cape.study.question import report
    from cape.study.question.looks import (
        RowState,
        evaluate,
        next_draws,
        next_seeds,
        seed_values,
        values_frame,
    )
    from cape.study.question.plan import Plan, QuestionSettings, run_overrides
    from cape.study.question.state import QuestionState

    extra = [a for a in args.snakemake_args if a != "--"]
    files = [*DEFAULT_FILES[: 1 if args.no_question_config else 2], *args.configfile]
    config = merged_config(files)
    settings = QuestionSettings.from_config(config, " + ".join(files))
    study = StudySpec.from_config(config)
    design = settings.design()
    states = [RowState(row) for row in settings.rows()]
    logs = [Path(paths.QUESTION, "logs", f"stage{k + 1}.log") for k in range(len(settings.stages))]
    outputs = [paths.QUESTION_STAGE, paths.QUESTION_LOOKS, paths.QUESTION_STATE,
               paths.QUESTION_REPORT, paths.QUESTION_COMPONENTS, paths.QUESTION_VALUES, *logs,
               Path(paths.QUESTION, "logs", "notebook.log")]  # fmt: skip
    identity = settings.identity(dict(study.models))
    record = QuestionState.read(identity)  # refused: nothing changed
    published = _published(args, identity, record)
    if not args.dry_run:
        _claim(args, *(Output(Path(p), "question report", option="output") for p in outputs))
    draws = {m: settings.stages[0] for m in settings.models}
    seeds = [settings.seeds] * settings.stages[0]
    started = time.perf_counter()
    components = None
    seeds_said = f"the study's {settings.seeds}"
    print(
        f"cape question: {len(states)} rows ({len(settings.claims())} metrics × "
        f"{len(settings.claims()[0].pairs)} pairs of {', '.join(settings.models)}); looks at "
        f"{', '.join(map(str, settings.stages))} draws per model; family-wise α "
        f"{settings.alpha:g} (each row {design.per_row:.2g}, spent over the looks); futility "
        f"below a {settings.futility:.0%} chance of settling",
        flush=True,
    )
    stages: list[dict[str, Any]] = []
    for k, n in enumerate(settings.stages):
        plan = Plan(draws, tuple(seeds), _reused(published, settings, draws, seeds))
        overrides = run_overrides(study, settings, plan)
        stage_files = [*files, paths.QUESTION_STAGE]
        if args.dry_run:
            import yaml

            print(yaml.safe_dump(overrides, sort_keys=False).rstrip())
            print("$ snakemake question --configfile " + " ".join(stage_files))
            return
        write_text(paths.QUESTION_STAGE, _yaml(overrides))
        print(
            f"stage {k + 1}/{len(settings.stages)}: draws "
            + ", ".join(f"{m.upper()} {d}" for m, d in draws.items())
            + f"; seeds per draw {report.seed_runs(seeds)}",
            flush=True,
        )
        tick = time.perf_counter()
        try:
            _snakemake(stage_files, args.cores, extra, logs[k], f"stage {k + 1}")
        except BaseException:  # stopped or failed: its wall time so far is kept for the resume
            record.stopped[k + 1] = round(time.perf_counter() - tick + record.wall_before(k + 1), 1)
            record.looks, record.seeds = stages, seeds
            write_text(paths.QUESTION_STATE, record.as_json())
            raise
        runs = report.read_stage_runs(settings, plan)
        values = {} if runs is None else seed_values(runs, settings.rows())
        if published is not None:
            values = published.merge(values, plan.reused)
        write_text(paths.QUESTION_VALUES, values_frame(values).to_csv(index=False))
        cost = report.costs(settings, plan)
        most = _most(published, plan, k, report.most_seeds(settings, cost))
        evaluate(values, states, design, k, most)
        wall = time.perf_counter() - tick + record.wall_before(k + 1)
        record.stopped.pop(k + 1, None)
        if k + 1 < len(settings.stages) and not all(s.done for s in states):
            following = next_draws(states, draws, settings.stages[k + 1])
            planned = record.seeds[len(seeds) : settings.stages[k + 1]]
            if len(planned) == settings.stages[k + 1] - len(seeds):  # a resumed run's own
                chosen, components = planned[0], None
                seeds_said = "as this question's first run chose (looks.json)"
            else:
                chosen, components, seeds_said = next_seeds(
                    states, design, k, draws, cost, settings, most
                )
            seeds = seeds + [chosen] * (settings.stages[k + 1] - len(seeds))
        line = report.stage_record(k, n, draws, states, cost, wall, seeds, most)
        stages.append(_as_published(line, published, plan, k))
        record.looks, record.seeds = stages, seeds
        write_text(paths.QUESTION_LOOKS, report.looks_frame(states).to_csv(index=False))
        write_text(paths.QUESTION_STATE, record.as_json())
        if components is not None:
            write_text(paths.QUESTION_COMPONENTS, components.to_csv(index=False))
        later = seeds[-1]
        remaining = report.remaining(states, settings, draws, cost, later)
        walls = {
            c: report.projected_wall(states, settings, draws, cost, later, c)
            for c in dict.fromkeys((2, args.project_cores))
        }
        write_text(
            paths.QUESTION_REPORT,
            report.markdown(
                settings,
                design,
                states,
                stages,
                components,
                seeds_said,
                remaining,
                walls,
                {m: recipe(study.models[m]) for m in settings.models},
                report.further_draw(cost, settings, later),
            ),
        )
        finished = all(s.done for s in states)
        print(f"stage {k + 1}: " + report.summary_line(states, cost, finished, remaining, walls),
              flush=True)  # fmt: skip
        if finished:
            break
        if k + 1 < len(settings.stages):
            draws = following
    notebook = paths.scoped(paths.QUESTION, "notebooks", "question.ipynb")
    _snakemake(stage_files, args.cores, extra, Path(paths.QUESTION, "logs", "notebook.log"),
               "the report's notebook", notebook)  # fmt: skip
    wall = time.perf_counter() - started
    print(
        f"cape question: report in {paths.QUESTION_REPORT}, figure 15 and table 10 in "
        f"{notebook} ({wall:,.0f} s)",
        flush=True,
    )


def _yaml(value: Any) -> str:
    import yaml

    return yaml.safe_dump(value, sort_keys=False)


def _rederive(folder: Path) -> None:
    """``--from``: re-decide a published question's looks, then compare them with its own."""
    from cape.study.question import publish

    state, values, published = publish.read_folder(folder)
    derived = publish.rederive(state, values)
    wrong = publish.differences(derived, published, str(folder / "looks.csv"))
    if wrong:
        raise CapeError(
            f"{folder / 'looks.csv'}: the re-derivation from values.csv differs in {len(wrong)} "
            f"place(s), first {wrong[0]}; the published data do not give the published looks"
        )
    rows = derived[["claim", "comparison"]].drop_duplicates().shape[0]
    exact = derived.to_csv(index=False).encode() == (folder / "looks.csv").read_bytes()
    print(
        f"cape question --from {folder}: {len(derived)} looks of {rows} rows re-decided from "
        f"values.csv; every decision {'and number identical to' if exact else 'equal to'} "
        f"looks.csv{'' if exact else f' (numbers within {publish.TOLERANCE:g})'}"
    )


def _publish(args: argparse.Namespace, folder: Path) -> None:
    """``--publish``: results/question/'s answer, copied with its provenance."""
    import shutil

    from cape.storage.io import write_text
    from cape.storage.ownership import Output
    from cape.study.question import publish
    from cape.study.question.state import QuestionState

    source = Path(paths.QUESTION)
    missing = [n for n in publish.COPIED if not (source / n).is_file()]
    if any(n in publish.REQUIRED for n in missing):
        raise CapeError(
            f"{source}: no look to publish ({', '.join(missing)} missing); run `cape question` "
            "first"
        )
    files = [*DEFAULT_FILES[: 1 if args.no_question_config else 2], *args.configfile]
    config = merged_config(files)
    state = QuestionState.load(source / "looks.json", "run `cape question` again: it rewrites it")
    names = [n for n in publish.COPIED if n not in missing]
    _claim(args, *(Output(folder / n, "published question", option="--publish") for n in
                   [*names, *publish.DRAWN, paths.QUESTION_PROVENANCE]))  # fmt: skip
    for name in names:
        target = folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source / name, target)
    publish.draw(folder)
    record = publish.provenance(config, state)
    write_text(folder / paths.QUESTION_PROVENANCE, json.dumps(record, indent=1, default=str))
    count = len(names) + len(publish.DRAWN) + 1
    print(f"cape question --publish: {count} files in {folder}" +
          (f" ({', '.join(missing)} not there yet)" if missing else ""))  # fmt: skip


def _published(args: argparse.Namespace, identity: dict[str, Any], record: Any) -> Any:
    """``--reuse``: the published question to continue from (its design must be this one's);
    with no look of its own yet, the record takes the published seeds of each draw."""
    if not args.reuse:
        return None
    from cape.study.question.publish import Published

    published = Published(Path(args.reuse), identity)
    if not record.looks and len(published.state.seeds) > len(record.seeds):
        record.seeds = list(published.state.seeds)
    return published


def _reused(published: Any, settings: Any, draws: dict[str, int], seeds: list[int]) -> frozenset:
    """The stage's draws whose values the published question holds on their planned seeds."""
    if published is None:
        return frozenset()
    claims = sorted({row.name for row in settings.rows()})
    return frozenset(
        (m, r)
        for m, d in draws.items()
        for r in range(d)
        if published.covers(m, r, settings.draw_seeds(r, seeds[r]), claims)
    )


def _as_published(line: dict[str, Any], published: Any, plan: Any, k: int) -> dict[str, Any]:
    """A stage's line; where every draw of the stage was reused, its CPU, wall time and
    trainings are the published stage's (nothing ran here to measure them)."""
    every = {(m, r) for m, d in plan.draws.items() for r in range(d)}
    earlier = published.stage(k) if published is not None else None
    if earlier is None or not every or not every <= plan.reused:
        return line
    keep = ("cpu_s", "wall_s", "trainings tried", "trainings failed", "cpu by model", "runs_s")
    return {**line, **{key: earlier[key] for key in keep if key in earlier}, "reused": True}


def _most(published: Any, plan: Any, k: int, measured: int) -> int:
    """The most seeds futility assumes at stage ``k``: the published stage's where all its
    draws were reused (its costs were measured there, not here), else ``measured``."""
    earlier = published.stage(k) if published is not None else None
    every = {(m, r) for m, d in plan.draws.items() for r in range(d)}
    if earlier is not None and every <= plan.reused and earlier.get("most seeds") is not None:
        return int(earlier["most seeds"])
    return measured
