"""Two training recipes of one model class side by side: failure rate, RMSE, CPU per training.

Reads the trainings the workflow made (``results/trainings/<model>/seed<s>/``: ``health.json``
says whether each worked and its ETHZ validation one-step RMSE; ``model.pt`` is evaluated on
the held-out ETHZMobil set; ``results/benchmarks/train/<model>/seed<s>.tsv`` gives the CPU
seconds) and prints, per model: trainings, failed, the failure rate with its 95 %
Clopper–Pearson interval, the median ETHZ validation and ETHZMobil ω RMSE of the trained ones
(and their range) and the median CPU per training. The trainings come from Snakemake, e.g. for
DDM's recipe and the tuned one of ``config/examples/ddm_tuned.yaml`` over six seeds:

    snakemake --cores 2 --configfile config/config.yaml config/examples/ddm_tuned.yaml \\
        results/trainings/{ddm,ddm_tuned}/seed{0,1,2,3,4,5}/health.json
    python benchmarks/recipes.py ddm ddm_tuned --seeds 6 --configfile config/examples/ddm_tuned.yaml

Run it from the study's folder: the files are looked for where the workflow writes them
(``cape.layout.paths``). A training or record that is missing is named, never counted as a
pass, a failure or zero CPU; a damaged one (an empty benchmark TSV) ends the script with one
line naming it and the fix, exit status 2.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from _common import add_config, run, study_config  # a sibling module

from cape.config import section
from cape.data.bayesrace import read_dataset
from cape.data.windows import make_windows
from cape.errors import CapeError
from cape.layout import paths
from cape.storage.io import read_benchmark
from cape.training.outcome import read_outcome, reliability


def cpu_seconds(tsv: Path) -> float:
    """User + system CPU of one training from Snakemake's benchmark file (``cpu_time``)."""
    value = float(read_benchmark(tsv)["cpu_time"].iloc[0])
    if not math.isfinite(value):
        raise CapeError(f"{tsv}: no CPU time recorded (cpu_time {value}); rerun the training")
    return value


def test_rmse_omega(folder: Path, test: dict[str, np.ndarray]) -> float:
    """ETHZMobil one-step ω RMSE of the network in ``folder``."""
    from cape.training.checkpoint import load_model
    from cape.training.evaluate import one_step_rmse

    model = load_model(folder)
    return float(one_step_rmse(model, make_windows(test, model.history))["omega"])


def summarise(model: str, seeds: int, first: int, test: dict[str, np.ndarray]) -> dict[str, str]:
    """One model's row: its trainings with seeds ``first`` … ``first + seeds − 1``."""
    outcomes, val, mobil, cpu, missing = [], [], [], [], []
    for seed in range(first, first + seeds):
        folder = Path(paths.training_dir(model, seed))
        health = folder / paths.HEALTH
        if not health.is_file():
            missing.append(f"seed {seed}")
            continue
        outcome = read_outcome(health)
        outcomes.append(outcome)
        tsv = Path(paths.benchmark("train", model, f"seed{seed}.tsv"))
        if tsv.is_file():
            cpu.append(cpu_seconds(tsv))
        else:
            missing.append(f"seed {seed}'s CPU ({tsv})")
        if outcome.trained:
            val.append(outcome.val_rmse["omega"])
            mobil.append(test_rmse_omega(folder, test))
    rel = reliability(outcomes)

    def spread(values: list[float]) -> str:
        if not values:
            return "–"
        return f"{statistics.median(values):.3g} [{min(values):.3g}, {max(values):.3g}]"

    rate = "–" if math.isnan(rel.rate) else f"{rel.rate:.0%} [{rel.low:.0%}, {rel.high:.0%}]"
    return {
        "model": model,
        "trainings": str(rel.tried),
        "failed": str(rel.failed),
        "failure rate [95 % CI]": rate,
        "ETHZ val ω RMSE, trained": spread(val),
        "ETHZMobil ω RMSE, trained": spread(mobil),
        "CPU s per training": f"{statistics.median(cpu):.0f}" if cpu else "–",
        "missing": ", ".join(missing) or "none",
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+", help="config names of the models (recipes)")
    parser.add_argument("--seeds", type=int, default=6, help="trainings per model (default 6)")
    add_config(parser)
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error("--seeds: give at least 1")
    config = study_config(args)
    data = section(config, "data")
    first = int(section(config, "training")["seed"])
    test = read_dataset(paths.dataset(data["test_track"]))
    trainings = Path(paths.training_dir("<model>", 0)).parent.parent
    unknown = [m for m in args.models if not Path(paths.training_dir(m, first)).parent.is_dir()]
    if unknown:
        raise CapeError(
            f"{', '.join(unknown)}: no trainings under {trainings}; train them first (the "
            "snakemake command in this script's docstring)"
        )
    rows = [summarise(m, args.seeds, first, test) for m in args.models]
    columns = list(rows[0])
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        print("| " + " | ".join(row[c] for c in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(run(main))
