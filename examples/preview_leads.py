"""Laps of PID or RISE for several preview leads (SPEC §7.1: the preview is the actuator's
steering delay plus the law's own lead), on the ground-truth and the learned plants.

    python examples/preview_leads.py pid --leads 0.01,0.02,0.03 --eta 0.5,1,2,3 --seeds 5

Needs the reference line and the trained models of the plants it drives
(``snakemake --cores 2 results/models/rep0/epm/network.npz`` and likewise; docs/closed-loop.md
lists what it measured). η = 0 has no disturbance, so one seed stands for all there.
"""

from __future__ import annotations

import argparse
import copy
import math

from cape.closedloop.setup import build_run
from cape.config import load_config
from cape.specs.run import RunSpec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("controller", help="a controller entry with a `lead` (pid, rise)")
    parser.add_argument("--leads", default="0.01,0.02,0.03", help="leads to try (s)")
    parser.add_argument("--eta", default="0,0.5,1,2,3", help="η levels")
    parser.add_argument("--seeds", type=int, default=5, help="disturbance seeds at η > 0")
    parser.add_argument("--plants", default="truth,dpm,ddm,epm")
    parser.add_argument("--models", default="results/models/rep0")
    parser.add_argument("--raceline", default="results/raceline/ETHZMobil.npz")
    args = parser.parse_args()
    base = load_config()
    for plant in args.plants.split(","):
        for lead in (float(x) for x in args.leads.split(",")):
            cells = []
            for eta in args.eta.split(","):
                seeds = range(args.seeds) if float(eta) > 0 else range(1)
                laps, best = 0, math.inf
                for seed in seeds:
                    config = copy.deepcopy(base)
                    config["controllers"][args.controller]["lead"] = lead
                    spec = RunSpec.from_config(config, args.controller)
                    run = build_run(spec, plant, float(eta), seed, None, args.models,
                                    args.raceline)  # fmt: skip
                    metrics = run().metrics
                    laps += bool(metrics["success"])
                    if metrics["success"]:
                        best = min(best, metrics["lap_time"])
                cells.append(f"η {eta}: {laps}/{len(seeds)} ({best:.2f} s)")
            row = " | ".join(cells)
            print(f"{args.controller} {plant:6s} lead {lead:.3f} s  {row}", flush=True)


if __name__ == "__main__":
    main()
