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

    python benchmarks/draw_cost.py [--results results] [--replicate 1] [--models dpm ddm epm]
"""

from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path

from cape.layout.runs import RunId


def benchmark_cpu(folder: Path) -> dict[str, float]:
    """``cpu_time`` of each benchmark file under ``folder`` (file stem → s)."""
    out = {}
    for path in sorted(folder.rglob("*.tsv")):
        with path.open() as handle:
            row = next(csv.DictReader(handle, delimiter="\t"))
        value = row.get("cpu_time") or row.get("s")
        out[str(path.relative_to(folder).with_suffix(""))] = float(value or 0.0)
    return out


def draw_runs(results: Path, replicate: int, models: set[str] | None = None) -> list[dict]:
    """The phases of every run of ``replicate`` computed with a trained network (of
    ``models`` only, when given: a run whose plant or internal model is another is left out)."""
    rows = []
    for path in sorted((results / "runs").glob(f"*/rep{replicate}/*/*/*/*/*/timing.json")):
        run = RunId.parse(path)
        names = {n.removesuffix("-fixed") for n in (run.plant, run.internal)} - {"truth"}
        if models is not None and not names <= models:
            continue
        metrics = json.loads((path.parent / "metrics.json").read_text())
        timing = json.loads(path.read_text())
        job = timing.get("job_s")
        if not metrics.get("models") or job is None:
            continue
        rescues = timing.get("rescues") or {}
        rows.append({**job, "study": run.study, "law": run.controller,
                     "internal": run.internal, "eta": float(run.eta),
                     "parts": timing.get("controller_s") or {},
                     "rescues": int(metrics.get("rescues") or 0),
                     "rescued": rescues.get("succeeded")})  # fmt: skip
    return rows


def fixed_part(job: dict) -> float:
    """A job's fixed part (timing.json ``job_s``): start-up, config, build and writing."""
    return job["startup"] + job["config"] + job["build"] + job["write"]


def host_reference(results: Path) -> str:
    """The same work in every study, a gauge of the machine's speed while it ran: replicate 0's
    ground-truth plant driven by PID and RISE (no network, no solver; unchanged by the speed
    work), per step of their laps and per job's fixed part. Two studies' draw costs compare
    after scaling by it; the host's speed drifts by tens of per cent between hours."""
    lap = steps = fixed = jobs = 0.0
    for law in ("pid", "rise"):
        for path in (results / "runs" / "truth" / "rep0" / "truth" / "truth" / law).glob(
            "*/*/timing.json"
        ):
            job = json.loads(path.read_text()).get("job_s")
            if job is None:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--replicate", type=int, default=1, help="the draw to cost (not 0)")
    parser.add_argument("--budget", type=float, default=2400.0, help="s of CPU a draw may cost")
    parser.add_argument("--models", nargs="+", help="these models' draw only (default: all)")
    args = parser.parse_args()
    rep = f"rep{args.replicate}"
    bench = args.results / "benchmarks"
    models = set(args.models) if args.models else None

    def kept(key: str) -> bool:
        return models is None or key.split("/")[-1].removesuffix("-fixed") in models

    training = {k: v for k, v in benchmark_cpu(bench / "train").items()
                if k.startswith(rep) and kept(k)}  # fmt: skip
    solvers = {k: v for k, v in benchmark_cpu(bench / "solvers").items()
               if f"/{rep}/" in f"/{k}" and kept(k)}  # fmt: skip
    runs = draw_runs(args.results, args.replicate, models)
    if not runs:
        raise SystemExit(f"no run of replicate {args.replicate} under {args.results / 'runs'}")
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
    total = sum(training.values()) + sum(solvers.values()) + sum(parts.values())
    print(f"replicate {args.replicate}: {len(runs)} runs with its networks")
    print(f"  training  {sum(training.values()):8.0f} s  "
          + ", ".join(f"{k.split('/')[-1]} {v:.0f}" for k, v in training.items()))  # fmt: skip
    print(f"  solvers   {sum(solvers.values()):8.0f} s  ({len(solvers)} builds)")
    for name, value in parts.items():
        print(f"  {name:15} {value:8.0f} s")
    verdict = "within" if total <= args.budget else "over"
    print(
        f"  total     {total:8.0f} s of CPU ({verdict} the {args.budget:.0f} s budget); not "
        "counted: interpreter start-up before cape's imports, Snakemake's work per job"
    )
    print(f"  {host_reference(args.results)}")
    print(f"\n{'study':8} {'controller':10} {'jobs':>5} {'fixed':>7} {'plant Φ':>8} "
          f"{'step':>8} {'loop':>6} {'rescues':>8}")  # fmt: skip
    for (study, controller), c in sorted(by_cell.items()):
        print(f"{study:8} {controller:10} {c['jobs']:5.0f} {c['fixed']:7.0f} {c['plant Φ']:8.0f} "
              f"{c['controller step']:8.0f} {c['loop']:6.0f} {c['rescues']:8.0f}")  # fmt: skip
    step_breakdown(runs)
    rescue_table(runs)


if __name__ == "__main__":
    main()
