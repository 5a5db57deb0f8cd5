"""The NMPC's compiled solver built with two sets of compiler flags: the same plans, and the
time per solve of each, on the same recorded problems in one process.

Drives a closed-loop lap of ETHZMobil (ground-truth plant, seed 0) with the NMPC and each
internal model asked for, records every problem it solved, then builds the controller's
libraries (the condensed SQP and its rescue) once per flag set into a fresh cache (the build
time is printed: it is paid once per model structure and study) and replays the problems in
order, warm-starting as in a run, alternating between the flag sets ``--repeats`` times because
this machine's speed drifts between minutes. Prints, per lap: each flag set's median and total
time per solve, their ratio, and whether every solve's outcome and plan are bit-identical.

    python benchmarks/compile_flags.py [--flags=-O1 --flags=-O2] [--internal ddm truth] [--eta 0 4]
                                       [--models results/models/rep0] [--repeats 3]
                                       [--problems N] [--configfile config/smoke.yaml]

The models are draw 0's (``cape.layout.paths.models_of(0)``; run it from the study's folder).
It needs a C compiler (``controllers.nmpc.compile.compiler``), whatever the config's
``compile.enabled``. ``--problems N`` replays only the lap's first N problems. Each flag set is
one ``--flags=…`` (with ``=``: a set starts with a dash), e.g. ``--flags="-O2 -march=native"``.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_config, run, study_config  # a sibling module
from nmpc_step import controller_with, record_lap, replay  # a sibling script

from cape.errors import CapeError
from cape.layout import paths


def controller_built(
    config: dict[str, Any], internal: str, models: Path, flags: list[str], cache: Path
) -> tuple[Any, float]:
    """The NMPC with its libraries compiled with ``flags`` into ``cache``, and the seconds it
    took to build (compiling included when the cache does not hold them yet)."""
    compile_settings = {**config["controllers"]["nmpc"]["compile"], "enabled": True,
                        "flags": flags, "cache": str(cache)}  # fmt: skip
    start = time.perf_counter()
    controller = controller_with(config, internal, models, compile=compile_settings)
    assert controller.rescue is not None  # built on first use: build its library now
    return controller, time.perf_counter() - start


def same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Every solve's success, iterations and plan bit-identical."""
    if not (np.array_equal(a["ok"], b["ok"]) and np.array_equal(a["iterations"], b["iterations"])):
        return False
    return all(
        (p is None and q is None) or (p is not None and q is not None and np.array_equal(p, q))
        for p, q in zip(a["plans"], b["plans"], strict=True)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flags", action="append", metavar="=FLAGS",
                        help="a flag set, as --flags=\"-O2 …\"; give it twice (default: "
                        "--flags=-O1 --flags=-O2)")  # fmt: skip
    parser.add_argument("--internal", nargs="+", default=["ddm", "truth"])
    parser.add_argument("--eta", nargs="+", type=float, default=[0.0, 4.0])
    parser.add_argument("--models", type=Path, default=Path(paths.models_of(0)))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--problems", type=int, help="replay only the lap's first N problems")
    add_config(parser)
    args = parser.parse_args()
    if args.repeats < 1 or (args.problems is not None and args.problems < 1):
        parser.error("--repeats and --problems: give at least 1")
    args.flags = args.flags or ["-O1", "-O2"]
    if len(args.flags) != 2:
        parser.error(f"--flags: give two flag sets, not {len(args.flags)}")
    config = study_config(args)
    compiler = str(config["controllers"]["nmpc"]["compile"].get("compiler", "gcc"))
    if shutil.which(compiler) is None:
        raise CapeError(f"no C compiler {compiler!r} on the PATH: the flags cannot be compared; "
                        "install one (apt-get install gcc)")  # fmt: skip
    flag_sets = [shlex.split(f) for f in args.flags]
    names = [" ".join(f) for f in flag_sets]
    with tempfile.TemporaryDirectory(prefix="cape-flags-") as tmp:
        for internal in args.internal:
            built = [
                controller_built(config, internal, args.models, f, Path(tmp) / str(i))
                for i, f in enumerate(flag_sets)
            ]
            print(f"\n{internal}: built in " + ", ".join(
                f"{t:.1f} s ({n})" for n, (_, t) in zip(names, built, strict=True)))  # fmt: skip
            for eta in args.eta:
                problems = record_lap(config, internal, eta, args.models)[: args.problems]
                for controller, _ in built:
                    replay(controller, problems[:20])  # warm up caches and the code
                runs: list[list[dict[str, Any]]] = [[], []]
                for _ in range(max(1, args.repeats)):
                    for i, (controller, _) in enumerate(built):
                        runs[i].append(replay(controller, problems))
                identical = all(same(runs[0][0], r) for r in runs[0][1:] + runs[1])
                ms = [np.concatenate([r["ms"] for r in rs]) for rs in runs]
                medians = [float(np.median(m)) for m in ms]
                totals = [float(m.sum()) / len(rs) for m, rs in zip(ms, runs, strict=True)]
                lines = [f"{n}: median {m:.3f} ms, {t:.0f} ms a lap"
                         for n, m, t in zip(names, medians, totals, strict=True)]  # fmt: skip
                print(
                    f"  η = {eta:g}: {len(problems)} solves; "
                    + "; ".join(lines)
                    + f"; ratio {totals[1] / totals[0]:.2f} (total), "
                    f"{medians[1] / medians[0]:.2f} (median); plans bit-identical: {identical}"
                )


if __name__ == "__main__":
    sys.exit(run(main))
