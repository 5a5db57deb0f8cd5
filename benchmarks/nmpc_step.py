"""NMPC solve time, iterations and failures per step: the default solver against IPOPT and the
old default, on the same recorded problems.

Drives closed-loop laps of ETHZMobil (ground-truth plant, seed 0) with the nominal NMPC and the
default solver, at η = 0 and η = 4, for each internal model asked for, and records every problem
solved (initial state, parameters, throttle bounds). Then, in one process, replays those problems
in order, each solver warm-started from its own previous solution as in a run:

  default   the config's solver (the condensed SQP; with its IPOPT rescue), replayed ``--repeats``
            times because this machine's speed drifts by tens of per cent between minutes
  (a)       the NLP and IPOPT rebuilt every step, cold (every ``--stride``-th problem only)
  (b)       IPOPT built once, warm-started (the project's IPOPT settings)
  (c)       the old default: CasADi's sqpmethod, exact Hessian, qrqp, on the multiple-shooting NLP
  reference IPOPT at tolerance 1e-8 (1000 iterations), for the first-input agreement

and prints, per lap and solver: median, p90, p99 and max time per solve (ms), iterations (median,
max), failed solves, and the largest first-input difference against the reference, with the
share of problems within 1e-3 and where in the lap the others are.

    python benchmarks/nmpc_step.py [--internal epm truth] [--eta 0 4] [--stride 10]
                                    [--repeats 3] [--problems N] [--json PATH]
                                    [--configfile config/smoke.yaml]

The internal models are trained models of draw 0 (``results/models/rep0/``, the workflow's
``cape.layout.paths.models_of(0)``; or ``truth``, which needs none). ``--problems N`` replays
only the lap's first N problems (a quick check that every solver runs).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
from _common import add_config, json_output, run, study_config  # a sibling module

from cape.closedloop.setup import build_run
from cape.layout import paths
from cape.specs.run import RunSpec

Problem = tuple[np.ndarray, np.ndarray, tuple[float, float]]


def record_lap(config: dict[str, Any], internal: str, eta: float, models: Path) -> list[Problem]:
    run = build_run(RunSpec.from_config(config, "nmpc"), "truth", eta, 0, internal, models)
    controller = run.controller
    solve = controller.solve
    problems: list[Problem] = []

    def recording(x0, params, throttle):
        problems.append((x0.copy(), params.copy(), tuple(throttle)))
        return solve(x0, params, throttle)

    controller.solve = recording
    m = run().metrics
    outcome = f"lap {m['lap_time']} s" if m["success"] else f"failed ({m['failure']})"
    print(f"\nrecorded: internal {internal}, η = {eta:g}, {len(problems)} problems, {outcome}")
    return problems


def controller_with(config: dict[str, Any], internal: str, models: Path, **nmpc: Any) -> Any:
    cfg = copy.deepcopy(config)
    for key, value in nmpc.items():
        cfg["controllers"]["nmpc"][key] = value
    if cfg["controllers"]["nmpc"]["solver"] == "ipopt":  # the reference: no compiled library
        cfg["controllers"]["nmpc"]["compile"] = {"enabled": False}
    return build_run(RunSpec.from_config(cfg, "nmpc"), "truth", 0.0, 0, internal, models).controller


def replay(controller: Any, problems: list[Problem]) -> dict[str, np.ndarray]:
    """Solve the problems in order through the controller's solve (the default's rescue
    included), warm-starting as in a run; per-solve time (ms), iterations, success and the first
    input (NaN when the solve failed)."""
    controller.reset(problems[0][0][:6])
    n = len(problems)
    out = {"ms": np.empty(n), "iterations": np.empty(n), "ok": np.zeros(n, bool),
           "first": np.full((n, 2), np.nan), "plans": [None] * n}  # fmt: skip
    for i, (x0, params, throttle) in enumerate(problems):
        start = time.perf_counter()
        plan, ok = controller.solve(x0, params, throttle)
        out["ms"][i] = (time.perf_counter() - start) * 1e3
        out["iterations"][i] = controller.solver.stats.iterations
        out["ok"][i] = ok
        if ok:
            out["first"][i] = plan[0]
            out["plans"][i] = plan
    return out


def rebuild_every_step(controller: Any, problems: list[Problem], opts: dict) -> np.ndarray:
    """The reference implementations' pattern: a new NLP and IPOPT instance per step, cold.
    ``controller``: one whose solver is IPOPT on the multiple-shooting NLP (``solver:
    ipopt``), whose bounds and cold start are this NLP's. (Not the default's rescue: that is
    Fatrop's stage-wise NLP, another decision vector, since ``sqp.rescue: fatrop``.)"""
    backend = controller.solver  # the multiple-shooting NLP's bounds and cold start
    times = np.empty(len(problems))
    for i, (x0, params, throttle) in enumerate(problems):
        start = time.perf_counter()
        solver = ca.nlpsol("nmpc", "ipopt", controller.ocp.nlp(), opts)
        lbg, ubg = controller.ocp.nlp_bounds()
        cold = backend.cold_start(x0, params[controller.ocp.layout["u_prev"]])
        _, lbx, ubx = backend._prepare(cold, x0, throttle, True)
        solver(x0=cold, p=params, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        times[i] = time.perf_counter() - start
    return times * 1e3


def row(
    label: str, r: dict[str, Any], reference: dict[str, Any] | None, merit: Any = None
) -> dict[str, Any]:
    ms = r["ms"]
    result = {
        "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
        "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()),
        "iterations_median": float(np.median(r["iterations"])),
        "iterations_max": int(r["iterations"].max()), "failed": int((~r["ok"]).sum()),
        "n": int(ms.size),
    }  # fmt: skip
    text = (f"{label:34} {result['median_ms']:8.3f} {result['p90_ms']:8.3f} "
            f"{result['p99_ms']:8.2f} {result['max_ms']:8.2f} {result['iterations_median']:5.0f} "
            f"{result['iterations_max']:5d} {result['failed']:5d}")  # fmt: skip
    if reference is not None:
        diff = np.max(np.abs(r["first"] - reference["first"]), axis=1)
        both = np.isfinite(diff)
        within = diff[both] <= 1e-3
        result["first_input_max_diff"] = float(np.max(diff[both])) if both.any() else None
        result["within_1e-3"] = float(within.mean()) if both.any() else None
        outside = np.flatnonzero(both)[~within]
        result["outside_at_lap_fraction"] = [round(float(i) / len(diff), 3) for i in outside]
        if merit is not None:  # a different local optimum: which one is lower?
            result["outside_lower_or_equal_cost"] = int(sum(
                merit(i, r["plans"][i]) <= merit(i, reference["plans"][i]) * (1 + 1e-9) + 1e-12
                for i in outside))  # fmt: skip
        text += f"   {result['first_input_max_diff']:.1e}  {100 * within.mean():5.1f} %"
    print(text)
    return result


def benchmark_lap(
    config: dict[str, Any], internal: str, eta: float, args: argparse.Namespace
) -> dict[str, Any]:
    problems = record_lap(config, internal, eta, args.models)
    if args.problems:
        problems = problems[: args.problems]
    nmpc = config["controllers"]["nmpc"]
    tight = {"max_iter": 1000, "tol": 1e-8}
    reference = replay(controller_with(config, internal, args.models, solver="ipopt", ipopt=tight),
                       problems)  # fmt: skip
    default = controller_with(config, internal, args.models)
    replay(default, problems[:20])  # warm up caches and the compiled code
    replays = [replay(default, problems) for _ in range(max(1, args.repeats))]
    merged = {k: np.concatenate([r[k] for r in replays]) for k in ("ms", "iterations", "ok")}
    merged["first"] = replays[0]["first"]
    ipopt_controller = controller_with(config, internal, args.models, solver="ipopt")
    ipopt = replay(ipopt_controller, problems)
    old = replay(controller_with(config, internal, args.models, solver="sqpmethod"), problems)
    opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False,
            "ipopt.max_iter": int(nmpc["ipopt"]["max_iter"])}  # fmt: skip
    rebuilt = rebuild_every_step(ipopt_controller, problems[:: args.stride], opts)
    a = {"ms": rebuilt, "iterations": np.zeros(rebuilt.size), "ok": np.ones(rebuilt.size, bool)}
    print(
        f"{'solver':34} {'median':>8} {'p90':>8} {'p99':>8} {'max':>8} {'it.med':>5} "
        f"{'it.max':>5} {'fail':>5}   first-input diff vs IPOPT 1e-8, share ≤ 1e-3"
    )

    def merit(i: int, plan: np.ndarray) -> float:
        return default.solver.merit(*problems[i], plan)

    merged["plans"] = replays[0]["plans"]
    rows = {
        "default": row(f"default ({nmpc['solver']}, {len(replays)} replays)", merged,
                       reference, merit),
        "a_rebuild_ipopt": row("(a) NLP + IPOPT rebuilt, cold", a, None),
        "b_ipopt_once": row("(b) IPOPT built once, warm", ipopt, reference),
        "c_old_default": row("(c) old default (sqpmethod)", old, reference),
        "reference": row("reference IPOPT, tol 1e-8", reference, None),
    }  # fmt: skip
    rows["default"]["replay_medians_ms"] = [float(np.median(r["ms"])) for r in replays]
    rows["default"]["rescues"] = int(default.rescues)
    med = rows["default"]["median_ms"]
    ratio_a = rows["a_rebuild_ipopt"]["median_ms"] / med
    ratio_b = rows["b_ipopt_once"]["median_ms"] / med
    medians = ", ".join(f"{m:.3f}" for m in rows["default"]["replay_medians_ms"])
    print(
        f"default: replay medians {medians} ms; ratio a/default {ratio_a:.0f}, "
        f"b/default {ratio_b:.1f}; IPOPT rescues in the last replay {default.rescues}"
    )
    outside = rows["default"]["outside_at_lap_fraction"]
    if outside:
        lower = rows["default"]["outside_lower_or_equal_cost"]
        print(f"default's first input more than 1e-3 from the reference at lap fractions "
              f"{outside}: another local optimum, of lower or equal cost in {lower} of "
              f"{len(outside)}")  # fmt: skip
    return {"internal": internal, "eta": eta, "problems": len(problems), **rows,
            "ratio_a_default": ratio_a, "ratio_b_default": ratio_b}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--internal", nargs="+", default=["epm", "truth"])
    parser.add_argument("--eta", nargs="+", type=float, default=[0.0, 4.0])
    parser.add_argument("--models", type=Path, default=Path(paths.models_of(0)),
                        help="the draw's models folder (default: draw 0's)")  # fmt: skip
    parser.add_argument("--stride", type=int, default=10, help="(a) times every n-th problem")
    parser.add_argument("--repeats", type=int, default=3, help="replays of each lap (default)")
    parser.add_argument("--problems", type=int, help="replay only the lap's first N problems")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    add_config(parser)
    args = parser.parse_args()
    if args.stride < 1 or args.repeats < 1 or (args.problems is not None and args.problems < 1):
        parser.error("--stride, --repeats and --problems: give at least 1")
    with json_output(args.json, "nmpc_step.py") as write:
        config = study_config(args)
        results = [benchmark_lap(config, internal, eta, args) for internal in args.internal
                   for eta in args.eta]  # fmt: skip
        write(results)


if __name__ == "__main__":
    sys.exit(run(main))
