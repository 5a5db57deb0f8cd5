"""Did a training work? (SPEC §4: a failed training is a result, not a model.)

A training that fails the checks (settings in ``training.health``: finite numbers, the bar of
SPEC §4.2 for DDM and EPM, a stalled loss) is kept with its reasons and replaced by the model's
next training seed (``cape.training.draws``). An outlier among draws is checked beside them, never a
reason to retrain. The checks in full: docs/modules.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from cape.errors import CapeError
from cape.specs.training import HealthSettings
from cape.training.outcome import STATES, Outcome, reliability


def training_checks(
    model: str,
    val_rmse: Mapping[str, float],
    train_loss: Sequence[float],
    settings: HealthSettings,
) -> list[str]:
    """The reasons one training failed (none: it trained), from its validation RMSE per
    component and its training loss per epoch, under the checks ``settings``."""
    nonfinite = [f"validation RMSE {s}" for s in STATES if not np.isfinite(float(val_rmse[s]))]
    if not np.all(np.isfinite(np.asarray(train_loss, dtype=float))):
        nonfinite.append("the training loss")
    if nonfinite:  # the other checks compare numbers: NaN would pass them
        return ["not finite: " + ", ".join(nonfinite)]
    reasons = []
    if settings.applies_to(model):
        bar = _bar(settings)
        above = [f"{s} {val_rmse[s]:.2e} ≥ {bar[s]:g}" for s in STATES if not val_rmse[s] < bar[s]]
        if above:
            reasons.append("ETHZ validation RMSE above the bar: " + ", ".join(above))
    stall = settings.stall
    if stall is not None and len(train_loss) > int(stall.after) + 1:
        start = int(stall.after)
        first = float(train_loss[start - 1])
        drop = (first - float(np.min(train_loss[start:]))) / first if first > 0 else 0.0
        if drop < float(stall.min_drop):
            reasons.append(
                f"training loss stalled: {drop:.1%} lower after epoch {start} than at it "
                f"({first:.3g})"
            )
    return reasons


def _bar(settings: HealthSettings) -> dict[str, float]:
    """SPEC §4.2's bar by state; ``CapeError`` when the checks name models but no bar."""
    bar = settings.val_rmse_max
    if bar is None:
        raise CapeError(
            "`training.health.val_rmse_max` is missing: the bar of the models "
            f"`training.health.models` names ({', '.join(settings.models)}); give it"
        )
    return {s: float(getattr(bar, s)) for s in STATES}


def outliers(best_val_loss: Mapping[int, float], factor: float) -> dict[int, str]:
    """Replicate → reason, for a best validation loss more than ``factor`` × the replicates'
    median (three replicates or more)."""
    if len(best_val_loss) < 3:
        return {}
    median = float(np.median(list(best_val_loss.values())))
    return {
        r: f"best validation loss {v:.3g} > {factor:g} × the replicates' median {median:.3g}"
        for r, v in best_val_loss.items()
        if v > factor * median
    }


def over_replicates(
    tables: Mapping[int, pd.DataFrame], columns: Sequence[str], health: pd.DataFrame | None = None
) -> pd.DataFrame:
    """Per model: each column's mean and standard deviation over the replicates' tables (table
    4's errors, table 1's inference time), and how many replicates failed to train."""
    frame = pd.concat([t.assign(replicate=r) for r, t in tables.items()], ignore_index=True)
    rows = []
    for model, group in frame.groupby("model", sort=False):
        row: dict[str, Any] = {"model": model, "replicates": len(group)}
        for column in columns:
            values = group[column].to_numpy(dtype=float)
            row[f"{column}_mean"] = float(values.mean())
            row[f"{column}_sd"] = float(values.std(ddof=1)) if values.size > 1 else float("nan")
        if health is not None:
            mine = health[health["model"] == model]
            row["draws standing in for failed trainings"] = int((~mine["trained"]).sum())
            row["which draws"] = ", ".join(str(r) for r in mine[~mine["trained"]]["replicate"])
        rows.append(row)
    return pd.DataFrame(rows)


def training_outcome(
    model: str,
    seed: int,
    val_rmse: Mapping[str, float],
    train_loss: Sequence[float],
    settings: HealthSettings,
    weights_sha256: str,
) -> Outcome:
    """One training's health record (cape.training.draws): the checks on the training alone,
    the bar and the stalled loss; the outlier check compares draws and is not one of them."""
    reasons = training_checks(model, val_rmse, train_loss, settings)
    rmse = {s: float(val_rmse[s]) for s in STATES}
    return Outcome(int(seed), not reasons, tuple(reasons), rmse, weights_sha256)


