"""Project a replicated study's wall time on a cluster from a finished study's measurements: R
draws on N nodes of C cores, as the SLURM profile submits the jobs (docs/cluster.md).

    python benchmarks/cluster_projection.py [--draws 3 10 30] [--nodes 1 8 64] [--cores 2]
        [--queue-wait 0] [--run-overhead S] [--group-overhead S] [--configfile ...]

Run it from a replicated study's folder (`snakemake --cores 2 all replicates`), with its config.
What it reads, per measured draw (0, 1, …; draw 0 also computes the runs of the studies only it
has; since SPEC §10 revision 7 every draw runs its own seeds, its runs without a network too):
  - each model's trainings for the draw, failed ones included (``draw_cost.draw_trainings``:
    the draws that reached training.max_trainings share the trainings after the last that
    passed), CPU seconds from their benchmark files; and from them each model's measured
    failure rate and mean training;
  - the draw's solver builds (benchmark files), each after its internal model's trainings;
  - every run of the draw (timing.json: the fixed part and the lap), grouped as the profile
    groups them, one draw at one η and one seed per submission on one core, plus
    ``--run-overhead`` per run and ``--group-overhead`` per submission (the Snakemake process
    in the job), both measured through SLURM (docs/cluster.md); a group waits for all of its
    draw's trainings and solvers;
  - the tail after the last run: the replicates scope's aggregation and the longest
    closed-loop notebook (benchmark files).
Draw 0 of the projection is measured draw 0; draw d > 0 repeats measured draw 1 + (d − 1) mod
(M − 1), its solvers and runs. Its trainings are projected, not repeated: each draw of R takes,
per model, the bounded expectation E[min(τ, cap)] / R of trainings (``expected_trainings``; τ
the trainings until R pass at the model's measured failure rate, cap training.max_trainings,
2 × R when null), each of the model's mean measured training, one after another (a retry waits
for the training before it; a fraction of a training is that fraction of its seconds). Not
1 / (1 − rate): it is unbounded as the rate nears 1, while the workflow stops at the cap and
gives the further draws failed stand-ins. The jobs are list-scheduled on N × C
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
from dataclasses import dataclass, field, replace
from pathlib import Path

from _common import add_config, listed, run, study_config  # a sibling module
from draw_cost import benchmark_cpu, draw_runs, draw_trainings, fixed_part, solver_files

from cape.errors import CapeError
from cape.layout import paths
from cape.training.draws import default_max_trainings


@dataclass
class Draw:
    """One draw: each model's trainings (s, seed order; a shared one, the draw's share), its
    solver builds (internal model → s), its rollout groups ((η, seed) → seconds of runs and
    how many); measured, each model's trainings it took (seed → CPU s, passed; a shared one
    whole) and how many (a shared one counts 1/n)."""

    trainings: dict[str, list[float]] = field(default_factory=dict)
    solvers: list[tuple[str, float]] = field(default_factory=list)
    groups: dict[tuple[float, str], list[float]] = field(default_factory=dict)
    took: dict[str, dict[int, tuple[float, bool | None]]] = field(default_factory=dict)
    counts: dict[str, float] = field(default_factory=dict)


def measure_draw(config: dict, replicate: int, lacking: list[str]) -> Draw:
    """Draw ``replicate``'s measured jobs (a missing file goes to ``lacking``)."""
    draw = Draw()
    replicates = int(config["training"]["replicates"])
    for model in config["models"]:
        took = draw_trainings(model, replicate, replicates, lacking) or []
        files = [Path(paths.benchmark("train", model, f"seed{t.seed}.tsv")) for t in took]
        measured = benchmark_cpu(files, lacking)
        draw.trainings[model], draw.took[model] = [], {}
        for t, path in zip(took, files, strict=True):
            if str(path) in measured:
                draw.trainings[model].append(measured[str(path)] / t.sharing)
                draw.took[model][t.seed] = (measured[str(path)], t.trained)
        draw.counts[model] = sum(1 / t.sharing for t in took)
    for path, seconds in benchmark_cpu(solver_files(replicate, None), lacking).items():
        draw.solvers.append((Path(path).stem.removesuffix("-fixed"), seconds))
    groups: dict[tuple[float, str], list[float]] = defaultdict(list)
    for r in draw_runs(config, replicate, None, lacking, every=True):
        groups[(r["eta"], r["seed"])].append(fixed_part(r) + r["lap"])
    draw.groups = dict(groups)
    return draw


@dataclass(frozen=True)
class Recipe:
    """A model's measured trainings over every draw: how many, how many failed, their mean
    CPU seconds."""

    tried: int
    failed: int
    seconds: float

    @property
    def rate(self) -> float:
        return self.failed / self.tried


def recipes(draws: list[Draw]) -> dict[str, Recipe]:
    """Each model's trainings, failed ones included, from every measured draw (each once)."""
    out = {}
    for model in draws[0].took:
        trainings = {seed: t for d in draws for seed, t in d.took.get(model, {}).items()}
        unknown = sorted(seed for seed, (_, trained) in trainings.items() if trained is None)
        if unknown or not trainings:
            raise CapeError(
                f"{paths.MODELS}: the draws of {model} record "
                + (f"no `trained` for seed {unknown[0]}" if unknown else "no training")
                + " (meta.json's draw.trainings); rebuild them (`snakemake --cores 2 "
                "all replicates`)"
            )
        seconds = [s for s, _ in trainings.values()]
        failed = sum(not trained for _, trained in trainings.values())
        out[model] = Recipe(len(trainings), failed, sum(seconds) / len(seconds))
    return out


