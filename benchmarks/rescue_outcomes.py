"""Does the NMPC's rescue change what a run records? Reruns the NMPC runs of a finished study
that called the rescue, with another rescue setting (``sqp.rescue``, e.g. ``null``: the
fallback instead), and compares each run's outcome with the study's: lap or not, failure label,
lap time, and the mean |e_y|; prints the counts per study, internal model and controller, the
outcomes that changed, and the CPU of the rescue before and after.

Run from the study's folder (its results/ and config) with two workers:

    python benchmarks/rescue_outcomes.py --rescue null [--study truth] [--internal truth]
                                         [--replicate 0] [--limit 40] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

NMPCS = ("nmpc", "anmpc", "rnmpc")


def rescue_setting(text: str) -> Any:
    """``null`` → None; anything else is the solver's name."""
    return None if text in ("null", "none", "None") else text


def rerun(task: dict[str, Any]) -> dict[str, Any]:
    """One run of the study again, with the controller's rescue set to ``task['rescue']``."""
    from cape.closedloop.setup import ModelFolders, build_run
    from cape.config import load_config

    config = load_config(task["config"])
    for overlay in task["overlays"]:
        config = _merge(config, yaml.safe_load(Path(overlay).read_text()))
    config["controllers"][task["controller"]]["sqp"]["rescue"] = task["rescue"]
    for key, value in task["sqp"].items():
        config["controllers"][task["controller"]]["sqp"][key] = value
    if task["ipopt"]:
        config["controllers"][task["controller"]]["ipopt"]["options"] = task["ipopt"]
    if task["cap"]:
        config["controllers"][task["controller"]]["ipopt"]["max_iter"] = task["cap"]
    if task["fatrop"]:
        config["controllers"][task["controller"]]["fatrop"]["options"] = task["fatrop"]
    run = build_run(
        config, task["plant"], task["controller"], task["eta"], task["seed"], task["internal"],
        ModelFolders(Path(f"results/models/rep{task['replicate']}")), None,
    )  # fmt: skip
    solves: list[tuple[bool, int, float]] = []  # every rescue: converged, iterations, ms
    rescue = run.controller.rescue if task["rescue"] in ("ipopt", "fatrop") else None
    if rescue is not None:
        real = rescue.solve

        def timed(*a: Any, **k: Any) -> Any:
            begin = time.perf_counter()
            out = real(*a, **k)
            solves.append((out[1], rescue.stats.iterations, 1e3 * (time.perf_counter() - begin)))
            return out

        rescue.solve = timed
    start = time.process_time()
    result = run()
    parts = result.controller_s
    m = result.metrics
    return {**task, "cpu_s": time.process_time() - start,
            "rescue_s": parts.get("rescue", 0.0), "new_success": bool(m["success"]),
            "new_failure": m.get("failure"), "new_lap_time": m.get("lap_time"),
            "new_ey": m.get("mean_abs_ey"), "new_rescues": m.get("rescues", 0),
            "new_succeeded": result.rescues_succeeded, "solves": solves}  # fmt: skip


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for key, value in over.items():
        out[key] = _merge(out[key], value) if isinstance(value, dict) and isinstance(
            out.get(key), dict) else value  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rescue", required=True, help="the rescue to try: ipopt, fatrop or null")
    parser.add_argument("--sqp", default="{}", help="other sqp settings, JSON")
    parser.add_argument("--ipopt", default="{}", help="IPOPT's own options, JSON (ipopt.options)")
    parser.add_argument("--cap", type=int, help="IPOPT's iterations at most (ipopt.max_iter)")
    parser.add_argument("--fatrop", default="{}", help="Fatrop's options, JSON (fatrop.options)")
    parser.add_argument("--runs", default="results/replicates/study/runs.parquet")
    parser.add_argument("--study", nargs="+", default=["learned", "truth"])
    parser.add_argument("--internal", nargs="+")
    parser.add_argument("--replicate", nargs="+", type=int, default=[0])
    parser.add_argument("--limit", type=int, help="at most this many runs per (study, internal)")
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--overlay", nargs="*", default=[])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every rerun's record here")
    args = parser.parse_args()
    runs = pd.read_parquet(args.runs)
    runs = runs[runs.controller.isin(NMPCS) & (runs.rescues > 0)]
    # a run two studies share (the ablation's diagonal is the learned study's) is listed under
    # each: select the studies first, then keep each folder once
    runs = runs[runs.study.isin(args.study) & runs.replicate.isin(args.replicate)]
    runs = runs.drop_duplicates("folder")
    if args.internal:
        runs = runs[runs.internal.isin(args.internal)]
    if args.limit:
        shuffled = runs.sample(frac=1.0, random_state=0)
        runs = shuffled.groupby(["study", "internal"]).head(args.limit)
    tasks = []
    for r in runs.itertuples():
        timing = json.loads((Path(r.folder) / "timing.json").read_text())
        tasks.append({"folder": r.folder, "study": r.study, "plant": r.plant,
                      "internal": r.internal, "controller": r.controller, "eta": float(r.eta),
                      "seed": int(r.seed), "replicate": int(r.replicate),
                      "success": bool(r.success),
                      "failure": r.failure if isinstance(r.failure, str) else None,
                      "lap_time": r.lap_time, "ey": r.mean_abs_ey, "rescues": int(r.rescues),
                      "old_rescue_s": (timing.get("controller_s") or {}).get("rescue"),
                      "old_succeeded": (timing.get("rescues") or {}).get("succeeded", 0),
                      "config": args.config, "overlays": args.overlay,
                      "rescue": rescue_setting(args.rescue), "sqp": json.loads(args.sqp),
                      "ipopt": json.loads(args.ipopt), "cap": args.cap,
                      "fatrop": json.loads(args.fatrop)})  # fmt: skip
    print(f"{len(tasks)} runs that called the rescue; rerunning with rescue = {args.rescue}",
          flush=True)  # fmt: skip
    with ProcessPoolExecutor(args.jobs) as pool:
        done = list(pool.map(rerun, tasks, chunksize=1))
    cells: dict[tuple, Counter] = defaultdict(Counter)
    changes: Counter = Counter()
    for d in done:
        cell = cells[(d["study"], d["internal"], d["controller"])]
        cell["runs"] += 1
        cell["lap changed"] += d["success"] != d["new_success"]
        cell["label changed"] += d["failure"] != d["new_failure"]
        same_time = d["success"] and d["new_success"] and abs(
            d["lap_time"] - d["new_lap_time"]) < 1e-9  # fmt: skip
        cell["lap time changed"] += d["success"] and d["new_success"] and not same_time
        cell["rescues before"] += d["rescues"]
        cell["rescues after"] += d["new_rescues"]
        cell["ok before"] += d["old_succeeded"]
        cell["ok after"] += d["new_succeeded"]
        cell["rescue s before"] += d["old_rescue_s"] or 0.0
        cell["rescue s after"] += d["rescue_s"]
        if d["success"] != d["new_success"]:
            before = "lap" if d["success"] else d["failure"]
            after = "lap" if d["new_success"] else d["new_failure"]
            changes[(d["study"], d["internal"], f"{before} → {after}")] += 1
    print(
        f"\n{'study':8} {'internal':9} {'law':6} {'runs':>5} {'lap≠':>5} {'label≠':>6} "
        f"{'time≠':>6} {'resc. before':>12} {'after':>6} {'ok before':>9} {'after':>6} "
        f"{'s before':>9} {'s after':>8}"
    )
    for (study, internal, law), c in sorted(cells.items()):
        print(
            f"{study:8} {internal:9} {law:6} {c['runs']:5d} {c['lap changed']:5d} "
            f"{c['label changed']:6d} {c['lap time changed']:6d} {c['rescues before']:12d} "
            f"{c['rescues after']:6d} {c['ok before']:9d} {c['ok after']:6d} "
            f"{c['rescue s before']:9.1f} {c['rescue s after']:8.1f}"
        )
    solves = [x for d in done for x in d["solves"]]
    if solves:
        import numpy as np

        ok = np.array([x[0] for x in solves])
        it = np.array([x[1] for x in solves])
        ms = np.array([x[2] for x in solves])
        print(f"\nrescues: {len(solves)}, converged {ok.mean():.1%}; ms median {np.median(ms):.1f}"
              f" (converged {np.median(ms[ok]) if ok.any() else 0:.1f}, failed "
              f"{np.median(ms[~ok]) if (~ok).any() else 0:.1f}); iterations of the converged: "
              f"median {np.median(it[ok]) if ok.any() else 0:.0f}, p90 "
              f"{np.percentile(it[ok], 90) if ok.any() else 0:.0f}")  # fmt: skip
    print("\nlap outcomes that changed:")
    for (study, internal, what), n in sorted(changes.items()):
        print(f"  {study:8} {internal:9} {what:32} {n}")
    if args.json:
        args.json.write_text(json.dumps(done, indent=1, default=str))


if __name__ == "__main__":
    main()
