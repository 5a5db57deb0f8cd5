"""The verdicts' calibration table (docs/study.md): for each method of
``cape.study.stats.calibration``, the share of simulated studies with no true effect whose 95 %
interval excludes zero (the false-verdict rate, nominal 5 %), at R training draws of five seeds
and a ratio σ_between/σ_within, and the share that finds a true effect of 3 σ_between at R = 5.

    python benchmarks/verdict_calibration.py [--trials 4000] [--bootstrap-trials 1000]

The t-interval runs in seconds; the retired two-level bootstrap (2000 resamples a trial) takes
a few minutes at 1000 trials a case.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from _common import run  # a sibling module

from cape.study.stats.calibration import exclusion_rate, t_over_draws

DRAWS = (3, 5, 10)
RATIOS = (0.0, 0.2, 1.0, 10.0)


def bootstrap_two_level(
    data: np.ndarray, level: float, rng: np.random.Generator, resamples: int = 2000
) -> tuple[np.ndarray, np.ndarray]:
    """The interval the scorecard used before the t over draws (docs/study.md says why it was
    retired): draws resampled with replacement, then the seeds within each
    drawn draw; the statistic is the mean over the drawn draws of their seeds' mean; the
    interval its percentiles."""
    trials, draws, seeds = data.shape
    lows, highs = np.empty(trials), np.empty(trials)
    tail = 100 * (1 - level) / 2
    for k in range(trials):
        picked = rng.integers(0, draws, size=(resamples, draws))
        inner = rng.integers(0, seeds, size=(resamples, draws, seeds))
        statistic = data[k][picked[..., None], inner].mean(axis=(1, 2))
        lows[k], highs[k] = np.percentile(statistic, [tail, 100 - tail])
    return lows, highs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=4000, help="trials a case, t-interval")
    parser.add_argument(
        "--bootstrap-trials", type=int, default=1000, help="trials a case, bootstrap"
    )
    args = parser.parse_args()
    if args.trials < 1 or args.bootstrap_trials < 1:
        parser.error("--trials and --bootstrap-trials: give at least 1")
    methods = (("t over draws", t_over_draws, args.trials),
               ("two-level bootstrap", bootstrap_two_level, args.bootstrap_trials))  # fmt: skip
    header = " | ".join(f"{r:g}" for r in RATIOS)
    print(f"| method | trials | R | {header} | power, 3 σ_between at R = 5 (ratios 0.2, 1, 10) |")
    print("|---|---|---|" + "---|" * len(RATIOS) + "---|")
    for name, method, trials in methods:
        start = time.perf_counter()
        power = [exclusion_rate(method, 5, r, 3 * r, trials, seed=7) for r in RATIOS[1:]]
        for draws in DRAWS:
            rates = [exclusion_rate(method, draws, r, 0.0, trials, seed=draws) for r in RATIOS]
            found = ", ".join(f"{p:.1%}" for p in power) if draws == 5 else ""
            cells = " | ".join(f"{x:.1%}" for x in rates)
            print(f"| {name} | {trials} | {draws} | {cells} | {found} |", flush=True)
        print(f"<!-- {name}: {time.perf_counter() - start:.0f} s -->", flush=True)


if __name__ == "__main__":
    sys.exit(run(main))
