"""The training data: the BayesRace protocol (SPEC §3), windows, split and scaling."""

from cape.data.bayesrace import ProtocolSettings, generate_dataset
from cape.data.windows import StandardScaler, WindowSet, make_windows, split_indices

__all__ = [
    "ProtocolSettings",
    "StandardScaler",
    "WindowSet",
    "generate_dataset",
    "make_windows",
    "split_indices",
]
