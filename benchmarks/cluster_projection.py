"""Project a replicated study's wall time on a cluster from a finished study's measurements: R
draws on N nodes of C cores, as the SLURM profile submits the jobs (docs/cluster.md).

    python benchmarks/cluster_projection.py [--draws 3 10 30] [--nodes 1 8 64] [--cores 2]
        [--queue-wait 0] [--run-overhead S] [--group-overhead S] [--configfile ...]

Run it from a replicated study's folder (`snakemake --cores 2 all replicates`), with its config.
What it reads, per measured draw (0, 1, …; draw 0 also computes, once, the runs no draw's
network enters, such as the ground-truth car with its true model):
  - each model's trainings for the draw, CPU seconds from their benchmark files; a model's
    retries after a failed training run one after another (the health decides a retry);
  - the draw's solver builds (benchmark files), each after its internal model's trainings;
  - every run of the draw (timing.json: the fixed part and the lap), grouped as the profile
    groups them, one draw at one η and one seed per submission on one core, plus
    ``--run-overhead`` per run and ``--group-overhead`` per submission (the Snakemake process
    in the job), both measured through SLURM (docs/cluster.md); a group waits for all of its
    draw's trainings and solvers;
  - the tail after the last run: the replicates scope's aggregation and the longest
    closed-loop notebook (benchmark files).
Draw 0 of the projection is measured draw 0; draw d > 0 repeats measured draw 1 + (d − 1) mod
(M − 1). The jobs are list-scheduled on N × C
single-core slots, trainings first, each start ``--queue-wait`` seconds after its job is ready
(the site's queue; 0 on an idle cluster). Not modelled: the node a job lands on, memory, and
the main Snakemake process's own pace on the login node.
"""

from __future__ import annotations

import argparse
import heapq
import math
import sys
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from _common import add_config, listed, run, study_config  # a sibling module
from draw_cost import benchmark_cpu, draw_runs, draw_trainings, fixed_part, solver_files

from cape.errors import CapeError
from cape.layout import paths


@dataclass
class Draw:
    """One measured draw: each model's trainings (s, seed order), its solver builds (internal
    model → s), its rollout groups ((η, seed) → seconds of runs and how many)."""

    trainings: dict[str, list[float]] = field(default_factory=dict)
    solvers: list[tuple[str, float]] = field(default_factory=list)
    groups: dict[tuple[float, str], list[float]] = field(default_factory=dict)


def measure_draw(config: dict, replicate: int, lacking: list[str]) -> Draw:
    """Draw ``replicate``'s measured jobs (a missing file goes to ``lacking``)."""
    draw = Draw()
    for model in config["models"]:
        seeds = draw_trainings(model, replicate, lacking) or []
        files = [Path(paths.benchmark("train", model, f"seed{s}.tsv")) for s in seeds]
        draw.trainings[model] = list(benchmark_cpu(files, lacking).values())
    for path, seconds in benchmark_cpu(solver_files(replicate, None), lacking).items():
        draw.solvers.append((Path(path).stem.removesuffix("-fixed"), seconds))
    groups: dict[tuple[float, str], list[float]] = defaultdict(list)
    for r in draw_runs(config, replicate, None, lacking, every=True):
        groups[(r["eta"], r["seed"])].append(fixed_part(r) + r["lap"])
    draw.groups = dict(groups)
    return draw


def tail_seconds(lacking: list[str]) -> float:
    """The replicates scope's aggregation, then its longest closed-loop notebook."""
    aggregate = Path(paths.scoped(paths.REPLICATES_SCOPE, "benchmarks", "study", "aggregate.tsv"))
    notebooks = sorted(Path(paths.benchmark("notebooks")).glob("*.tsv"))
    if not notebooks:
        lacking.append(f"{paths.benchmark('notebooks')}/*.tsv (the closed-loop notebooks)")
    measured = benchmark_cpu([aggregate, *notebooks], lacking)
    notebook = max((measured[str(p)] for p in notebooks if str(p) in measured), default=0.0)
    return measured.get(str(aggregate), 0.0) + notebook


@dataclass(order=True)
class Job:
    rank: tuple[int, int, int]
    seconds: float = field(compare=False)
    after: list[int] = field(compare=False, default_factory=list)


def study_jobs(draws: list[Draw], count: int, run_s: float, group_s: float) -> list[Job]:
    """The jobs of ``count`` draws: draw 0 is measured draw 0 (it also computes the runs no
    draw's network enters, once), draw d > 0 repeats measured draw 1 + (d - 1) mod (M - 1)."""
    jobs: list[Job] = []

    def add(kind: int, d: int, seconds: float, after: list[int]) -> int:
        jobs.append(Job((kind, d, len(jobs)), seconds, after))
        return len(jobs) - 1

    for d in range(count):
        draw = draws[0] if d == 0 else draws[1 + (d - 1) % (len(draws) - 1)]
        last: dict[str, list[int]] = {}
        for model, seconds in draw.trainings.items():
            chain: list[int] = []
            for s in seconds:  # a retry waits for the training before it
                chain.append(add(0, d, s, chain[-1:]))
            last[model] = chain[-1:]
        solvers = [add(1, d, s, last.get(model, [])) for model, s in draw.solvers]
        everything = [j for chain in last.values() for j in chain] + solvers
        for runs in draw.groups.values():
            add(2, d, group_s + sum(t + run_s for t in runs), everything)
    return jobs


