"""Single-window Φ prediction: PyTorch's training graph against CAPE's fast path.

Runs both on the same windows in the same process and prints the median and p90 time of each,
and their ratio. Uses the trained models under results/models/ when present (else freshly
initialised ones: the timing does not depend on the weights).

    python benchmarks/model_inference.py [--repeats 2000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from cape.config import load_config
from cape.data.windows import make_windows
from cape.models.checkpoint import load_model
from cape.models.training import build_model


def timings(fn, window: np.ndarray, repeats: int) -> np.ndarray:
    for _ in range(50):
        fn(window)
    out = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        fn(window)
        out[i] = time.perf_counter() - start
    return out * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = load_config()
    data_path = Path("results/data/DYN-PP-ETHZMobil.npz")
    if not data_path.is_file():
        raise SystemExit(f"{data_path} missing: run `snakemake --cores 2 {data_path}` first")
    with np.load(data_path) as npz:
        data = {k: npz[k] for k in npz.files}
    header = ("model", "source", "torch median", "p90", "fast median", "p90", "ratio")
    print("{:6} {:8} {:>13} {:>8} {:>12} {:>8} {:>7}".format(*header))
    for name, spec in config["models"].items():
        folder = Path("results/models") / name
        if (folder / "model.pt").is_file():
            model, source = load_model(folder, name), "trained"
        else:
            model = build_model(name, spec, config["data"]["ts"], seed=0).eval()
            source = "untrained"
        window = make_windows(data, model.history).features[100]
        fast = model.inference()
        with torch.inference_mode():
            graph = lambda w, m=model: m.phi(torch.as_tensor(w[None]))  # noqa: E731
            eager = timings(graph, window, args.repeats)
        quick = timings(fast.phi, window, args.repeats)
        ratio = np.median(eager) / np.median(quick)
        print(
            f"{name:6} {source:8} {np.median(eager):10.3f} ms {np.percentile(eager, 90):8.3f} "
            f"{np.median(quick):9.3f} ms {np.percentile(quick, 90):8.3f} {ratio:6.1f}x"
        )


if __name__ == "__main__":
    main()