def draw_health(metas: Mapping[tuple[int, str], Mapping[str, Any]], factor: float) -> pd.DataFrame:
    """One row per (replicate, model) draw: ``trained`` and the ``reason`` it did not (its
    training's health, recorded by ``cape draw`` in meta.json), its training's seed, and the
    outlier check beside (``outlier``: a best validation loss far above the model's draws';
    reported, never a reason to retrain). ``metas``: (replicate, model) → the draw's meta.json."""
    rows = []
    for (replicate, model), meta in sorted(metas.items()):
        draw = meta.get("draw") or {}
        chosen = (draw.get("trainings") or [{}])[int(draw.get("index", 0))] if draw else {}
        trained = bool(draw.get("trained", True))
        rows.append({
            "replicate": int(replicate),
            "model": str(model),
            "seed": int(meta.get("seed", -1)),
            "trained": trained,
            "reason": "; ".join(chosen.get("reasons", [])) if not trained else "",
            "outlier": "",
        })  # fmt: skip
    frame = pd.DataFrame(
        rows, columns=["replicate", "model", "seed", "trained", "reason", "outlier"]
    )
    for model in frame["model"].unique():
        best = {r: float(meta["best_val_loss"]) for (r, m), meta in metas.items() if m == model}
        for replicate, reason in outliers(best, factor).items():
            mask = (frame["model"] == model) & (frame["replicate"] == replicate)
            frame.loc[mask, "outlier"] = reason
    return frame


def failed_draws(health: pd.DataFrame) -> dict[int, dict[str, str]]:
    """Replicate → model → reason, for the draws whose training failed (the cap reached)."""
    out: dict[int, dict[str, str]] = {}
    for row in health[~health["trained"]].itertuples(index=False):
        out.setdefault(int(row.replicate), {})[str(row.model)] = str(row.reason)
    return out


def trainings_tried(metas: Mapping[tuple[int, str], Mapping[str, Any]]) -> pd.DataFrame:
    """Every training a model's draws were chosen among, once (the union of the draws'
    records): model, seed, trained, the draw it became (-1: none), its ETHZ validation RMSE
    and the reasons it failed."""
    seen: dict[tuple[str, int], dict[str, Any]] = {}
    draw_of: dict[tuple[str, int], int] = {}
    for (replicate, model), meta in metas.items():
        draw = meta.get("draw")
        if not draw:  # a model folder made before draws: its one training, as it is
            continue
        for record in draw.get("trainings", []):
            seen[(str(model), int(record["seed"]))] = record
        draw_of[(str(model), int(meta["seed"]))] = int(replicate)
    rows = []
    for (model, seed), record in sorted(seen.items()):
        rmse = record.get("val_rmse", {})
        rows.append({
            "model": model,
            "seed": seed,
            "trained": bool(record["trained"]),
            "draw": draw_of.get((model, seed), -1),
            **{f"val_rmse_{s}": float(rmse.get(s, np.nan)) for s in STATES},
            "reasons": "; ".join(record.get("reasons", [])),
        })  # fmt: skip
    columns = ["model", "seed", "trained", "draw", *(f"val_rmse_{s}" for s in STATES), "reasons"]
    return pd.DataFrame(rows, columns=columns)


def reliability_table(
    trainings: pd.DataFrame,
    settings: HealthSettings,
    draws: int,
    max_trainings: int,
    factors: Sequence[float] = (0.5, 1.0, 2.0),
) -> pd.DataFrame:
    """Per model: trainings tried, failed, the failure rate with its 95 % Clopper–Pearson
    interval, trained draws against ``draws`` (and whether the cap was reached), and how many
    trainings would pass the ETHZ validation bar scaled by each of ``factors`` (the bar
    applies to the models ``settings.models`` names; others: empty)."""
    rows = []
    for model, group in trainings.groupby("model", sort=False):
        outcomes = [
            Outcome(int(r.seed), bool(r.trained), tuple(filter(None, [r.reasons])))
            for r in group.itertuples(index=False)
        ]
        rel = reliability(outcomes)
        trained = int(group["trained"].sum())
        row: dict[str, Any] = {
            "model": model,
            "trainings tried": rel.tried,
            "failed": rel.failed,
            "failure rate": rel.rate,
            "ci95_low": rel.low,
            "ci95_high": rel.high,
            "trained draws": f"{min(trained, draws)} of {draws}",
            "cap reached": trained < draws and rel.tried >= max_trainings,
        }
        for factor in factors:
            name = f"pass at {factor:g}× bar"
            if settings.applies_to(model):
                bar = _bar(settings)
                ok = np.ones(len(group), dtype=bool)
                for s in STATES:
                    ok &= group[f"val_rmse_{s}"].to_numpy(dtype=float) < factor * bar[s]
                row[name] = f"{int(ok.sum())} of {len(group)}"
            else:
                row[name] = "no bar"
        rows.append(row)
    return pd.DataFrame(rows)


def draw_cap(metas: Mapping[tuple[int, str], Mapping[str, Any]]) -> int:
    """The cap on a model's trainings the draws were made under, as ``cape draw`` recorded it
    (0 for folders made before draws). The workflow gives a draw that found its training the
    least cap that finds it, and one that reached the cap ``training.max_trainings``: the
    largest is the configured cap whenever a draw reached it."""
    return max(
        (int((m.get("draw") or {}).get("max_trainings", 0)) for m in metas.values()), default=0
    )
