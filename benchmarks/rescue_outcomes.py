"""Does the NMPC's rescue change what a run records? Reruns the NMPC runs of a finished study
that called the rescue, with another rescue setting (``sqp.rescue``, e.g. ``null``: the
fallback instead), and compares each run's outcome with the study's: lap or not, failure label,
lap time, and the mean |e_y|; prints the counts per study, internal model and controller, the
outcomes that changed, and the CPU of the rescue before and after.

Run from the study's folder (its results/ and config, and ``--configfile`` the overlays it
was built with) with two workers:

    python benchmarks/rescue_outcomes.py --rescue null [--study truth] [--internal truth]
                                         [--replicate 0] [--limit 40] [--jobs 2] [--json PATH]

The runs are the replicated study's table (``results/replicates/study/runs.parquet``,
``cape.layout.paths.study_runs``), each run's models the draw's (``paths.models_of``).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from _common import add_config, json_output, run, study_config  # a sibling module

from cape.errors import CapeError
from cape.layout import paths
from cape.layout.record import read_timing

NMPCS = ("nmpc", "anmpc", "rnmpc")


def rescue_setting(text: str) -> Any:
    """``null`` → None; anything else is the solver's name."""
    return None if text in ("null", "none", "None") else text


def rerun(task: dict[str, Any]) -> dict[str, Any]:
    """One run of the study again, with the controller's rescue set to ``task['rescue']``."""
    from cape.closedloop.setup import ModelFolders, build_run
    from cape.specs.run import RunSpec

    config = copy.deepcopy(task["config"])
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
        RunSpec.from_config(config, task["controller"]), task["plant"], task["eta"], task["seed"],
        task["internal"], ModelFolders(Path(paths.models_of(task["replicate"]))), None,
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


def read_runs(path: Path) -> Any:
    """The study's runs table, or ``CapeError`` naming the file and the fix."""
    import pandas as pd

    fix = f"build it with `snakemake --cores 2 {path}` (the `replicates` target builds it)"
    if not path.is_file():
        raise CapeError(f"{path}: missing; {fix}")
    try:
        runs = pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise CapeError(f"{path}: not a readable runs table ({type(exc).__name__}); delete it "
                        f"and {fix}") from None  # fmt: skip
    needed = ("folder", "study", "plant", "internal", "controller", "eta", "seed", "replicate",
              "success", "failure", "lap_time", "mean_abs_ey", "rescues")  # fmt: skip
    lacking = [c for c in needed if c not in runs.columns]
    if lacking:
        raise CapeError(f"{path}: no column {', '.join(lacking)}, so not a study's runs table; "
                        f"delete it and {fix}")  # fmt: skip
    return runs


def json_option(text: str, option: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise CapeError(f"{option} {text!r}: not JSON ({exc})") from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rescue", required=True, help="the rescue to try: ipopt, fatrop or null")
    parser.add_argument("--sqp", default="{}", help="other sqp settings, JSON")
    parser.add_argument("--ipopt", default="{}", help="IPOPT's own options, JSON (ipopt.options)")
    parser.add_argument("--cap", type=int, help="IPOPT's iterations at most (ipopt.max_iter)")
    parser.add_argument("--fatrop", default="{}", help="Fatrop's options, JSON (fatrop.options)")
    parser.add_argument("--runs", type=Path,
                        default=Path(paths.study_runs(paths.REPLICATES_SCOPE)))  # fmt: skip
    parser.add_argument("--study", nargs="+", default=["learned", "truth"])
    parser.add_argument("--internal", nargs="+")
    parser.add_argument("--replicate", nargs="+", type=int, default=[0])
    parser.add_argument("--limit", type=int, help="at most this many runs per (study, internal)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every rerun's record here")
    add_config(parser)
    args = parser.parse_args()
    if args.jobs < 1 or (args.limit is not None and args.limit < 1):
        parser.error("--jobs and --limit: give at least 1")
    with json_output(args.json, "rescue_outcomes.py") as write:
        write(rerun_all(args))


def rerun_all(args: argparse.Namespace) -> list[dict[str, Any]]:
    config = study_config(args)
    options = {name: json_option(getattr(args, name), f"--{name}")
               for name in ("sqp", "ipopt", "fatrop")}  # fmt: skip
    runs = read_runs(args.runs)
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
        timing = read_timing(Path(r.folder))
        tasks.append({"folder": r.folder, "study": r.study, "plant": r.plant,
                      "internal": r.internal, "controller": r.controller, "eta": float(r.eta),
                      "seed": int(r.seed), "replicate": int(r.replicate),
                      "success": bool(r.success),
                      "failure": r.failure if isinstance(r.failure, str) else None,
                      "lap_time": r.lap_time, "ey": r.mean_abs_ey, "rescues": int(r.rescues),
                      "old_rescue_s": (timing.get("controller_s") or {}).get("rescue"),
                      "old_succeeded": (timing.get("rescues") or {}).get("succeeded", 0),
                      "config": config, "rescue": rescue_setting(args.rescue),
                      "sqp": options["sqp"], "ipopt": options["ipopt"], "cap": args.cap,
                      "fatrop": options["fatrop"]})  # fmt: skip
    print(f"{len(tasks)} runs that called the rescue; rerunning with rescue = {args.rescue}",
          flush=True)  # fmt: skip
    with ProcessPoolExecutor(args.jobs) as pool:
        done = list(pool.map(rerun, tasks, chunksize=1))
    for d in done:
        del d["config"]
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
    return done


if __name__ == "__main__":
    sys.exit(run(main))
