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
    python benchmarks/recipes.py ddm ddm_tuned --seeds 6

A training or record that is missing is named, never counted as a pass, a failure or zero CPU.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import numpy as np

from cape.config import load_config, section
from cape.data.windows import make_windows
from cape.errors import CapeError
from cape.io import read_npz
from cape.models.draws import read_outcome, reliability

REPO = Path(__file__).resolve().parents[1]


def cpu_seconds(tsv: Path) -> float:
    """User + system CPU of one training from Snakemake's benchmark file (``cpu_time``)."""
    import pandas as pd

    try:
        table = pd.read_csv(tsv, sep="\t")
        return float(table["cpu_time"].iloc[0])
    except (OSError, KeyError, IndexError, ValueError, pd.errors.ParserError) as exc:
        raise CapeError(f"{tsv}: no CPU time ({type(exc).__name__}); rerun the training") from None


def test_rmse_omega(folder: Path, test: dict[str, np.ndarray]) -> float:
    """ETHZMobil one-step ω RMSE of the network in ``folder``."""
    from cape.models.checkpoint import load_model
    from cape.models.evaluate import one_step_rmse

    model = load_model(folder)
    return float(one_step_rmse(model, make_windows(test, model.history))["omega"])


def summarise(
    results: Path, model: str, seeds: int, first: int, test: dict[str, np.ndarray]
) -> dict[str, str]:
    """One model's row: its trainings with seeds ``first`` … ``first + seeds − 1``."""
    outcomes, val, mobil, cpu, missing = [], [], [], [], []
    for seed in range(first, first + seeds):
        folder = results / "trainings" / model / f"seed{seed}"
        health = folder / "health.json"
        if not health.is_file():
            missing.append(f"seed {seed}")
            continue
        outcome = read_outcome(health)
        outcomes.append(outcome)
        tsv = results / "benchmarks" / "train" / model / f"seed{seed}.tsv"
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+", help="config names of the models (recipes)")
    parser.add_argument("--seeds", type=int, default=6, help="trainings per model (default 6)")
    parser.add_argument("--config", type=Path, default=REPO / "config/config.yaml")
    parser.add_argument("--results", type=Path, default=REPO / "results", help="results folder")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds: give at least 1")
    try:
        config = load_config(args.config)
        data = section(config, "data")
        first = int(section(config, "training")["seed"])
        path = args.results / "data" / f"DYN-PP-{data['test_track']}.npz"
        if not path.is_file():
            raise CapeError(f"{path}: missing; build it with `snakemake --cores 2 {path}`")
        test = read_npz(path)
        unknown = [m for m in args.models if not (args.results / "trainings" / m).is_dir()]
        if unknown:
            raise CapeError(
                f"{', '.join(unknown)}: no trainings under {args.results / 'trainings'}; train "
                "them first (the snakemake command in this script's docstring)"
            )
        rows = [summarise(args.results, m, args.seeds, first, test) for m in args.models]
    except CapeError as exc:
        print(f"recipes.py: {exc}", file=sys.stderr)
        return 2
    columns = list(rows[0])
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        print("| " + " | ".join(row[c] for c in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
