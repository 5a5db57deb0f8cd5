"""``cape question``: the ground-truth question answered in stages (SPEC §10, revision 6).

Stage by stage it writes the plan (results/question/stage.yaml), runs Snakemake's ``question``
target with it (the trainings, draws, solvers and runs the stage's rows read, nothing else),
looks at every open row, and adds draws only to the models of rows still open, until every row
is settled or the last stage is looked at. Killed, it resumes: a rerun goes through the stages
again, Snakemake redoes only what is missing, and the looks are the same (they are computed
from the runs). The report: results/question/RESULTS.md, looks.csv and looks.json, after every
stage. How to read it: docs/question.md. This command parses, calls and prints: the stages are
run by ``cape.study.question.run.QuestionRun``, Snakemake by ``cape.workflow.launch``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cape.cli.common import CORES, claim, command
from cape.errors import CapeError
from cape.layout import paths

DEFAULT_FILES = ("config/config.yaml", "config/question.yaml")


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
    _actions(p)


def _actions(p: argparse.ArgumentParser) -> None:
    """What else the command does than run the stages: plan only, re-derive, reuse, publish;
    and the arguments every Snakemake run gets."""
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
    from cape.storage.ownership import Output
    from cape.study.question.run import QuestionRun
    from cape.workflow.launch import Snakemake

    extra = [a for a in args.snakemake_args if a != "--"]
    run = QuestionRun(_files(args), args.reuse, Snakemake(args.cores, extra), args.project_cores)
    if not args.dry_run:
        claim(args, *(Output(p, "question report", option="output") for p in run.outputs()))
    print(run.opening(), flush=True)
    while (stage := run.next_stage()) is not None:
        if args.dry_run:
            return print(run.dry_run(stage))
        print(run.announced(stage), flush=True)
        run.run(stage)
        print(run.look(stage), flush=True)
    print(run.finish(), flush=True)


def _files(args: argparse.Namespace) -> list[str]:
    """The config files, in the order they are merged."""
    return [*DEFAULT_FILES[: 1 if args.no_question_config else 2], *args.configfile]


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

    from cape.config import merged_config
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
    config = merged_config(_files(args))
    state = QuestionState.load(source / "looks.json", "run `cape question` again: it rewrites it")
    names = [n for n in publish.COPIED if n not in missing]
    claim(args, *(Output(folder / n, "published question", option="--publish") for n in
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
