"""The lateral tyre curves a trained model has learned, beside the true car's and the slip range
of its training data (SPEC §1, §4): where each axle's force peaks, and where it turns against
the slip (which a real tyre never does).

    python examples/learned_tyre_curves.py dpm --replicates 0,1,2

Φ is the per-parameter median over the ETHZ windows (the fixed-parameter variant's, SPEC
§4.5). Needs ``results/data/DYN-PP-ETHZ.npz`` and the replicates' trained models
(``snakemake --cores 2 replicates`` or ``results/models/rep<r>/<model>/network.npz``); what it
measured is in docs/closed-loop.md, "the feedback laws at η = 0".
"""

from __future__ import annotations

import argparse

import numpy as np

from cape.data.windows import make_windows
from cape.models.trained import load_trained
from cape.training.evaluate import rear_slip
from cape.vehicle.dynamics import pacejka
from cape.vehicle.params import GROUND_TRUTH

AXLES = {"front": ("Bf", "Cf", "Df", "Ef"), "rear": ("Br", "Cr", "Dr", "Er")}


def curve_shape(coefficients: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(slip of the largest force, that force, first slip where the force turns negative) on
    0 … 1 rad, for a positive slip (NaN: it never turns); SPEC §1's formula without shifts."""
    alpha = np.linspace(1e-4, 1.0, 10001)
    force = pacejka(alpha, *coefficients) * np.sign(pacejka(alpha[:1], *coefficients))
    turned = np.flatnonzero(force < 0)
    peak = int(np.argmax(force))
    turns = float(alpha[turned[0]]) if turned.size else float("nan")
    return float(alpha[peak]), float(force[peak]), turns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a trained model with Pacejka coefficients in Φ (dpm, ddm)")
    parser.add_argument("--replicates", default="0,1,2")
    parser.add_argument("--models", default="results/models")
    parser.add_argument("--data", default="results/data/DYN-PP-ETHZ.npz")
    args = parser.parse_args()
    data = dict(np.load(args.data))
    slip = rear_slip(data)
    print(f"ETHZ data: |rear slip| 99th percentile {np.percentile(slip, 99):.3f} rad")
    truth = GROUND_TRUTH.as_dict()
    for axle, names in AXLES.items():
        at, force, turns = curve_shape(tuple(truth[n] for n in names))
        print(f"truth {axle:5s}: peak {force:.3f} N at {at:.2f} rad, turns: {turns:.2f}")
    for r in (int(x) for x in args.replicates.split(",")):
        model = load_trained(f"{args.models}/rep{r}/{args.model}", args.model)
        windows = make_windows(data, model.physics.history)
        phi = np.median([model.network.phi(w) for w in windows.features], axis=0)
        named = dict(zip(model.physics.param_names, phi, strict=True))
        for axle, names in AXLES.items():
            at, force, turns = curve_shape(tuple(float(named[n]) for n in names))
            print(
                f"replicate {r} {axle:5s}: peak {force:.3f} N at {at:.2f} rad, "
                f"turns against the slip at {turns:.2f} rad"
            )


if __name__ == "__main__":
    main()