def draw_cap(config: dict, count: int) -> int:
    """training.max_trainings for ``count`` draws: the config's, at least ``count`` (the least
    the config accepts), or 2 × ``count`` when it is null (the workflow's default)."""
    cap = config["training"].get("max_trainings")
    return default_max_trainings(count) if cap is None else max(int(cap), count)


def expected_trainings(rate: float, count: int, cap: int) -> float:
    """The trainings a draw takes on average when a model whose trainings fail at ``rate``
    makes ``count`` draws under the cap ``cap``: E[min(τ, cap)] / count, τ the trainings until
    ``count`` of them pass (negative binomial), and E[min(τ, cap)] = Σ_{k < cap} P(τ > k), the
    chance that fewer than ``count`` of k trainings pass. It is 1 at rate 0, cap / count at
    rate 1 (every training fails: the workflow stops at the cap), below 1 / (1 − rate)."""
    import numpy as np
    from scipy.stats import binom

    passes = binom.cdf(count - 1, np.arange(cap), 1.0 - rate)
    return float(passes.sum()) / count


def training_chain(expected: float, seconds: float) -> list[float]:
    """``expected`` trainings of ``seconds`` each, one after another: the whole ones, then
    the fraction as a training of that fraction of the seconds."""
    whole = math.floor(expected + 1e-9)
    rest = expected - whole
    return [seconds] * whole + ([rest * seconds] if rest > 1e-9 else [])


def projected(draws: list[Draw], models: dict[str, Recipe], count: int, cap: int) -> list[Draw]:
    """The measured draws with each model's trainings replaced by the expectation for
    ``count`` draws under ``cap`` (``expected_trainings``)."""
    chains = {m: training_chain(expected_trainings(r.rate, count, cap), r.seconds)
              for m, r in models.items()}  # fmt: skip
    return [replace(d, trainings=dict(chains)) for d in draws]


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
        trained = ", ".join(f"{m} {sum(s):.0f} s ({draw.counts[m]:.4g})"
                            for m, s in draw.trainings.items())  # fmt: skip
        print(f"draw {r}: trainings {trained}; {len(draw.solvers)} solver builds "
              f"{sum(s for _, s in draw.solvers):.0f} s; {len(runs)} runs {sum(runs):.0f} s in "
              f"{len(draw.groups)} groups (largest {max(map(len, draw.groups.values()))} runs, "
              f"{max(map(sum, draw.groups.values())):.0f} s)")  # fmt: skip
    print(f"tail: {tail:.0f} s (aggregation and the longest closed-loop notebook)")
    models = recipes(draws)
    counts = sorted({replicates, *args.draws})
    print("trainings per draw, failed ones included: the bounded expectation E[min(τ, cap)] / R "
          "(τ: the trainings until R pass at the measured failure rate; cap: "
          "training.max_trainings, 2 × R when null), not 1 / (1 − rate), each of the mean "
          "measured training")  # fmt: skip
    for model, recipe in models.items():
        expected = ", ".join(
            f"R = {c}: {expected_trainings(recipe.rate, c, draw_cap(config, c)):.4g} "
            f"(cap {draw_cap(config, c)})" for c in counts
        )  # fmt: skip
        print(f"  {model}: {recipe.tried} trainings, {recipe.failed} failed "
              f"({recipe.rate:.0%}), mean {recipe.seconds:.0f} s; per draw {expected}")  # fmt: skip
    overheads = (args.run_overhead, args.group_overhead)
    study = projected(draws, models, replicates, draw_cap(config, replicates))
    first = sum(j.seconds for j in study_jobs(study, 1, *overheads))
    more = (sum(j.seconds for j in study_jobs(study, len(draws), *overheads)) - first) / (
        len(draws) - 1
    )
    path = makespan(study_jobs(study, len(draws), *overheads), 10**6, args.queue_wait)
    print(f"work: draw 0 {first / 3600:.2f} CPU hours (with the runs computed once), a further "
          f"draw {more / 3600:.2f}; critical path {hours(path)} (h:mm, unlimited cores) "
          "+ the tail")  # fmt: skip
    print(f"\nwall time (h:mm) on N nodes of {args.cores} cores, queue wait "
          f"{args.queue_wait:g} s per job")  # fmt: skip
    print("| R draws | " + " | ".join(f"N = {n}" for n in args.nodes) + " |")
    print("|---:|" + "---:|" * len(args.nodes))
    for count in args.draws:
        plan = projected(draws, models, count, draw_cap(config, count))
        jobs = study_jobs(plan, count, args.run_overhead, args.group_overhead)
        cells = [hours(makespan(jobs, n * args.cores, args.queue_wait) + tail) for n in args.nodes]
        print(f"| {count} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(run(main))
