"""How often the NMPC's rescue solves a problem the condensed SQP failed, and at what cost, for
IPOPT (several iteration caps), Fatrop and a longer condensed SQP, on the same problems.

Drives closed-loop laps as the learned study does (the trained model as plant and as the NMPC's
internal model; or ``--plant truth``, as the ground-truth study) with the configured NMPC. Every
time the SQP fails and the rescue is called, each capped IPOPT solves the same problem from the
same start (the SQP's last iterate), so does Fatrop on the stage-wise form (in its guarded
worker, as the study runs it), and a second condensed SQP with more iterations solves it warm
(from that iterate) and cold (the previous input held), each timed; then the configured rescue
solves it and the lap goes on as in the study. Prints, per model and η: rescues, and
per variant the share solved, the median and p90 time per rescue, the median iterations, and
how many of its solutions agree with the configured rescue's first input (within 1e-3).

    python benchmarks/rescue.py [--replicate 0] [--model dpm ddm epm] [--controller nmpc]
                                [--eta 1 3 5] [--seeds 0 1] [--caps 30 15 8] [--json PATH]
                                [--configfile config/smoke.yaml]

Run it from the study's folder: the models are the draw's (``cape.layout.paths.models_of``).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_config, json_output, run, study_config  # a sibling module

from cape.closedloop.setup import ModelFolders, build_run
from cape.errors import CapeError
from cape.layout import paths
from cape.specs.run import RunSpec


def capped(controller: Any, cap: int) -> Any:
    """The controller's rescue NLP under IPOPT with at most ``cap`` iterations."""
    settings = controller.settings
    kept = copy.deepcopy(settings["ipopt"])
    settings["ipopt"] = {**kept, "max_iter": cap}
    try:
        return controller._multiple_shooting("ipopt")
    finally:
        settings["ipopt"] = kept


def longer_sqp(controller: Any, max_iter: int) -> Any:
    """A second condensed SQP of the controller's problem, allowed ``max_iter`` iterations."""
    settings = controller.settings
    kept = copy.deepcopy(settings["sqp"])
    settings["sqp"] = {**kept, "max_iter": max_iter}
    try:
        clone = copy.copy(controller)
        clone._build()
        return clone.solver
    finally:
        settings["sqp"] = kept


