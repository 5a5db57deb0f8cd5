"""Which disturbance source makes a controller fail? Run it with each source of SPEC §6 switched
off in turn (and with only the steering delay left), on one plant at one η, over a few seeds.

Several sources do not scale with η (the 20 ms steering delay, the IMU bias walk, the crosswind,
the parameter mismatch): they are at full strength from the first η > 0. This script is how the
finding that the printed PID and RISE (`pid_paper`, `rise_paper`) leave the track at every
η > 0 was traced to the steering delay. It uses the same run builder as `cape rollout`; a source
is switched off through its `active_from` key, as a user would in the config.

    python examples/disturbance_attribution.py --controller pid_paper --eta 0.5 --seeds 5
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

from cape.closedloop.disturbances import SOURCES
from cape.closedloop.setup import build_run
from cape.config import load_config
from cape.specs.run import RunSpec


def outcome(config: dict, plant: str, controller: str, eta: float, seed: int) -> str:
    """'lap' or the step at which the run failed."""
    models = Path("results/models/rep0")
    spec = RunSpec.from_config(config, controller)
    result = build_run(spec, plant, eta, seed, None, models, None)()
    return "lap" if result.metrics["success"] else f"step {result.metrics['steps']}"


def without(config: dict, sources: list[str]) -> dict:
    """A copy of ``config`` with ``sources`` inactive at every η."""
    changed = copy.deepcopy(config)
    for source in sources:
        changed["disturbances"][source]["active_from"] = float("inf")
    return changed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--controller", default="pid_paper")
    parser.add_argument("--plant", default="truth")
    parser.add_argument("--eta", type=float, default=0.5)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--config", default="config/config.yaml")
    args = parser.parse_args()
    base = load_config(Path(args.config))
    cases = {"every source": [], **{f"without {s}": [s] for s in SOURCES}}
    cases["the steering delay alone"] = [s for s in SOURCES if s != "steering_delay"]
    seeds = range(args.seeds)
    print(f"{args.controller} on the {args.plant} plant at η = {args.eta}, seeds 0…{seeds[-1]}")
    for name, off in cases.items():
        config = without(base, off)
        runs = [outcome(config, args.plant, args.controller, args.eta, s) for s in seeds]
        print(f"  {name:<28} {', '.join(runs)}", flush=True)


if __name__ == "__main__":
    main()
