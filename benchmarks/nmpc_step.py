"""NMPC solve time per step: rebuilt-every-step IPOPT, IPOPT built once, and CAPE's default.

Drives one closed-loop lap of ETHZMobil (ground-truth plant, η = 0) with the nominal NMPC and
records every problem it solved (initial state, parameters, throttle bounds). Then, in the same
process, solves those same problems with

  (a) the pattern of the public reference implementations: the NLP and an IPOPT instance built
      anew for every step and solved from a cold start (on every ``--stride``-th problem only;
      it is slow);
  (b) IPOPT built once per run, warm-started from the previous solution;
  (c) the default solver of the config (SQP + qrqp on compiled NLP functions), warm-started;

and prints the median and p90 time per solve of each, the ratios a/c and b/c, and the largest
first-input difference between (b) and (c). (c) replays the lap ``--repeats`` times, because
this machine's speed drifts by tens of per cent from minute to minute: it reports the median
over every solve of every replay and the range of the replays' medians.

    python benchmarks/nmpc_step.py [--internal epm] [--stride 10] [--repeats 5] [--json PATH]

The internal model is a trained model from results/models/ (or ``truth``, which needs none).
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.closedloop.setup import build_run
from cape.config import load_config
from cape.controllers.nmpc import NominalNMPC

Problem = tuple[np.ndarray, np.ndarray, tuple[float, float], np.ndarray]


def record_lap(config: dict[str, Any], internal: str, models: Path) -> list[Problem]:
    run = build_run(config, "truth", "nmpc", 0.0, 0, internal, models)
    controller = run.controller
    solve = controller.solve
    problems: list[Problem] = []

    def recording(x0, params, throttle):
        problems.append((x0.copy(), params.copy(), tuple(throttle), controller.u_prev.copy()))
        return solve(x0, params, throttle)

    controller.solve = recording
    metrics = run().metrics
    if not metrics["success"]:
        raise SystemExit(f"the recorded lap failed ({metrics['failure']}); nothing to time")
    print(
        f"recorded lap: internal {internal}, {len(problems)} steps, "
        f"lap time {metrics['lap_time']} s, mean |e_y| {metrics['mean_abs_ey']:.4f} m"
    )
    return problems


def replay(controller: NominalNMPC, problems: list[Problem]) -> tuple[np.ndarray, np.ndarray]:
    """Solve the problems in order, warm-starting like the controller does; per-solve times (ms)
    and first inputs."""
    controller.reset(problems[0][0][:6])
    times, firsts = np.empty(len(problems)), np.empty((len(problems), 2))
    for i, (x0, params, throttle, u_prev) in enumerate(problems):
        controller.u_prev = u_prev
        start = time.perf_counter()
        out, ok = controller.solve(x0, params, throttle)
        times[i] = time.perf_counter() - start
        controller._sol = out if ok else None
        firsts[i] = controller.inputs(out[0].full().ravel())[0] if ok else np.nan
    return times * 1e3, firsts


def rebuild_every_step(controller: NominalNMPC, problems: list[Problem], ipopt: dict) -> np.ndarray:
    """The reference implementations' pattern: a new NLP and IPOPT instance per step, cold."""
    times = np.empty(len(problems))
    for i, (x0, params, throttle, u_prev) in enumerate(problems):
        start = time.perf_counter()
        built = controller.nlp()
        solver = ca.nlpsol("nmpc", "ipopt", built["problem"], ipopt)
        controller.u_prev = u_prev
        cold = controller.cold_start(x0)
        _, lbx, ubx = controller._prepare(cold, x0, throttle)
        solver(x0=cold, p=params, lbx=lbx, ubx=ubx, lbg=built["lbg"], ubg=built["ubg"])
        times[i] = time.perf_counter() - start
    return times * 1e3


def controller_with(config: dict[str, Any], internal: str, models: Path, solver: str) -> Any:
    cfg = copy.deepcopy(config)
    cfg["controllers"]["nmpc"]["solver"] = solver
    return build_run(cfg, "truth", "nmpc", 0.0, 0, internal, models).controller


def summary(label: str, ms: np.ndarray) -> dict[str, float]:
    row = {"median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)), "n": len(ms)}
    print(f"{label:44} {row['median_ms']:9.3f} {row['p90_ms']:9.3f} {row['n']:6d}")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--internal", default="epm", help="internal model (default: epm)")
    parser.add_argument("--models", type=Path, default=Path("results/models"))
    parser.add_argument("--stride", type=int, default=10, help="(a) times every n-th problem")
    parser.add_argument("--repeats", type=int, default=5, help="replays of the lap for (c)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    config = load_config()
    problems = record_lap(config, args.internal, args.models)

    solver = config["controllers"]["nmpc"]["solver"]
    default = controller_with(config, args.internal, args.models, solver)
    ipopt = controller_with(config, args.internal, args.models, "ipopt")
    replay(default, problems[:20])  # warm up caches and the compiled code
    replays = [replay(default, problems) for _ in range(max(1, args.repeats))]
    c_ms, c_first = np.concatenate([r[0] for r in replays]), replays[0][1]
    spread = [float(np.median(r[0])) for r in replays]
    b_ms, b_first = replay(ipopt, problems)
    ipopt_opts = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": int(config["controllers"]["nmpc"]["ipopt_max_iter"]),
        "print_time": False,
    }
    a_ms = rebuild_every_step(default, problems[:: args.stride], ipopt_opts)

    print(f"\n{'solver (same problems, same process)':44} {'median':>9} {'p90':>9} {'n':>6}  (ms)")
    rows = {
        "a_rebuild_ipopt": summary("(a) NLP + IPOPT rebuilt every step, cold", a_ms),
        "b_ipopt_once": summary("(b) IPOPT built once, warm start", b_ms),
        "c_default": summary(f"(c) default ({config['controllers']['nmpc']['solver']})", c_ms),
    }
    rows["c_default"]["replay_medians_ms"] = spread
    print(f"(c) medians of the {len(spread)} replays: {min(spread):.3f} … {max(spread):.3f} ms")
    ratio_a = rows["a_rebuild_ipopt"]["median_ms"] / rows["c_default"]["median_ms"]
    ratio_b = rows["b_ipopt_once"]["median_ms"] / rows["c_default"]["median_ms"]
    agree = float(np.nanmax(np.abs(b_first - c_first)))
    print(f"\nratio a/c {ratio_a:.1f}   ratio b/c {ratio_b:.1f}")
    print(f"largest first-input difference (b) vs (c): {agree:.2e}")
    if args.json:
        result = {"internal": args.internal, **rows, "ratio_a_c": ratio_a, "ratio_b_c": ratio_b,
                  "first_input_max_diff": agree}  # fmt: skip
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
