"""What the model stage's commands read: the models' entries and the training's settings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.errors import CapeError


@dataclass(frozen=True)
class ModelsSpec:
    """The ``models``, ``data`` and ``training`` sections as the model commands read them
    (``cape train``, ``health``, ``freeze``, ``export-network``, ``openloop``, ``complexity``,
    ``plot-models``); a section the job's specification lacks is empty."""

    models: Mapping[str, Mapping[str, Any]]
    data: Mapping[str, Any]
    training: Mapping[str, Any]
    rollout_compile: Mapping[str, Any] | None
    """How an exported network's Φ is compiled (``rollout.compile``)."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ModelsSpec:
        return cls(
            models=MappingProxyType(dict(config.get("models") or {})),
            data=MappingProxyType(dict(config.get("data") or {})),
            training=MappingProxyType(dict(config.get("training") or {})),
            rollout_compile=(config.get("rollout") or {}).get("compile"),
        )

    def entry(self, name: str) -> Mapping[str, Any]:
        """Model ``name``'s entry, or ``CapeError`` naming the configured ones."""
        if name not in self.models:
            known = ", ".join(sorted(self.models))
            raise CapeError(f"--model {name}: not in the config's `models` ({known})")
        return self.models[name]

    @property
    def ts(self) -> float:
        return float(_need(self.data, "data", "ts"))

    @property
    def split(self) -> Mapping[str, Any]:
        """The train/validation split of a data set's windows (``data.split``)."""
        return _need(self.data, "data", "split")

    @property
    def health(self) -> Mapping[str, Any]:
        return _need(self.training, "training", "health")

    @property
    def multistep_horizon(self) -> int:
        return int(self.training.get("multistep_horizon", 15))

    @property
    def inference_repeats(self) -> int:
        return int(self.training.get("inference_repeats", 2000))

    def colors_labels(self, names: list[str]) -> tuple[dict[str, str], dict[str, str]]:
        """Each model's colour and label (defaults where the config has none)."""
        colors = {n: self.models.get(n, {}).get("color", f"C{i}") for i, n in enumerate(names)}
        labels = {n: self.models.get(n, {}).get("label", n.upper()) for n in names}
        return colors, labels


def _need(section: Mapping[str, Any], name: str, key: str) -> Any:
    try:
        return section[key]
    except KeyError:
        raise CapeError(
            f"the configuration lacks `{name}.{key}`, which this command needs"
        ) from None
