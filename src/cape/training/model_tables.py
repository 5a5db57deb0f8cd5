"""The model tables (SPEC §4.4): assembled from trained models as DataFrames."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from cape.data.windows import make_windows, split_indices
from cape.models.base import LearnedModel
from cape.paper import COMPLEXITY, OPENLOOP_RMSE
from cape.specs.training import Split
from cape.training.evaluate import STATE_NAMES, complexity_row, multistep_error, one_step_rmse


def openloop_table(
    models: Mapping[str, LearnedModel],
    train_data: dict[str, np.ndarray],
    test_data: dict[str, np.ndarray],
    split: Split,
    horizon: int,
) -> pd.DataFrame:
    """One row per model: one-step RMSE on the ETHZ validation split and on ETHZMobil, the mean
    absolute error after ``horizon`` open-loop steps on ETHZMobil, and the paper's RMSE."""
    rows = []
    for name, model in models.items():
        windows = make_windows(train_data, model.history)
        _, val_idx = split_indices(len(windows), float(split.train_fraction), int(split.seed))
        val = one_step_rmse(model, windows.subset(val_idx))
        test = one_step_rmse(model, make_windows(test_data, model.history))
        multi = multistep_error(model, test_data, horizon)
        row: dict[str, object] = {"model": name}
        row.update({f"val_rmse_{s}": val[s] for s in STATE_NAMES})
        row.update({f"test_rmse_{s}": test[s] for s in STATE_NAMES})
        row.update({f"test_mae{horizon}_{s}": multi[s] for s in STATE_NAMES})
        paper = OPENLOOP_RMSE.get(name, {})
        row.update({f"paper_rmse_{s}": paper.get(s, np.nan) for s in STATE_NAMES})
        rows.append(row)
    return pd.DataFrame(rows)


def complexity_table(
    models: Mapping[str, LearnedModel], window_by_model: Mapping[str, np.ndarray], repeats: int
) -> pd.DataFrame:
    """One row per model: the paper's complexity columns, ours measured, then the paper's."""
    rows = []
    for name, model in models.items():
        row = complexity_row(model, window_by_model[name], repeats)
        row["model"] = name
        paper = COMPLEXITY.get(name, {})
        row.update(
            {
                f"paper_{k}": paper.get(k, np.nan)
                for k in ("params_M", "size_MB", "flops_M", "inference_ms")
            }
        )
        rows.append(row)
    return pd.DataFrame(rows)
