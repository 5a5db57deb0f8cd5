"""When a plant, not a controller, has failed (SPEC §5.3): a learned or fixed-parameter plant
whose body velocities or yaw rate leave the envelope of its training data by a wide margin,
or whose state is non-finite (a non-finite Φ), ends the run as ``plant_diverged``.

The envelope is ``factor`` × the largest |vx|, |vy|, |ω| of the training data set (the ETHZ
windows every model was trained on; ``rollout.plant_envelope`` in the config). The
ground-truth plant has none: a state beyond the envelope there is a defect of the simulation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cape.errors import CapeError

VELOCITIES = ("vx", "vy", "omega")
"""The state components the envelope bounds (state indices 3, 4, 5)."""


@dataclass(frozen=True)
class Envelope:
    """|vx|, |vy|, |ω| bounds of a plant's state (``limits``, in that order)."""

    limits: tuple[float, float, float]

    @classmethod
    def of_data(cls, data: Mapping[str, np.ndarray], factor: float) -> Envelope:
        """``factor`` × the largest |vx|, |vy|, |ω| of a DYN-PP data set's states."""
        states = np.asarray(data["states"], dtype=float)
        extremes = np.max(np.abs(states[3:6]), axis=1)
        return cls(tuple(float(factor * e) for e in extremes))  # type: ignore[arg-type]

    @classmethod
    def of_file(
        cls, path: str | Path, factor: float, trained_on: str | None = None
    ) -> tuple[Envelope, dict[str, str]]:
        """The envelope of the training data set in ``path`` (an .npz of `cape data`), and
        where it came from (path and SHA-256, for the run's record). ``trained_on``: the
        digest of the data the plant's model was trained on (its meta.json), which ``path``
        must be: a plant is bounded by its own training data, never another track's."""
        from cape.data.bayesrace import read_dataset
        from cape.storage.integrity import file_digest

        if not Path(path).is_file():
            raise CapeError(
                f"{path}: missing; a learned plant's envelope is measured on its training data: "
                f"build it (snakemake --cores 2 {path}) or pass --training-data"
            )
        envelope = cls.of_data(read_dataset(path), factor)
        digest = file_digest(path)
        if trained_on and digest != trained_on:
            raise CapeError(
                f"--training-data {path}: is not the data set the plant's model was trained on "
                f"(its meta.json records data_sha256 {trained_on[:12]}…, this file is "
                f"{digest[:12]}…); give that model's training data"
            )
        return envelope, {"path": str(path), "sha256": digest}

    def left(self, x: np.ndarray) -> bool:
        """Whether the plant state ``x`` (X, Y, ψ, vx, vy, ω) is non-finite or beyond the
        envelope in vx, vy or ω."""
        if not np.isfinite(x).all():
            return True
        return bool(np.any(np.abs(np.asarray(x[3:6], dtype=float)) > self.limits))


def divergence_record(step: int | None, x: np.ndarray | None) -> dict[str, float | int | None]:
    """metrics.json's account of a ``plant_diverged`` run: the step at which the plant left
    its envelope and its vx, vy, ω there (None where non-finite); all None otherwise."""
    if step is None or x is None:
        return {"plant_diverged_step": None, **{f"plant_diverged_{v}": None for v in VELOCITIES}}
    values = {
        f"plant_diverged_{v}": (float(x[3 + i]) if np.isfinite(x[3 + i]) else None)
        for i, v in enumerate(VELOCITIES)
    }
    return {"plant_diverged_step": int(step), **values}
