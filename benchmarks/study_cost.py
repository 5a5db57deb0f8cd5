"""What the study's rollouts cost: job count and wall seconds per job from the
``benchmark:`` files Snakemake writes (``results/benchmarks/runs/...tsv``), grouped by study and
controller, and the wall time they add up to on N cores.

Snakemake's benchmark times a job from the start of its shell command to its end, so the
figures include the process start (imports, loading the model and the compiled solver); the
per-job overhead of the scheduler itself is not in them. (Snakemake's ``cpu_time`` column is
sampled every few seconds and misses most of a short job, so it is not used.)

    python benchmarks/study_cost.py [--root results/benchmarks/runs] [--cores 2]
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path


def read(root: Path) -> list[dict]:
    """One row per run: study, controller, η, wall s."""
    rows = []
    for path in sorted(root.glob("*/*/*/*/eta*/seed*.tsv")):
        study, _plant, _internal, controller, eta = path.relative_to(root).parts[:5]
        with path.open() as handle:
            record = next(csv.DictReader(handle, delimiter="\t"))
        rows.append({
            "study": study, "controller": controller, "eta": eta.removeprefix("eta"),
            "wall": float(record["s"]),
        })  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path("results/benchmarks/runs"))
    parser.add_argument("--cores", type=int, default=2)
    args = parser.parse_args()
    rows = read(args.root)
    if not rows:
        raise SystemExit(f"{args.root}: no benchmark files (run the study first)")
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["study"], row["controller"])].append(row)
    print(f"{'study':<10}{'controller':<12}{'jobs':>6}{'wall s/job':>12}")
    for (study, controller), group in sorted(groups.items()):
        wall = sum(r["wall"] for r in group) / len(group)
        print(f"{study:<10}{controller:<12}{len(group):>6}{wall:>12.1f}")
    wall = sum(r["wall"] for r in rows)
    print(f"{len(rows)} jobs: {wall / 3600:.2f} h of job wall time, "
          f"{wall / args.cores / 3600:.2f} h on {args.cores} cores")  # fmt: skip


if __name__ == "__main__":
    main()