def one_lap(
    config: dict,
    plant: str,
    model: str,
    controller_name: str,
    eta: float,
    seed: int,
    models: Path,
    caps: list[int],
    sqp_iterations: int,
) -> tuple[list[dict], dict]:
    spec = RunSpec.from_config(config, controller_name)
    run = build_run(spec, plant, eta, seed, model, ModelFolders(models), None)
    controller = run.controller
    rescue = controller.rescue
    variants: dict[Any, Any] = {cap: capped(controller, cap) for cap in caps}
    variants["fatrop"] = controller._multiple_shooting("fatrop")
    sqp = longer_sqp(controller, sqp_iterations)
    configured = int(controller.settings["ipopt"]["max_iter"])
    real = rescue.solve
    records: list[dict] = []

    def measured(x0, params, throttle, guess=None):
        record: dict[str, Any] = {}
        for cap, solver in variants.items():
            start_at = guess
            if guess is not None and solver is not rescue:  # the guess in the solver's own order
                index = rescue.ix, rescue.iu, rescue.ie
                start_at = solver.decision_vector(*(guess[i] for i in index))
            start = time.perf_counter()
            plan, ok = solver.solve(x0, params, throttle, guess=start_at)
            record[cap] = (ok, (time.perf_counter() - start) * 1e3, solver.stats.iterations,
                           None if plan is None else np.asarray(plan[0]))  # fmt: skip
        inputs, _ = controller.solver.iterate()  # where the failed SQP stopped
        for name, warm in (("sqp-warm", True), ("sqp-cold", False)):
            sqp.reset()
            if warm:
                sqp.adopt(inputs)
            start = time.perf_counter()
            plan, ok = sqp.solve(x0, params, throttle)
            record[name] = (ok, (time.perf_counter() - start) * 1e3, sqp.stats.iterations,
                            None if plan is None else np.asarray(plan[0]))  # fmt: skip
        start = time.perf_counter()
        plan, ok = real(x0, params, throttle, guess=guess)
        record[configured] = (ok, (time.perf_counter() - start) * 1e3, rescue.stats.iterations,
                              None if plan is None else np.asarray(plan[0]))  # fmt: skip
        records.append(record)
        return plan, ok

    rescue.solve = measured
    metrics = run().metrics
    return records, metrics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replicate", type=int, default=0, help="the models' draw (default 0)")
    parser.add_argument("--model", nargs="+", default=["dpm", "ddm", "epm"])
    parser.add_argument("--plant", default="learned", choices=["learned", "truth"])
    parser.add_argument("--controller", default="nmpc")
    parser.add_argument("--eta", nargs="+", type=float, default=[1.0, 3.0, 5.0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--caps", nargs="+", type=int, default=[30, 15, 8])
    parser.add_argument("--sqp-iterations", type=int, default=100,
                        help="iterations of the second SQP, warm (from the failed SQP's iterate) "
                        "and cold (the previous input held)")  # fmt: skip
    parser.add_argument("--json", type=Path, help="write the per-rescue records here")
    add_config(parser)
    args = parser.parse_args()
    with json_output(args.json, "rescue.py") as write:
        write(rescues(args))


def rescues(args: argparse.Namespace) -> dict[str, Any]:
    config = study_config(args)
    nmpc = config["controllers"].get(args.controller)
    if nmpc is None or "sqp" not in nmpc:
        raise CapeError(f"--controller {args.controller}: not an NMPC of the config's "
                        f"`controllers` ({', '.join(config['controllers'])})")  # fmt: skip
    models = Path(paths.models_of(args.replicate))
    # the lap is driven with IPOPT's rescue at its configured cap, the reference of the others
    config["controllers"][args.controller]["sqp"]["rescue"] = "ipopt"
    configured = int(config["controllers"][args.controller]["ipopt"]["max_iter"])
    caps = [c for c in args.caps if c != configured]
    order: list[Any] = [configured, *caps, "fatrop", "sqp-warm", "sqp-cold"]
    dump: dict[str, Any] = {}
    names = [f"cap {c}" if isinstance(c, int) else c for c in order]
    print(f"{'model':6} {'η':>4} {'laps':>5} {'rescues':>8}  "
          + "  ".join(f"{name:>30}" for name in names))  # fmt: skip
    print(f"{'':26}" + "  ".join(f"{'solved  med ms  p90 ms  it  agree':>30}" for _ in order))
    for model in args.model:
        plant = model if args.plant == "learned" else "truth"
        for eta in args.eta:
            rows: list[dict] = []
            laps = 0
            for seed in args.seeds:
                records, metrics = one_lap(
                    config,
                    plant,
                    model,
                    args.controller,
                    eta,
                    seed,
                    models,
                    caps,
                    args.sqp_iterations,
                )
                rows += records
                laps += bool(metrics["success"])
            cells = []
            for cap in order:
                if not rows:
                    cells.append(f"{'—':>30}")
                    continue
                ok = np.array([r[cap][0] for r in rows])
                ms = np.array([r[cap][1] for r in rows])
                it = np.array([r[cap][2] for r in rows])
                agree = sum(
                    r[cap][0] and r[configured][0]
                    and float(np.max(np.abs(r[cap][3] - r[configured][3]))) <= 1e-3
                    for r in rows
                )  # fmt: skip
                cells.append(f"{ok.mean():6.1%} {np.median(ms):7.1f} {np.percentile(ms, 90):7.1f}"
                             f" {np.median(it):3.0f} {agree:6d}")  # fmt: skip
            print(f"{model:6} {eta:4g} {laps:2d}/{len(args.seeds):<2d} {len(rows):8d}  "
                  + "  ".join(f"{c:>30}" for c in cells), flush=True)  # fmt: skip
            dump[f"{model}/{eta:g}"] = [
                {str(cap): {"ok": bool(r[cap][0]), "ms": r[cap][1], "iterations": r[cap][2]}
                 for cap in order} for r in rows
            ]  # fmt: skip
    return dump


if __name__ == "__main__":
    sys.exit(run(main))
