"""An NMPC step inside a study job against the same step replayed alone: where the difference
goes.

Drives one run of the study as `cape rollout` does (default: the learned study, the plant and
the internal model the same trained model of replicate 0), recording every problem the NMPC
solves and every window its internal model's Φ sees, and the step's parts as the run clocks
them (timing.json's ``controller_s``). Then, in the same process, replays the problems in order
through a fresh controller's solve (warm-started as in the run, the rescue included:
`benchmarks/nmpc_step.py`'s method) and the windows through Φ, each in a tight loop (hot
caches), and prints per controller and model, in ms per step: the run's step by part, the
replay's solve and Φ, and their ratio.

    python benchmarks/step_inside.py [--models dpm ddm epm] [--controllers nmpc anmpc rnmpc]
                                     [--eta 1 4] [--seed 0] [--replicate 0] [--plant learned]
    python benchmarks/step_inside.py --cache   # how long Φ's weights stay in the cache

Run from a study's folder (its results/models, results/data and config, and ``--configfile``
the overlays it was built with): the models are the draw's (``cape.layout.paths.models_of``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_config, run, study_config  # a sibling module
from nmpc_step import replay  # a sibling script: run as `python benchmarks/step_inside.py`

from cape.closedloop.setup import ModelFolders, build_run
from cape.errors import CapeError
from cape.layout import paths
from cape.specs.run import RunSpec


def build(config: dict, args: argparse.Namespace, model: str, law: str, eta: float) -> Any:
    """The study's run, as `cape rollout` builds it (the plant's envelope from the config's
    training data)."""
    plant = model if args.plant == "learned" else "truth"
    return build_run(
        RunSpec.from_config(config, law), plant, eta, args.seed, model,
        ModelFolders(Path(paths.models_of(args.replicate))), None,
    )  # fmt: skip


def one(config: dict, args: argparse.Namespace, model: str, law: str, eta: float) -> dict:
    run = build(config, args, model, law, eta)
    controller = run.controller
    problems: list[tuple] = []
    windows: list[np.ndarray] = []
    solve, phi = controller.solve, controller.internal.phi

    def recording_solve(x0, params, throttle):
        problems.append((x0.copy(), params.copy(), tuple(throttle)))
        return solve(x0, params, throttle)

    def recording_phi():
        windows.append(controller.internal.window.copy())
        return phi()

    controller.solve, controller.internal.phi = recording_solve, recording_phi
    result = run()
    steps = int(result.metrics["steps"])
    inside = {k: 1e3 * v / steps for k, v in result.controller_s.items()}
    inside["step"] = float(np.sum(result.solve_ms)) / steps
    inside["step median"] = float(np.median(result.solve_ms))
    inside["plant Φ"] = 1e3 * result.plant_s / steps
    # the replay: a fresh controller, the same problems in order; then Φ on the same windows
    solve_ms = replay(build(config, args, model, law, eta).controller, problems)["ms"]
    predictor = controller.internal.predictor
    phi_ms = np.nan
    if predictor is not None:
        for w in windows[:50]:  # warm
            predictor.phi(w)
        start = time.perf_counter()
        for w in windows:
            predictor.phi(w)
        phi_ms = 1e3 * (time.perf_counter() - start) / len(windows)
    alone = float(solve_ms.mean()) + (0.0 if np.isnan(phi_ms) else phi_ms)
    return {"model": model, "law": law, "eta": eta, "steps": steps,
            "lap": bool(result.metrics["success"]), "inside": inside,
            "solve": float(solve_ms.mean()), "solve median": float(np.median(solve_ms)),
            "phi": phi_ms, "alone": alone, "ratio": inside["step"] / alone}  # fmt: skip


def cache(config: dict, args: argparse.Namespace) -> None:
    """Φ back to back, after a wait of busy work that touches no memory, and after streaming
    64 MB of other memory: how long its weights stay in this machine's cache."""
    from cape.models.trained import load_trained

    small, big = np.ones(1000), np.ones(64 * 2**20 // 8)
    folders = ModelFolders(Path(paths.models_of(args.replicate)))
    for model in args.models:
        trained = load_trained(folders(model), model, config["rollout"].get("compile"))
        window = np.random.default_rng(0).normal(size=(trained.physics.history, 7)) * 0.1
        for _ in range(50):
            trained.network.phi(window)
        cells = []
        for gap_ms in (0.0, 1.0, 3.0, "64 MB"):
            total = 0.0
            for _ in range(200):
                if gap_ms == "64 MB":
                    big += 1.0
                else:
                    end = time.perf_counter() + float(gap_ms) / 1e3
                    while time.perf_counter() < end:
                        small.sum()
                start = time.perf_counter()
                trained.network.phi(window)
                total += time.perf_counter() - start
            label = gap_ms if isinstance(gap_ms, str) else f"{gap_ms:g} ms busy"
            cells.append(f"after {label}: {1e3 * total / 200:.3f}")
        print(f"{model:6} Φ ms " + ", ".join(cells), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["dpm", "ddm", "epm"])
    parser.add_argument("--controllers", nargs="+", default=["nmpc", "anmpc", "rnmpc"])
    parser.add_argument("--eta", nargs="+", type=float, default=[1.0, 4.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--replicate", type=int, default=0)
    parser.add_argument("--plant", default="learned", choices=["learned", "truth"])
    parser.add_argument("--cache", action="store_true",
                        help="only: how long each model's Φ weights stay in the cache")  # fmt: skip
    add_config(parser)
    args = parser.parse_args()
    config = study_config(args)
    unknown = [m for m in args.models if m not in config["models"]]
    unknown += [c for c in args.controllers if c not in config["controllers"]]
    if unknown:
        raise CapeError(f"{' '.join(unknown)}: not in the config's `models` or `controllers`")
    if args.cache:
        cache(config, args)
        return
    parts = ("estimate", "internal_phi", "parameters", "solve", "rescue", "adaptation")
    print("ms per step; inside: the run's own clocks; alone: the same problems' solves (mean)"
          " and Φ on the same windows, replayed hot; ratio: inside step / alone")  # fmt: skip
    print(f"{'model':6} {'law':6} {'η':>4} {'lap':>4} " + " ".join(f"{p[:9]:>9}" for p in parts)
          + f" {'step':>7} {'median':>7} {'plant Φ':>8} | {'solve':>7} {'median':>7} "
          f"{'Φ':>6} {'alone':>6} {'ratio':>6}")  # fmt: skip
    for model in args.models:
        for law in args.controllers:
            for eta in args.eta:
                r = one(config, args, model, law, eta)
                i = r["inside"]
                print(f"{model:6} {law:6} {eta:4g} {'yes' if r['lap'] else 'no':>4} "
                      + " ".join(f"{i.get(p, 0.0):9.3f}" for p in parts)
                      + f" {i['step']:7.3f} {i['step median']:7.3f} {i['plant Φ']:8.3f} | "
                      f"{r['solve']:7.3f} {r['solve median']:7.3f} {r['phi']:6.3f} "
                      f"{r['alone']:6.3f} {r['ratio']:6.2f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    sys.exit(run(main))
