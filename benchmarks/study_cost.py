"""What the study costs: training per model, and the rollouts per study and controller.

Training times come from Snakemake's ``benchmark:`` files of the training rules
(``results/benchmarks/train/<model>.tsv``). A rollout job times its own phases into its
``timing.json`` (``job_s``: start-up, i.e. interpreter and imports up to the run's building;
building the run, i.e. models and the compiled solver; the lap; writing), because Snakemake's
benchmark monitor roughly doubled the wall time of these 1–3 s jobs. A run shared by two studies
is counted once, under the study it was computed for.

    python benchmarks/study_cost.py [--results results] [--cores 2]
"""

from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path

from cape.layout.runs import RunId

PHASES = ("startup", "config", "build", "lap", "write")


def training(results: Path) -> dict[str, float]:
    """Wall seconds of each model's training job, by replicate (``rep<r>/<model>``)."""
    out = {}
    for path in sorted((results / "benchmarks" / "train").glob("rep*/*.tsv")):
        with path.open() as handle:
            out[f"{path.parent.name}/{path.stem}"] = float(
                next(csv.DictReader(handle, delimiter="\t"))["s"]
            )
    return out


def rollouts(results: Path) -> list[dict]:
    """One row per computed run: study, controller, and the wall seconds of each phase."""
    rows = []
    for path in sorted((results / "runs").glob(f"{RunId.glob()}/timing.json")):
        run = RunId.parse(path)
        study, controller = run.study, run.controller
        job = json.loads(path.read_text()).get("job_s")
        if job is None:  # a run of an older version, without its phases
            continue
        rows.append({"study": study, "controller": controller, "steps": job.get("steps", 0),
                     **{phase: float(job.get(phase, 0.0)) for phase in PHASES}})  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--cores", type=int, default=2)
    args = parser.parse_args()

    trained = training(args.results)
    print("training (wall s per job):", ", ".join(f"{m} {s:.0f}" for m, s in trained.items())
          or "no benchmark files")  # fmt: skip

    rows = rollouts(args.results)
    if not rows:
        raise SystemExit(f"no timing.json with job phases under {args.results / 'runs'}")
    cells: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for row in rows:
        cells[(row["study"], row["controller"])].append(row)
    print(f"\n{'study':10} {'controller':11} {'jobs':>5} {'job s':>8} {'s/job':>6} "
          f"{'fixed s/job':>11} {'lap s/job':>9} {'ms/step':>8}")  # fmt: skip
    total = fixed_total = 0.0
    for (study, controller), group in sorted(cells.items()):
        fixed = sum(r["startup"] + r["config"] + r["build"] + r["write"] for r in group)
        lap = sum(r["lap"] for r in group)
        steps = sum(r["steps"] for r in group)
        total += fixed + lap
        fixed_total += fixed
        n = len(group)
        print(f"{study:10} {controller:11} {n:5d} {fixed + lap:8.0f} {(fixed + lap) / n:6.2f} "
              f"{fixed / n:11.2f} {lap / n:9.2f} {1e3 * lap / max(steps, 1):8.2f}")  # fmt: skip
    print(f"\n{len(rows)} rollouts: {total:.0f} s of job wall time ({fixed_total:.0f} s fixed, "
          f"{total - fixed_total:.0f} s laps), {total / 3600:.2f} h; "
          f"{total / args.cores / 60:.1f} min on {args.cores} cores")  # fmt: skip


if __name__ == "__main__":
    main()
