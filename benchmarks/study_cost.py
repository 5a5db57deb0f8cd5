"""What the study costs: training per model, and the rollouts per study and controller.

Training times come from Snakemake's ``benchmark:`` files of the training rules
(``results/benchmarks/train/<model>/seed<s>.tsv``, ``cape.layout.paths.benchmark``). A rollout
job times its own phases into its ``timing.json`` (``job_s``: start-up, i.e. interpreter and
imports up to the run's building; building the run, i.e. models and the compiled solver; the
lap; writing), because Snakemake's benchmark monitor roughly doubled the wall time of these 1–3
s jobs. A run shared by two studies is counted once, under the study it was computed for.

    python benchmarks/study_cost.py [--cores 2] [--configfile config/smoke.yaml]

Run it from the study's folder, with the config the study was built with (``--configfile``):
the runs it expects are the config's grid (``cape.study.grid``). What the study lacks (a
training's benchmark file, a run not computed yet) is named, and no total is given then: a
missing part is never counted as zero. A damaged file (an empty benchmark TSV, a truncated
timing.json) ends the script with one line naming it and the fix, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from _common import add_config, listed, run, study_config  # a sibling module

from cape.errors import CapeError
from cape.layout import paths
from cape.layout.record import read_timing
from cape.storage.io import read_benchmark

PHASES = ("startup", "config", "build", "lap", "write")


def training(lacking: list[str]) -> dict[str, float]:
    """Wall seconds of each training job (``<model>/seed<s>``), from its benchmark file; a
    training (its folder holds ``model.pt``) without one goes to ``lacking``."""
    out = {}
    for weights in sorted(Path().glob(str(Path(paths.training_dir("*", 0)).with_name("seed*")))):
        model, seed = weights.parent.name, weights.name
        if not (weights / paths.WEIGHTS).is_file():
            continue
        tsv = Path(paths.benchmark("train", model, f"{seed}.tsv"))
        if tsv.is_file():
            out[f"{model}/{seed}"] = float(read_benchmark(tsv)["s"].iloc[0])
        else:
            lacking.append(f"{tsv} (the training {weights} has no benchmark file)")
    return out


def rollouts(config: dict[str, Any], lacking: list[str]) -> list[dict]:
    """One row per computed run of the config's grid: study, controller, and the wall seconds
    of each phase; a run not computed goes to ``lacking``."""
    from cape.specs.study import StudySpec
    from cape.study.grid import study_grid

    rows, absent = [], []
    for run_id in dict.fromkeys(
        study_grid(StudySpec.from_config(config)).values()
    ):  # each computed run once
        folder = run_id.folder()
        if not folder.is_dir():
            absent.append(str(folder))
            continue
        job = read_timing(folder).get("job_s")
        if not isinstance(job, dict):
            raise CapeError(
                f"{folder / paths.TIMING}: no `job_s` (the job's phases: a run of "
                f"an older version); delete {folder} and rerun snakemake"
            )
        rows.append({"study": run_id.study, "controller": run_id.controller,
                     "steps": job.get("steps", 0),
                     **{phase: float(job.get(phase, 0.0)) for phase in PHASES}})  # fmt: skip
    if absent:
        lacking.append(f"{len(absent)} runs not computed ({listed(absent, 3)})")
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cores", type=int, default=2)
    add_config(parser)
    args = parser.parse_args()
    if args.cores < 1:
        parser.error("--cores: give at least 1")
    config = study_config(args)
    lacking: list[str] = []
    trained = training(lacking)
    print("training (wall s per job):", ", ".join(f"{m} {s:.0f}" for m, s in trained.items())
          or "no training has run here")  # fmt: skip

    rows = rollouts(config, lacking)
    cells: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for row in rows:
        cells[(row["study"], row["controller"])].append(row)
    if cells:
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
    if lacking:
        print(f"\n{len(rows)} rollouts computed; no total: this study lacks {len(lacking)} "
              "part(s), which would count as 0 s:")  # fmt: skip
        for item in lacking:
            print(f"  - {item}")
        return 0
    print(f"\n{len(rows)} rollouts: {total:.0f} s of job wall time ({fixed_total:.0f} s fixed, "
          f"{total - fixed_total:.0f} s laps), {total / 3600:.2f} h; "
          f"{total / args.cores / 60:.1f} min on {args.cores} cores")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(run(main))
