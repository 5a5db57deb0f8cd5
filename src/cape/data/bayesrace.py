"""The BayesRace/Deep-Dynamics data sets ``DYN-PP-<track>``, reproduced from first principles.

SPEC §3: the ground-truth car, integrated with the 6-stage RKF step, is driven around a
BayesRace raceline by pure pursuit for 1000 steps. The models train on a side trajectory,
``dstates``: a forward-Euler integration of the same equations driven by the inputs computed
on the RKF trajectory. It drifts from ``states``; that is how the published sets were made,
and they are reproduced to 1e-9.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cape.data.purepursuit import PurePursuit
from cape.errors import CapeError
from cape.layout import paths
from cape.specs.tracks import DataSettings
from cape.tracks.track import Raceline
from cape.vehicle.dynamics import state_derivative
from cape.vehicle.integrators import rkf_step
from cape.vehicle.params import VehicleParams

DATASET_KEYS = ("time", "states", "dstates", "inputs", "vrefs")


def read_dataset(path: str | Path) -> dict[str, np.ndarray]:
    """A DYN-PP data set as ``cape data`` writes it, or ``CapeError`` naming the file, what is
    wrong (not an .npz, an array missing, of another shape, or not finite) and the fix."""
    from cape.storage.io import read_npz

    fix = f"give a data set `cape data` wrote (snakemake --cores 2 {paths.dataset('ETHZ')})"
    what = "a DYN-PP data set"
    arrays = read_npz(path, DATASET_KEYS, what, fix)
    time = arrays["time"]
    if time.ndim != 1 or len(time) < 2:
        raise CapeError(f"{path}: array 'time' has shape {time.shape}, so it is not {what}; {fix}")
    n = len(time) - 1
    shapes = {"time": (n + 1,), "vrefs": (n + 1,), "states": (6, n + 1), "dstates": (8, n + 1),
              "inputs": (2, n)}  # fmt: skip
    for key, shape in shapes.items():
        array = arrays[key]
        if array.shape != shape:
            raise CapeError(
                f"{path}: array {key!r} has shape {array.shape}, not {shape}, so it is not "
                f"{what}; {fix}"
            )
        if array.dtype.kind not in "fiu" or not np.all(np.isfinite(array)):
            raise CapeError(f"{path}: array {key!r} holds non-numbers, so it is not {what}; {fix}")
    return arrays


@dataclass(frozen=True)
class ProtocolSettings:
    """The data-collection protocol; values come from the config's ``data`` section."""

    steps: int
    ts: float
    vx0: float
    lookahead: float
    speed_gain: float
    psi0: float

    @classmethod
    def of(cls, data: DataSettings, track: str) -> ProtocolSettings:
        """Settings for ``track`` (one of ``data.tracks``) from the ``data`` section."""
        return cls(
            steps=int(data.steps),
            ts=float(data.ts),
            vx0=float(data.vx0),
            lookahead=float(data.lookahead),
            speed_gain=float(data.speed_gain),
            psi0=float(data.tracks[track].psi0),
        )


def generate_dataset(
    raceline: Raceline, params: VehicleParams, settings: ProtocolSettings
) -> dict[str, np.ndarray]:
    """Run the protocol; return ``time (n+1,), states (6, n+1), dstates (8, n+1),
    inputs (2, n), vrefs (n+1,)`` for n = ``settings.steps``."""
    p = params.as_dict()
    ts, n = settings.ts, settings.steps

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return state_derivative(x, u, p)

    controller = PurePursuit(
        raceline.x,
        raceline.y,
        raceline.speed,
        lookahead=settings.lookahead,
        kp=settings.speed_gain,
        wheelbase=params.lf + params.lr,
    )
    x = np.array([raceline.x[0], raceline.y[0], settings.psi0, settings.vx0, 0.0, 0.0])
    d = np.concatenate([x, [0.0, 0.0]])
    states = np.zeros((6, n + 1))
    dstates = np.zeros((8, n + 1))
    inputs = np.zeros((2, n))
    vrefs = np.zeros(n + 1)
    states[:, 0] = x
    dstates[3, 0] = settings.vx0  # the published column 0 holds only vx
    vrefs[0] = settings.vx0
    for k in range(n):
        throttle, delta, _ = controller.command(x)
        u = np.array([throttle, delta])
        inputs[:, k] = u
        vrefs[k + 1] = throttle / settings.speed_gain + x[3]
        x = rkf_step(f, x, u, ts)
        states[:, k + 1] = x
        d = d + np.concatenate([ts * f(d[:6], u), u - d[6:8]])
        dstates[:, k + 1] = d
    time = np.arange(n + 1) * ts
    return {"time": time, "states": states, "dstates": dstates, "inputs": inputs, "vrefs": vrefs}
