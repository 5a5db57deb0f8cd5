"""What one more training draw costs in a finished replicated study (`snakemake --cores 2 all
replicates`): the CPU of its trainings, solvers and every run that uses its networks (the
learned study's, and the ground-truth study's with a learned internal model), split into
training, a job's fixed part, the plant's Φ, the controller's step (solve, internal Φ and any
rescue) and the loop around them; then an NMPC step of a study job by part, per controller and
internal model, and the rescue's success rate and cost.

Training and solver CPU come from the rules' benchmark files (`cpu_time`); a run's phases from
its own timing.json (`job_s`, wall seconds of a single-threaded job: its CPU time, near enough).
What no file records (the interpreter before cape's first import, Snakemake's own work per job)
is left out and said so. A host reference (the same PID and RISE laps in every study) is
printed beside the total, as this machine's speed drifts between studies.

    python benchmarks/draw_cost.py [--replicate 1] [--models dpm ddm epm]
                                   [--configfile config/smoke.yaml]

Run it from the study's folder, with the config the study was built with (``--configfile``):
every file is looked for where the workflow writes it (``cape.layout.paths``), and the runs of
the draw are the config's grid (``cape.study.grid``). A draw's trainings are every training
it took, failed ones included (``draw_trainings``): those its ``meta.json`` says were consulted
for it and not for the draw before it; and when the model reached ``training.max_trainings``
(too few trainings passed), the trainings after its last passed one, shared equally by the
draws that reached the cap (each counts 1/n of them). Over the study's draws every training is
counted once. A study that lacks a part (a training's or a solver's benchmark file, a draw, a
run not computed yet) is told what it lacks and given no total: a missing part is never
counted as zero. A damaged file (an empty
benchmark TSV, a truncated timing.json, a run folder without its metrics.json) ends the script
with one line naming the file and the fix, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from _common import add_config, listed, run, study_config  # a sibling module

from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import TRUTH
from cape.layout.record import read_metrics, read_timing
from cape.layout.runs import RunId
from cape.storage.io import read_benchmark, read_json


def cpu_of(path: Path) -> float:
    """``cpu_time`` of a Snakemake benchmark file (its first row), else its wall ``s``."""
    row = read_benchmark(path).iloc[0]
    value = row.get("cpu_time")
    try:
        value = float(value)
    except (TypeError, ValueError):
        value = float("nan")
    return value if value == value else float(row["s"])  # NaN: Snakemake could not measure


@dataclass(frozen=True)
class Took:
    """A training a draw took: its seed, whether it passed its checks (None: the draw's
    meta.json does not say) and how many draws share it (1: this draw's alone)."""

    seed: int
    trained: bool | None
    sharing: int = 1


def read_draw(model: str, replicate: int, lacking: list[str]) -> tuple[Path, dict, bool] | None:
    """Draw ``replicate`` of ``model``'s meta.json: its path, the trainings it consulted
    (seed → passed, None when not recorded) and whether it reached training.max_trainings;
    None when the draw is not built (said in ``lacking``)."""
    path = Path(paths.model_dir(model, replicate), paths.META)
    if not path.is_file():
        lacking.append(f"{path} (draw {replicate} of {model}: `snakemake --cores 2 {path}`)")
        return None
    fix = f"delete it and rebuild it with `snakemake --cores 2 {path}`"
    meta = read_json(path, "a model's meta.json", fix)
    try:
        record = meta["draw"]
        outcomes: dict[int, bool | None] = {}
        for t in record["trainings"]:
            trained = t.get("trained")
            if trained is not None and not isinstance(trained, bool):
                raise ValueError
            outcomes[int(t["seed"])] = trained
        cap_reached = record.get("cap_reached", False)
        if not isinstance(cap_reached, bool):
            raise ValueError
    except (KeyError, TypeError, ValueError, AttributeError):
        raise CapeError(
            f"{path}: no `draw.trainings` (the trainings consulted for the "
            f"draw) with their seeds and outcomes; {fix}"
        ) from None
    return path, dict(sorted(outcomes.items())), cap_reached


def draw_trainings(
    model: str, replicate: int, replicates: int, lacking: list[str]
) -> list[Took] | None:
    """The trainings of ``model`` that draw ``replicate`` took, failed ones included (its
    ``meta.json``'s ``draw.trainings``), or None (said in ``lacking``):

    - a draw that found its training (the (r + 1)-th that passed) took the trainings it
      consulted and the draw before it did not: the failed ones since that draw's, and its own;
    - the draws that reached ``training.max_trainings`` (P of the model's trainings passed,
      fewer than the ``replicates`` draws) share the trainings after the last that passed:
      each of those R − P draws takes 1/(R − P) of every one of them.

    So each training the model ran is counted once over the study's draws, and a draw whose
    trainings all failed costs its share of them, never 0 s."""
    mine = read_draw(model, replicate, lacking)
    if mine is None:
        return None
    path, outcomes, cap_reached = mine
    if cap_reached:
        if None in outcomes.values():
            raise CapeError(f"{path}: `draw.trainings` records no `trained` for a training; "
                            f"rebuild it with `snakemake --cores 2 {path}`")  # fmt: skip
        passed = [seed for seed, trained in outcomes.items() if trained]
        if not len(passed) <= replicate < replicates:
            raise CapeError(
                f"{path}: draw {replicate} reached training.max_trainings with "
                f"{len(passed)} trainings passed, which a study of training.replicates "
                f"{replicates} does not make; give the config the study was built with"
            )
        after = [seed for seed in outcomes if not passed or seed > passed[-1]]
        return [Took(seed, outcomes[seed], replicates - len(passed)) for seed in after]
    before = read_draw(model, replicate - 1, lacking) if replicate > 0 else (path, {}, False)
    if before is None:
        return None
    return [Took(seed, trained) for seed, trained in outcomes.items() if seed not in before[1]]


def benchmark_cpu(files: list[Path], lacking: list[str]) -> dict[str, float]:
    """CPU seconds of each benchmark file (path → s); a missing one goes to ``lacking``."""
    out = {}
    for path in files:
        if path.is_file():
            out[str(path)] = cpu_of(path)
        else:
            lacking.append(f"{path} (its rule has not run here, or ran without its benchmark)")
    return out


def solver_files(replicate: int, models: set[str] | None) -> list[Path]:
    """The benchmark file of every solver build of the draw (its solver record exists)."""
    pattern = paths.solver("*", "*", replicate)
    files = []
    for record in sorted(Path().glob(pattern)):
        controller, internal = record.parent.name, record.stem
        if models is not None and internal.removesuffix("-fixed") not in models:
            continue
        files.append(Path(paths.benchmark("solvers", paths.REP.format(replicate=replicate),
                                          controller, f"{internal}.tsv")))  # fmt: skip
    return files


def draw_runs(
    config: dict[str, Any],
    replicate: int,
    models: set[str] | None,
    lacking: list[str],
    every: bool = False,
) -> list[dict]:
    """The phases of every run of the config's grid that draw ``replicate`` computes with a
    trained network (of ``models`` only, when given; ``every``: with a network or not); a run
    not computed goes to ``lacking``."""
    from cape.specs.study import StudySpec
    from cape.study.grid import study_grid

    rows, absent = [], []
    grid = study_grid(StudySpec.from_config(config))
    for run_id in dict.fromkeys(grid.values()):  # each computed run once
        if run_id.replicate != replicate or not (every or run_id.uses_trained_model()):
            continue
        names = {n.removesuffix("-fixed") for n in (run_id.plant, run_id.internal)} - {TRUTH}
        if models is not None and not names <= models:
            continue
        folder = run_id.folder()
        if not folder.is_dir():
            absent.append(str(folder))
            continue
        timing = read_timing(folder)
        metrics = read_metrics(folder / paths.METRICS)
        job = timing.get("job_s")
        if not isinstance(job, dict):
            raise CapeError(
                f"{folder / paths.TIMING}: no `job_s` (the job's phases: a run of "
                f"an older version); delete {folder} and rerun snakemake"
            )
        rescues = timing.get("rescues") or {}
        rows.append({**job, "study": run_id.study, "law": run_id.controller, "seed": run_id.seed,
                     "internal": run_id.internal, "eta": float(run_id.eta),
                     "parts": timing.get("controller_s") or {},
                     "rescues": int(metrics.get("rescues") or 0),
                     "rescued": rescues.get("succeeded")})  # fmt: skip
    if absent:
        lacking.append(f"{len(absent)} runs not computed ({listed(absent, 3)})")
    return rows


def fixed_part(job: dict) -> float:
    """A job's fixed part (timing.json ``job_s``): start-up, config, build and writing."""
    return job["startup"] + job["config"] + job["build"] + job["write"]


def host_reference() -> str:
    """The same work in every study, a gauge of the machine's speed while it ran: replicate 0's
    ground-truth plant driven by PID and RISE (no network, no solver; unchanged by the speed
    work), per step of their laps and per job's fixed part. Two studies' draw costs compare
    after scaling by it; the host's speed drifts by tens of per cent between hours."""
    lap = steps = fixed = jobs = 0.0
    for law in ("pid", "rise"):
        pattern = RunId("truth", TRUTH, TRUTH, law, "*", "*", 0).folder()  # type: ignore[arg-type]
        for folder in sorted(Path().glob(str(pattern))):
            job = read_timing(folder).get("job_s")
            if not isinstance(job, dict):
                continue
            lap, steps, jobs = lap + job["lap"], steps + job["steps"], jobs + 1
            fixed += fixed_part(job)
    if not jobs:
        return "host reference: no PID or RISE run on the ground-truth plant in replicate 0"
    return (
        f"host reference (replicate 0, ground-truth plant, PID and RISE, {jobs:.0f} runs): "
        f"{1e6 * lap / steps:.0f} µs a step of the lap, {fixed / jobs:.3f} s a job's fixed part"
    )


STEP_PARTS = ("estimate", "internal_phi", "parameters", "solve", "rescue", "adaptation")


def step_breakdown(runs: list[dict]) -> None:
    """An NMPC step of a study job, per controller and internal model: ms per step of each
    part the controller clocks (timing.json controller_s), the rest of its step, the plant's Φ."""
    cells: dict[tuple[str, str], dict[str, float]] = defaultdict(lambda: defaultdict(float))
    for r in runs:
        if not r["parts"]:
            continue
        cell = cells[(r["law"], r["internal"])]
        for name in STEP_PARTS:
            cell[name] += r["parts"].get(name, 0.0)
        cell["other"] += r["controller"] - sum(r["parts"].values())
        cell["plant Φ"] += r["plant"]
        cell["steps"] += r["steps"]
    if not cells:
        print("\n(no timing.json with controller_s: runs computed before the step was clocked)")
        return
    names = (*STEP_PARTS, "other", "plant Φ")
    print("\nan NMPC step inside a study job, ms per step (timing.json controller_s)")
    print(f"{'controller':10} {'internal':9} {'steps':>7} " + " ".join(f"{n:>12}" for n in names)
          + f" {'step':>7}")  # fmt: skip
    for (law, internal), c in sorted(cells.items()):
        per = {n: 1e3 * c[n] / c["steps"] for n in names}
        step = sum(per[n] for n in names if n != "plant Φ")
        print(f"{law:10} {internal:9} {c['steps']:7.0f} "
              + " ".join(f"{per[n]:12.3f}" for n in names) + f" {step:7.3f}")  # fmt: skip


def rescue_table(runs: list[dict]) -> None:
    """How often the rescue (Fatrop or IPOPT) solved a problem the SQP had not, and what it
    cost, per internal model and η band."""
    cells: dict[tuple[str, str], dict[str, float]] = defaultdict(lambda: defaultdict(float))
    for r in runs:
        if r["rescued"] is None or not r["rescues"]:
            continue
        band = "η ≤ 1.5" if r["eta"] <= 1.5 else ("η 2–3.5" if r["eta"] <= 3.5 else "η ≥ 4")
        for key in ((r["internal"], band), (r["internal"], "all")):
            cells[key]["tried"] += r["rescues"]
            cells[key]["succeeded"] += r["rescued"]
            cells[key]["s"] += r["parts"].get("rescue", 0.0)
    if not cells:
        return
    print("\nrescues: tried, succeeded (the SQP had failed), mean ms per rescue")
    for (internal, band), c in sorted(cells.items()):
        rate = c["succeeded"] / c["tried"]
        print(f"  {internal:9} {band:9} {c['tried']:6.0f} {c['succeeded']:6.0f} ({rate:6.1%})"
              f" {1e3 * c['s'] / c['tried']:7.1f} ms")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replicate", type=int, default=1, help="the draw to cost (not 0)")
    parser.add_argument("--budget", type=float, default=2400.0, help="s of CPU a draw may cost")
    parser.add_argument("--models", nargs="+", help="these models' draw only (default: all)")
    add_config(parser)
    args = parser.parse_args()
    if args.replicate < 0:
        parser.error("--replicate: give a draw, 0 or more")
    config = study_config(args)
    trainable = [m for m in config["models"]]
    unknown = [m for m in args.models or [] if m not in trainable]
    if unknown:
        raise CapeError(f"--models {' '.join(unknown)}: not in the config's `models` "
                        f"({', '.join(trainable)})")  # fmt: skip
    models = set(args.models) if args.models else None
    lacking: list[str] = []
    replicates = int(config["training"]["replicates"])
    took: dict[str, Took] = {}  # a training's benchmark file → how the draw took it
    for model in args.models or trainable:
        for t in draw_trainings(model, args.replicate, replicates, lacking) or []:
            took[paths.benchmark("train", model, f"seed{t.seed}.tsv")] = t
    measured = benchmark_cpu([Path(f) for f in took], lacking)
    training = {f: cpu / took[f].sharing for f, cpu in measured.items()}  # the draw's share
    solvers = benchmark_cpu(solver_files(args.replicate, models), lacking)
    runs = draw_runs(config, args.replicate, models, lacking)
    parts: dict[str, float] = defaultdict(float)
    by_cell: dict[tuple[str, str], dict[str, float]] = defaultdict(lambda: defaultdict(float))
    for r in runs:
        fixed = fixed_part(r)
        loop = r["lap"] - r["controller"] - r["plant"]
        for name, value in (("fixed", fixed), ("plant Φ", r["plant"]),
                            ("controller step", r["controller"]), ("loop", loop)):  # fmt: skip
            parts[name] += value
            by_cell[(r["study"], r["law"])][name] += value
        by_cell[(r["study"], r["law"])]["jobs"] += 1
        by_cell[(r["study"], r["law"])]["rescues"] += r["rescues"]
    print(f"replicate {args.replicate}: {len(runs)} runs with its networks")
    count = sum(1 / t.sharing for t in took.values())
    failed = sum(1 / t.sharing for t in took.values() if t.trained is False)
    counted = f"{count:.4g} training{'' if count == 1 else 's'}" + (
        f", {failed:.4g} failed" if all(t.trained is not None for t in took.values()) else ""
    )
    print(f"  training  {sum(training.values()):8.0f} s  ({counted}) "
          + ", ".join(f"{Path(k).parent.name}/{Path(k).stem} {v:.0f}"
                      + (f" (1/{took[k].sharing} of {measured[k]:.0f})"
                         if took[k].sharing > 1 else "")
                      for k, v in training.items()))  # fmt: skip
    if any(t.sharing > 1 for t in took.values()):
        print("            (1/n of a training: one after its model's last passed training, "
              "shared by the n draws that reached training.max_trainings)")  # fmt: skip
    print(f"  solvers   {sum(solvers.values()):8.0f} s  ({len(solvers)} builds)")
    for name, value in parts.items():
        print(f"  {name:15} {value:8.0f} s")
    if lacking:
        print(
            f"  total     not given: this study lacks {len(lacking)} part(s) of the draw, "
            "which would count as 0 s:"
        )
        for item in lacking:
            print(f"    - {item}")
    else:
        total = sum(training.values()) + sum(solvers.values()) + sum(parts.values())
        verdict = "within" if total <= args.budget else "over"
        print(
            f"  total     {total:8.0f} s of CPU ({verdict} the {args.budget:.0f} s budget); not "
            "counted: interpreter start-up before cape's imports, Snakemake's work per job"
        )
    print(f"  {host_reference()}")
    if by_cell:
        print(f"\n{'study':8} {'controller':10} {'jobs':>5} {'fixed':>7} {'plant Φ':>8} "
              f"{'step':>8} {'loop':>6} {'rescues':>8}")  # fmt: skip
    for (study, controller), c in sorted(by_cell.items()):
        print(f"{study:8} {controller:10} {c['jobs']:5.0f} {c['fixed']:7.0f} {c['plant Φ']:8.0f} "
              f"{c['controller step']:8.0f} {c['loop']:6.0f} {c['rescues']:8.0f}")  # fmt: skip
    step_breakdown(runs)
    rescue_table(runs)
    return 0


if __name__ == "__main__":
    sys.exit(run(main))