def makespan(jobs: list[Job], slots: int, queue_wait: float) -> float:
    """When the last job ends: each job may start ``queue_wait`` s after the jobs it waits for
    have ended, on a free slot, the available ones in rank order (trainings, solvers, groups;
    then draw)."""
    waiting = [len(j.after) for j in jobs]
    needed_by: dict[int, list[int]] = defaultdict(list)
    for i, job in enumerate(jobs):
        for k in job.after:
            needed_by[k].append(i)
    queued = [(queue_wait, job.rank, i) for i, job in enumerate(jobs) if not job.after]
    heapq.heapify(queued)  # (when it may start, rank, job)
    available: list[tuple[tuple[int, int, int], int]] = []
    running: list[tuple[float, int]] = []  # (when it ends, job)
    now, free = 0.0, slots
    while queued or available or running:
        while queued and queued[0][0] <= now:
            _, rank, i = heapq.heappop(queued)
            heapq.heappush(available, (rank, i))
        while free and available:
            _, i = heapq.heappop(available)
            heapq.heappush(running, (now + jobs[i].seconds, i))
            free -= 1
        now = min([t for t, _ in running[:1]] + [t for t, _, _ in queued[:1]])
        while running and running[0][0] <= now:
            _, k = heapq.heappop(running)
            free += 1
            for n in needed_by[k]:
                waiting[n] -= 1
                if not waiting[n]:
                    heapq.heappush(queued, (now + queue_wait, jobs[n].rank, n))
    return now


def hours(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes // 60}:{minutes % 60:02d}"


def _bounded(kind: type, low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number of ``kind`` from ``low`` to ``high``."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value) or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text} is not from {low:g} to {high:g}")
        return value

    return parse


def main() -> int:
    from cape.cli import OneLineParser

    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    count = _bounded(int, 1, 1000)
    parser.add_argument("--draws", type=count, nargs="+", default=[3, 10, 30], help="R")
    parser.add_argument("--nodes", type=_bounded(int, 1, 100_000), nargs="+", default=[1, 8, 64],
                        help="N")  # fmt: skip
    parser.add_argument("--cores", type=_bounded(int, 1, 1024), default=2, help="C, per node")
    parser.add_argument("--queue-wait", type=_bounded(float, 0, 86_400), default=0.0,
                        help="s a job queues")  # fmt: skip
    parser.add_argument(
        "--run-overhead",
        type=_bounded(float, 0, 3600),
        default=0.1,
        help="s per run in a group beyond its timing.json (measured: 0.05–0.08)",
    )
    parser.add_argument("--group-overhead", type=_bounded(float, 0, 3600), default=2.0,
                        help="s per submission: its Snakemake process (measured: 1–2)")  # fmt: skip
    add_config(parser)
    args = parser.parse_args()
    config = study_config(args)
    replicates = int(config["training"]["replicates"])
    if replicates < 2:
        raise CapeError("the study has one draw: build `snakemake --cores 2 all replicates` "
                        "with training.replicates ≥ 2 to measure a draw of its own")  # fmt: skip
    lacking: list[str] = []
    draws = [measure_draw(config, r, lacking) for r in range(replicates)]
    tail = tail_seconds(lacking)
    if lacking:
        print(f"not projected: this study lacks {len(lacking)} part(s), which would count as 0 s:")
        print("  " + listed(lacking, 10))
        return 0

    for r, draw in enumerate(draws):
        runs = [t for g in draw.groups.values() for t in g]
        trained = ", ".join(f"{m} {sum(s):.0f} s ({len(s)})" for m, s in draw.trainings.items())
        print(f"draw {r}: trainings {trained}; {len(draw.solvers)} solver builds "
              f"{sum(s for _, s in draw.solvers):.0f} s; {len(runs)} runs {sum(runs):.0f} s in "
              f"{len(draw.groups)} groups (largest {max(map(len, draw.groups.values()))} runs, "
              f"{max(map(sum, draw.groups.values())):.0f} s)")  # fmt: skip
    print(f"tail: {tail:.0f} s (aggregation and the longest closed-loop notebook)")
    overheads = (args.run_overhead, args.group_overhead)
    first = sum(j.seconds for j in study_jobs(draws, 1, *overheads))
    more = (sum(j.seconds for j in study_jobs(draws, len(draws), *overheads)) - first) / (
        len(draws) - 1
    )
    path = makespan(study_jobs(draws, len(draws), *overheads), 10**6, args.queue_wait)
    print(f"work: draw 0 {first / 3600:.2f} CPU hours (with the runs computed once), a further "
          f"draw {more / 3600:.2f}; critical path {hours(path)} (h:mm, unlimited cores) "
          "+ the tail")  # fmt: skip
    print(f"\nwall time (h:mm) on N nodes of {args.cores} cores, queue wait "
          f"{args.queue_wait:g} s per job")  # fmt: skip
    print("| R draws | " + " | ".join(f"N = {n}" for n in args.nodes) + " |")
    print("|---:|" + "---:|" * len(args.nodes))
    for count in args.draws:
        jobs = study_jobs(draws, count, args.run_overhead, args.group_overhead)
        cells = [hours(makespan(jobs, n * args.cores, args.queue_wait) + tail) for n in args.nodes]
        print(f"| {count} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(run(main))
