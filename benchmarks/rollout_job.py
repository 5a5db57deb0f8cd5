"""What one rollout job costs, measured from outside as Snakemake runs it, phase by phase.

Runs the real ``cape rollout`` command with the arguments the workflow's rule gives it (the
config sections as JSON, ``--model NAME=DIR``) for PID and for each NMPC with a learned internal
model, on the ground-truth plant, interleaved in rounds with a bare ``python -c "import numpy,
casadi"`` (the floor of any job that needs them), and prints per job kind the medians of:

- ``process``: the wall time from outside, as ``subprocess`` sees it;
- ``fixed``: process minus the lap (the job's price for not being a lap: interpreter, imports,
  config, building the run, writing, exit), the figure issue 22 bounds (≤ 0.3 s for PID,
  ≤ 0.4 s for an NMPC with a learned internal model);
- the phases the job times itself (``timing.json``'s ``job_s``): ``startup`` (cape's command
  modules and arguments), ``config``, ``build``, ``write``, and ``outside`` (what no phase
  covers: the interpreter's start, the imports before cape's first clock, the exit);
- per step of the lap (ms): ``controller``, ``plant`` and ``loop`` (reference points,
  projections, disturbances, recording: the lap minus the other two).

    python benchmarks/rollout_job.py [--rounds 5] [--internal epm] [--eta 1] [--replicate 0]
                                     [--controllers pid nmpc anmpc rnmpc]
                                     [--configfile config/smoke.yaml]

Run it from the study's folder. It needs what the rollouts need, at the paths the workflow
gives them (``cape.layout.paths``): ``snakemake --cores 2 results/models/rep0/epm/network.npz
results/raceline/ETHZMobil.npz``, and the compiled solvers (``snakemake --cores 2
results/solvers/rep0/nmpc/epm.json`` …; the first job of each controller compiles otherwise,
and that round is then dropped from the medians).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import add_config, require_file, run, study_config  # a sibling module

from cape.errors import CapeError
from cape.layout import paths
from cape.layout.record import read_timing
from cape.workflow.job_files import JobFiles


def job_command(config: dict[str, Any], controller: str, internal: str, eta: str, out: Path,
                replicate: int) -> list[str]:  # fmt: skip
    """The command line the rollout rule runs for one run on the ground-truth plant, the
    internal model of draw ``replicate`` where the workflow keeps it (``paths.model_dir``)."""
    learned = controller != "pid"
    plant, used = "truth", internal if learned else "truth"
    spec = JobFiles(config).write_rollout(controller, plant, used)
    command = ["cape", "rollout", "--study", "truth", "--plant", "truth", "--controller",
               controller, "--internal", used, "--eta", eta,
               "--seed", "0", "--replicate", str(replicate), "--out", str(out), "--raceline",
               paths.raceline(config["reference"]["track"]),
               "--spec", spec]  # fmt: skip
    if learned:
        command += ["--model", f"{internal}={paths.model_dir(internal, replicate)}"]
    return command


def timed(command: list[str]) -> float:
    """The command's wall time; ``CapeError`` with its last line of stderr when it fails."""
    start = time.perf_counter()
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode:
        said = (done.stderr.strip().splitlines() or ["(nothing on stderr)"])[-1]
        raise CapeError(f"`{' '.join(command[:12])} …` failed (exit status {done.returncode}): "
                        f"{said}")  # fmt: skip
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--internal", default="epm")
    parser.add_argument("--eta", default="1")
    parser.add_argument("--replicate", type=int, default=0, help="the models' draw (default 0)")
    parser.add_argument("--controllers", nargs="+", default=["pid", "nmpc", "anmpc", "rnmpc"])
    add_config(parser)
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error("--rounds: give at least 1")
    config = study_config(args)
    unknown = [c for c in args.controllers if c not in config["controllers"]]
    if unknown:
        raise CapeError(f"--controllers {' '.join(unknown)}: not in the config's `controllers` "
                        f"({', '.join(config['controllers'])})")  # fmt: skip
    if shutil.which("cape") is None:
        raise CapeError("the `cape` command is not on the PATH; activate the venv it is "
                        "installed in (`pip install -e .`)")  # fmt: skip
    require_file(paths.raceline(config["reference"]["track"]))
    if any(c != "pid" for c in args.controllers):
        require_file(Path(paths.model_dir(args.internal, args.replicate), paths.NETWORK))
    floor = [sys.executable, "-c", "import numpy, casadi"]
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in ["floor", *args.controllers]}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds + 1):  # round 0 warms the caches and is not counted
            rows_now = {"floor": {"process": timed(floor)}}
            for controller in args.controllers:
                out = Path(tmp) / f"{controller}{r}"
                command = job_command(config, controller, args.internal, args.eta, out,
                                      args.replicate)  # fmt: skip
                wall = timed(command)
                job = read_timing(out).get("job_s")
                if not isinstance(job, dict):
                    raise CapeError(f"{out / paths.TIMING}: no `job_s` (the job's phases); "
                                    "this `cape` is older than the benchmark")  # fmt: skip
                steps = max(int(job["steps"]), 1)
                inside = sum(job[k] for k in ("startup", "config", "build", "lap", "write"))
                rows_now[controller] = {
                    "process": wall,
                    "fixed": wall - job["lap"],
                    "outside": wall - inside,
                    **{k: job[k] for k in ("startup", "config", "build", "write")},
                    "controller ms/step": 1e3 * job["controller"] / steps,
                    "plant ms/step": 1e3 * job["plant"] / steps,
                    "loop ms/step": 1e3 * (job["lap"] - job["controller"] - job["plant"]) / steps,
                }
            if r:
                for name, row in rows_now.items():
                    rows[name].append(row)
    columns = ["process", "fixed", "outside", "startup", "config", "build", "write",
               "controller ms/step", "plant ms/step", "loop ms/step"]  # fmt: skip
    print(
        f"medians of {args.rounds} rounds (s unless ms/step); ground-truth plant, η = "
        f"{args.eta}, internal model {args.internal} of draw {args.replicate} for the NMPCs"
    )
    print(f"{'job':8}" + "".join(f"{c:>20}" for c in columns))
    for name, group in rows.items():
        cells = [statistics.median(r[c] for r in group) if c in group[0] else None
                 for c in columns]  # fmt: skip
        print(f"{name:8}" + "".join(f"{'':>20}" if v is None else f"{v:>20.4f}" for v in cells))


if __name__ == "__main__":
    sys.exit(run(main))
