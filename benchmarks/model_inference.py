"""Single-window Φ prediction: PyTorch's training graph against the closed loop's paths.

For each model, in the same process: the PyTorch graph (eager, one thread); the previous
default (the scaling and GRU compiled alone, the trunk in NumPy); the compiled Φ (the default:
the whole prediction as one C function, ``cape.models.compiled_phi``); and the uncompiled path
(the scaling and GRU in CasADi's virtual machine, the trunk in NumPy: what
``rollout.compile.enabled: false`` runs). Timed in interleaved blocks of consecutive calls (a
rollout calls one path only, so each path's weights are in cache as they are there), the
median and p90 per call, and the speed-up over the previous default. Then the largest change
of Φ over every ETHZMobil window, compiled against the previous default and against the
PyTorch graph: absolute, and relative to each component's largest magnitude. Uses the
trained models of draw 0 (``results/models/rep0/``, ``cape.layout.paths.model_dir``) when
present (else freshly initialised ones: the timing does not depend on the weights); run it from
the study's folder.

    python benchmarks/model_inference.py [--rounds 60] [--block 25] [--cache DIR]
                                         [--models dpm ddm epm] [--configfile FILE]

``--cache``: where the compiled libraries are kept (default ``rollout.compile.cache``); an
empty folder times a cold compilation.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from _common import add_config, run, study_config  # a sibling module

from cape.data.bayesrace import read_dataset
from cape.data.windows import make_windows
from cape.errors import CapeError
from cape.layout import paths as layout
from cape.models.network import NumpyNetwork
from cape.numerics.compiled import compiled_functions
from cape.training.checkpoint import load_model
from cape.training.loop import build_model

Predict = Callable[[np.ndarray], np.ndarray]


def interleaved(paths: dict[str, Predict], window: np.ndarray, rounds: int, block: int) -> dict:
    """Per-call times (ms) of each path: ``rounds`` rounds, each a block of ``block`` calls of
    every path in turn (the first call of a block, cold, left out)."""
    times: dict[str, list[float]] = {name: [] for name in paths}
    for _ in range(rounds):
        for name, fn in paths.items():
            fn(window)
            for _ in range(block):
                start = time.perf_counter()
                fn(window)
                times[name].append(time.perf_counter() - start)
    return {name: np.array(t) * 1e3 for name, t in times.items()}


def largest_change(phi: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """max |Φ − ref|, and the same relative to each component's largest |ref|."""
    diff = np.abs(phi - ref)
    return float(diff.max()), float((diff / np.maximum(np.abs(ref).max(axis=0), 1e-300)).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--block", type=int, default=25)
    parser.add_argument("--cache", help="compiled libraries (default: rollout.compile.cache)")
    parser.add_argument("--models", nargs="+", help="these models only (default: every one)")
    add_config(parser)
    args = parser.parse_args()
    if args.rounds < 1 or args.block < 1:
        parser.error("--rounds and --block: give at least 1")
    torch.set_num_threads(1)
    config = study_config(args)
    unknown = [m for m in args.models or [] if m not in config["models"]]
    if unknown:
        raise CapeError(f"--models {' '.join(unknown)}: not in the config's `models` "
                        f"({', '.join(config['models'])})")  # fmt: skip
    settings = dict(config["rollout"]["compile"], enabled=True)
    if args.cache:
        settings["cache"] = args.cache
    data = read_dataset(layout.dataset(config["data"]["test_track"]))
    rows = []
    for name, spec in config["models"].items():
        if args.models and name not in args.models:
            continue
        folder = Path(layout.model_dir(name, 0))
        if (folder / layout.WEIGHTS).is_file():
            model, source = load_model(folder, name), "trained"
        else:
            model = build_model(name, spec, config["data"]["ts"], seed=0).eval()
            source = "untrained"
        arrays = model.network_arrays()
        windows = make_windows(data, model.history).features
        start = time.perf_counter()
        compiled = NumpyNetwork(arrays, settings)
        compiled.phi(windows[0])  # compiles, or loads the cached library
        build = time.perf_counter() - start
        if compiled.library is None:
            raise CapeError(
                f"no C compiler ({settings.get('compiler', 'gcc')}): the compiled "
                "paths cannot be timed; install one (apt-get install gcc)"
            )
        uncompiled = NumpyNetwork(arrays).uncompiled_phi()
        network = NumpyNetwork(arrays)
        digest = hashlib.sha256(b"benchmark front")
        for part in (network.mean, network.scale, *(network.gru or ())):
            digest.update(part.tobytes())
        start = time.perf_counter()
        front, _ = compiled_functions(
            "front", {"front": network.front_function()}, settings, digest.hexdigest()
        )
        previous = network.uncompiled_phi(front["front"])
        previous(windows[0])
        build_previous = time.perf_counter() - start
        with torch.inference_mode():

            def graph(w: np.ndarray, m: torch.nn.Module = model) -> np.ndarray:
                return m.phi(torch.as_tensor(w[None]))[0].numpy()

            paths = {
                "torch": graph,
                "previous": previous,
                "compiled": compiled.phi,
                "uncompiled": uncompiled,
            }
            times = interleaved(paths, windows[100], args.rounds, args.block)
            ref = model.phi(torch.as_tensor(windows)).numpy()
        phi = {key: np.array([paths[key](w) for w in windows]) for key in paths if key != "torch"}
        rows.append((name, times))
        size = compiled.library.stat().st_size / 2**20
        print(
            f"{name} ({source}): compiled Φ ready in {build:.1f} s ({size:.1f} MiB), the "
            f"previous default's GRU in {build_previous:.1f} s",
            flush=True,
        )
        for key in ("previous", "uncompiled"):
            a, r = largest_change(phi["compiled"], phi[key])
            print(f"  compiled vs {key:10}: max |ΔΦ| {a:.2e}, relative {r:.2e}")
        for key in phi:
            a, r = largest_change(phi[key], ref)
            print(f"  {key:10} vs torch     : max |ΔΦ| {a:.2e}, relative {r:.2e}")
    print()
    header = ("model", "path", "median", "p90", "vs previous")
    print("{:6} {:11} {:>10} {:>9} {:>12}".format(*header))
    for name, times in rows:
        base = np.median(times["previous"])
        for key, t in times.items():
            print(
                f"{name:6} {key:11} {np.median(t):7.3f} ms {np.percentile(t, 90):9.3f} "
                f"{base / np.median(t):11.2f}x"
            )


if __name__ == "__main__":
    sys.exit(run(main))
