"""What the model stage's commands read: the models' entries and the training's settings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from cape.config import setting
from cape.errors import CapeError
from cape.specs import Entry, entries, entry_of
from cape.specs.run import PhiCompile
from cape.specs.training import HealthSettings, Split

T = TypeVar("T")


@dataclass(frozen=True)
class ModelsSpec:
    """What the model commands read (``cape train``, ``check-training``, ``draw``, ``freeze``,
    ``export-network``, ``openloop``, ``complexity``, ``plot-models``) of the ``models``,
    ``data``, ``training`` and ``rollout`` sections; what the job's file lacks is None (its
    ``ts``, ``split`` and ``health`` say so in one line when a command needs them)."""

    models: Mapping[str, Entry]
    given_ts: float | None
    given_split: Split | None
    given_health: HealthSettings | None
    multistep_horizon: int
    """Open-loop steps of the multi-step error (``training.multistep_horizon``)."""
    inference_repeats: int
    """Predictions timed per model (``training.inference_repeats``)."""
    rollout_compile: PhiCompile | None
    """How an exported network's Φ is compiled (``rollout.compile``)."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ModelsSpec:
        data, training = config.get("data") or {}, config.get("training") or {}
        return cls(
            models=entries(config.get("models") or {}),
            given_ts=float(data["ts"]) if "ts" in data else None,
            given_split=Split.from_config(config) if "split" in data else None,
            given_health=HealthSettings.from_config(config) if "health" in training else None,
            multistep_horizon=int(setting(training, "multistep_horizon", "training")),
            inference_repeats=int(setting(training, "inference_repeats", "training")),
            rollout_compile=PhiCompile.from_config(config) if "rollout" in config else None,
        )

    def entry(self, name: str) -> Entry:
        """Model ``name``'s entry, or ``CapeError`` naming the configured ones."""
        return entry_of(self.models, name, "--model", "models")

    @property
    def ts(self) -> float:
        return _need(self.given_ts, "data.ts")

    @property
    def split(self) -> Split:
        """The train/validation split of a data set's windows (``data.split``)."""
        return _need(self.given_split, "data.split")

    @property
    def health(self) -> HealthSettings:
        return _need(self.given_health, "training.health")

    def colors_labels(self, names: list[str]) -> tuple[dict[str, str], dict[str, str]]:
        """Each model's colour and label (a model without: matplotlib's colour cycle, its name
        in capitals)."""
        colors = {n: str(self.models.get(n, {}).get("color", f"C{i}")) for i, n in enumerate(names)}
        labels = {n: str(self.models.get(n, {}).get("label", n.upper())) for n in names}
        return colors, labels


def _need(value: T | None, key: str) -> T:
    if value is None:
        raise CapeError(f"the configuration lacks `{key}`, which this command needs")
    return value
