"""What ``cape question`` reads back and reports after each stage: the stage's runs, its CPU,
each row through the looks, and results/question/RESULTS.md (docs/question.md reads it)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from cape.layout import paths
from cape.layout.names import replicate_name
from cape.study.claims.declared import NMPCS
from cape.study.question.looks import RowState
from cape.study.question.plan import Plan, QuestionSettings, stage_runs
from cape.study.question.state import commit
from cape.study.stats.sequential import (
    CONTRADICTED,
    EQUIVALENT,
    FUTILE,
    HOLDS,
    INCONCLUSIVE,
    OPEN,
    Design,
)

DECISIONS = (HOLDS, CONTRADICTED, EQUIVALENT, INCONCLUSIVE, FUTILE, OPEN)


def draw_meta(model: str, replicate: int) -> dict[str, Any]:
    """A draw's meta.json (``cape draw`` wrote it), or {} where there is none yet."""
    from cape.storage.io import read_json

    path = Path(paths.model_dir(model, replicate), paths.META)
    if not path.is_file():
        return {}
    weights = Path(paths.model_dir(model, replicate), paths.WEIGHTS)
    fix = (f"make the draw again (`snakemake --cores 2 --force {weights}`, which replaces the "
           "draw's own files), then run the command again")  # fmt: skip
    return read_json(path, "a draw's metadata", fix)


def read_stage_runs(settings: QuestionSettings, plan: Plan) -> pd.DataFrame | None:
    """The stage's runs (``cape.study.aggregate.collect_runs``, each checked against the
    networks of its draw), less those of a draw whose training failed (a model that reached
    its cap: the stand-in is no draw of its recipe); None where the stage runs nothing (its
    draws all reused from a published question)."""
    from cape.study.aggregate import collect_runs

    runs = stage_runs(settings, plan)
    if not runs:  # every draw reused from a published question
        return None
    pairs = [(run.study, run.folder() / paths.METRICS, None, run.replicate) for run in runs]
    frame = collect_runs(pairs, (settings.study,), paths.MODELS)
    untrained = {
        (m, r)
        for m, d in plan.draws.items()
        for r in range(d)
        if draw_meta(m, r).get("draw", {}).get("trained") is False
    }
    if untrained:
        keep = [
            (m, int(r)) not in untrained
            for m, r in zip(frame["model"], frame["replicate"], strict=True)
        ]
        frame = frame[keep]
    return frame


@dataclass
class Cost:
    """The CPU seconds the question has used: per model its trainings (every one tried, the
    failed ones too) and draws, the stage's runs and their count, the solvers."""

    trainings: dict[str, list[float]] = field(default_factory=dict)
    solvers: dict[str, float] = field(default_factory=dict)
    tried: dict[str, int] = field(default_factory=dict)
    failed: dict[str, int] = field(default_factory=dict)
    draws: dict[str, int] = field(default_factory=dict)
    runs_s: float = 0.0
    runs: int = 0
    solvers_s: float = 0.0
    etas: int = 1
    missing: list[str] = field(default_factory=list)

    @property
    def total(self) -> float:
        return sum(sum(v) for v in self.trainings.values()) + self.runs_s + self.solvers_s

    def per_draw(self, model: str) -> float:
        """A draw's fixed CPU: the model's trainings (failed ones too) and its solvers' builds,
        over its draws."""
        spent = self.trainings.get(model, [])
        if not spent:
            return math.nan
        return (sum(spent) + self.solvers.get(model, 0.0)) / max(1, self.draws.get(model, 0))

    def per_seed(self) -> float:
        """One seed's runs of one model's draw: 3 NMPCs × the η grid, at the mean run's CPU."""
        return self.runs_s / self.runs * len(NMPCS) * self.etas if self.runs else math.nan

    def cost_ratio(self) -> float | None:
        """A draw's CPU over one seed's (the mean over the models), or None unmeasured."""
        draws = [self.per_draw(m) for m in self.trainings]
        draws = [d for d in draws if math.isfinite(d)]
        seed = self.per_seed()
        if not draws or not math.isfinite(seed) or seed <= 0:
            return None
        return sum(draws) / len(draws) / seed


def most_seeds(settings: QuestionSettings, cost: Cost) -> int:
    """The most seeds a later draw may get: ``question.seeds.most``, else as many as cost what
    a draw costs (its training and solvers over one seed's runs, the mean over the models), at
    least the study's seeds and ``question.seeds.least`` (never below the least asked for:
    issue 61), at most the seed stride."""
    if settings.most_seeds is not None:
        return settings.most_seeds
    ratio = cost.cost_ratio()
    most = settings.seeds if ratio is None else max(settings.seeds, math.floor(ratio))
    return min(max(most, settings.least_seeds), settings.seed_stride)


def _cpu(path: Path) -> float | None:
    from cape.storage.io import read_benchmark

    if not path.is_file():
        return None
    row = read_benchmark(path).iloc[0]
    try:
        value = float(row.get("cpu_time"))
    except (TypeError, ValueError):
        value = math.nan
    return value if math.isfinite(value) else float(row["s"])


def training_cpu(model: str, seed: int, tsv: Path) -> float | None:
    """A training's CPU seconds over all its parts: the ``cpu_seconds`` its meta.json records;
    for a training run before that was recorded, the benchmark's ``cpu_time``, which covers
    only the last part of a resumed training, scaled up by the training's whole wall time over
    that part's. None: neither file is there."""
    from cape.errors import CapeError
    from cape.storage.io import read_benchmark, read_json

    meta_path = Path(paths.training_dir(model, seed)) / paths.META
    try:
        meta = read_json(meta_path, "a training's meta.json", "its training reruns it")
    except CapeError:
        meta = {}
    recorded = meta.get("cpu_seconds")
    if isinstance(recorded, (int, float)) and math.isfinite(recorded):
        return float(recorded)
    last = _cpu(tsv)
    if last is None:
        return None
    part_wall = float(read_benchmark(tsv).iloc[0]["s"])
    whole_wall = meta.get("wall_seconds")
    if isinstance(whole_wall, (int, float)) and part_wall > 0 and whole_wall > part_wall:
        return last * float(whole_wall) / part_wall
    return last


def costs(settings: QuestionSettings, plan: Plan) -> Cost:
    """What the question's draws and the stage's runs cost, from the rules' benchmark files
    (trainings, solvers: ``cpu_time``) and each run's timing.json (its phases' wall seconds,
    single-threaded: its CPU, near enough). A file not there is listed in ``missing``."""
    from cape.layout.record import read_timing

    cost = Cost(etas=len(settings.etas))
    for model, d in plan.draws.items():
        meta = draw_meta(model, d - 1)
        consulted = meta.get("draw", {}).get("trainings", [])
        cost.tried[model] = len(consulted)
        cost.failed[model] = sum(not t.get("trained") for t in consulted)
        cost.draws[model] = d
        spent = []
        for t in consulted:
            tsv = Path(paths.benchmark("train", model, f"seed{int(t['seed'])}.tsv"))
            cpu = training_cpu(model, int(t["seed"]), tsv)
            if cpu is None:
                cost.missing.append(str(tsv))
            else:
                spent.append(cpu)
        cost.trainings[model] = spent
        for r in range(d):
            for controller in NMPCS:
                tsv = Path(
                    paths.benchmark("solvers", replicate_name(r), controller, f"{model}.tsv")
                )
                built = _cpu(tsv) or 0.0
                cost.solvers_s += built
                cost.solvers[model] = cost.solvers.get(model, 0.0) + built
    for run in stage_runs(settings, plan):
        folder = run.folder()
        try:
            phases = read_timing(folder).get("job_s", {})
        except Exception:
            cost.missing.append(str(folder / paths.TIMING))
            continue
        cost.runs_s += sum(
            float(phases.get(k, 0.0)) for k in ("startup", "config", "build", "lap", "write")
        )
        cost.runs += 1
    return cost


def tally(states: Sequence[RowState]) -> dict[str, int]:
    """How many rows stand at each decision (those that occur)."""
    counts = {d: sum(s.decision == d for s in states) for d in DECISIONS}
    return {d: c for d, c in counts.items() if c}


def stage_record(
    stage: int,
    n: int,
    draws: Mapping[str, int],
    states: Sequence[RowState],
    cost: Cost,
    wall: float,
    seeds: Sequence[int] = (),
    most: int | None = None,
) -> dict[str, Any]:
    """One stage's line of the report (``seeds``: each draw index's, the next stage's
    included; ``most``: the most seeds a later draw could get, which futility assumed)."""
    return {
        "stage": stage + 1,
        "look at draws": n,
        "draws": dict(draws),
        "seeds": list(seeds),
        "most seeds": most,
        "commit": commit(),
        "cpu by model": {
            m: round(sum(cost.trainings.get(m, [])) + cost.solvers.get(m, 0.0), 1) for m in draws
        },
        "runs_s": round(cost.runs_s, 1),
        "trainings tried": dict(cost.tried),
        "trainings failed": dict(cost.failed),
        **{d: sum(s.decision == d for s in states) for d in DECISIONS},
        "cpu_s": round(cost.total, 1),
        "cpu missing": len(cost.missing),
        "wall_s": round(wall, 1),
    }


def looks_frame(states: Sequence[RowState]) -> pd.DataFrame:
    """Every row at every look it had: the figure's and looks.csv's table."""
    records = []
    for s in states:
        for k, lk in enumerate(s.looks):
            records.append(
                {
                    "claim": s.row.name,
                    "metric": s.row.metric,
                    "comparison": s.row.comparison,
                    "look": k + 1,
                    "draws": lk.draws,
                    "estimate": lk.estimate,
                    "low": lk.low,
                    "high": lk.high,
                    "equivalence_low": lk.equivalence_low,
                    "equivalence_high": lk.equivalence_high,
                    "margin": s.row.margin if s.row.margin is not None else math.nan,
                    "side": s.row.pair.paper_effect,
                    "decision": lk.decision,
                    "why": lk.why,
                    "chance": lk.chance,
                    **_spread(lk),
                }
            )
    return pd.DataFrame(records)


def _spread(lk: Any) -> dict[str, float]:
    """A look's draws × seeds structure, for looks.csv."""
    sp = lk.spread
    if sp is None:
        return {"between_var": math.nan, "within_var": math.nan, "seeds_share": math.nan}
    return {"between_var": sp.between, "within_var": sp.within, "seeds_share": sp.seeds_share}


def summary_line(
    states: Sequence[RowState],
    cost: Cost,
    finished: bool,
    remaining_cpu: float,
    walls: Mapping[int, float],
) -> str:
    """The terminal's line after a look: rows settled, their verdicts, the CPU, what is left."""
    if finished:
        ahead = "done"
    elif math.isfinite(remaining_cpu):
        ahead = f"to the cap at most {remaining_cpu:,.0f} s more CPU, ≈ " + ", ".join(
            f"{w / 3600:.1f} h on {n} cores" for n, w in walls.items() if math.isfinite(w)
        )
    else:
        ahead = "to the cap: its cost is not measured (a benchmark file is missing)"
    settled = sum(s.settled for s in states)
    verdicts = ", ".join(f"{v} {c}" for v, c in tally(states).items())
    return (
        f"{settled} of {len(states)} rows settled ({verdicts}); CPU so far {cost.total:,.0f} s; "
        f"{ahead}"
    )


def remaining(
    states: Sequence[RowState],
    settings: QuestionSettings,
    draws: Mapping[str, int],
    cost: Cost,
    later_seeds: int,
) -> float:
    """The most CPU left to the cap: every model of an open row taken to the last stage's
    draws, each new draw at this study's measured cost (training and its seeds' runs)."""
    open_models = {m for s in states if not s.done for m in s.row.models}
    total = 0.0
    for m in open_models:  # NaN where a cost is not measured: never counted as zero
        per = cost.per_draw(m) + cost.per_seed() * later_seeds
        total += max(0, settings.stages[-1] - draws.get(m, 0)) * per
    return total


def further_draw(cost: Cost, settings: QuestionSettings, later_seeds: int) -> dict[str, float]:
    """What one more draw of each model costs the question, CPU seconds: its trainings and
    solvers (per draw, failed trainings included) and ``later_seeds`` seeds of NMPC runs."""
    return {m: cost.per_draw(m) + cost.per_seed() * later_seeds for m in settings.models}


def projected_wall(
    states: Sequence[RowState],
    settings: QuestionSettings,
    draws: Mapping[str, int],
    cost: Cost,
    later_seeds: int,
    slots: int,
) -> float:
    """The wall time to the cap on ``slots`` single-core slots (2: this machine; N nodes × C
    cores through the SLURM profile) if every open row stays open: stage after stage (a look
    waits for its stage), each stage's trainings list-scheduled longest first, then its runs
    spread over the slots (the profile's groups are a draw at one η and one seed, short beside
    a training). At this study's measured costs; queue waits are not included."""
    open_models = sorted({m for s in states if not s.done for m in s.row.models})
    seed = cost.per_seed()
    current = {m: draws.get(m, 0) for m in open_models}
    wall = 0.0
    for n in settings.stages:
        new = {m: n - d for m, d in current.items() if n > d}
        if not new:
            continue
        trainings = [cost.per_draw(m) for m, k in new.items() for _ in range(k)]
        trainings.sort(reverse=True)
        if any(not math.isfinite(c) for c in trainings) or not math.isfinite(cost.per_seed()):
            return math.nan  # a cost not measured: no projection
        finish = [0.0] * max(1, slots)
        for seconds in trainings:
            finish[finish.index(min(finish))] += seconds
        wall += max(finish) + sum(new.values()) * later_seeds * seed / max(1, slots)
        current.update({m: n for m in new})
    return wall


def _fmt(value: float, digits: int = 3) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def _pct(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.0%}"


def _share(lk: Any) -> str:
    return "–" if lk.spread is None else _pct(lk.spread.seeds_share)


def seed_runs(seeds: Sequence[int]) -> str:
    """Seeds per draw index, run-length encoded: ``5 (draws 0–2), 3 (draws 3–5)``."""
    parts, start = [], 0
    for r in range(1, len(seeds) + 1):
        if r == len(seeds) or seeds[r] != seeds[start]:
            span = f"draw {start}" if r - start == 1 else f"draws {start}–{r - 1}"
            parts.append(f"{seeds[start]} ({span})")
            start = r
    return ", ".join(parts)


def markdown(
    settings: QuestionSettings,
    design: Design,
    states: Sequence[RowState],
    stages: Sequence[Mapping[str, Any]],
    components: pd.DataFrame | None,
    seeds_said: str,
    remaining_cpu: float,
    projections: Mapping[int, float] | None = None,
    recipes: Mapping[str, str] | None = None,
    further: Mapping[str, float] | None = None,
) -> str:
    """results/question/RESULTS.md: the stages, each row's decision and its intervals, where it
    stopped and why."""
    models = ", ".join(m.upper() for m in settings.models)
    lines = [
        "# The ground-truth question, in stages",
        "",
        f"Which learned model, inside the NMPCs, drives the ground-truth plant best: {models} "
        "(claimed best first; each pair tested as the first better than the second) on five "
        "closed-loop metrics. Verdicts over training draws by a group-sequential t-test "
        f"(family-wise α {settings.alpha:g} over {design.rows} rows and every look: each row "
        f"{design.per_row:.2g}, spent as α·(n/{design.looks[-1]})^{settings.spending:g}); "
        "`equivalent`: the two one-sided tests put the effect inside ±margin, no practical "
        "difference. docs/question.md says how to read it.",
        "",
        *(
            [
                "Recipes: "
                + "; ".join(f"{m.upper()} {recipes.get(m, '')}" for m in settings.models)
                + " (SPEC §4.2: the question trains DDM as its authors drive it).",
                "",
            ]
            if recipes
            else []
        ),
        "## Stages",
        "",
        "| stage | draws per model | trainings tried (failed) | holds | contradicted | "
        "equivalent | inconclusive | futile | open | CPU so far (s) | wall of the stage (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in stages:
        draws = ", ".join(f"{m.upper()} {d}" for m, d in s["draws"].items())
        tried = ", ".join(
            f"{m.upper()} {s['trainings tried'].get(m, 0)} ({s['trainings failed'].get(m, 0)})"
            for m in s["draws"]
        )
        lines.append(
            f"| {s['stage']} | {draws} | {tried} | {s[HOLDS]} | {s[CONTRADICTED]} | "
            f"{s[EQUIVALENT]} | {s[INCONCLUSIVE]} | {s.get(FUTILE, 0)} | {s[OPEN]} | "
            f"{s['cpu_s']:,.0f} | "
            f"{s['wall_s']:,.0f} |"
        )
    open_rows = [s for s in states if not s.done]
    last = stages[-1] if stages else {}
    undecided = [s for s in states if s.done and not s.settled]
    if all(s.settled for s in states):
        stop = "every row is settled"
    elif last and last.get("look at draws") == settings.stages[-1]:
        stop = (
            f"the cap ({settings.stages[-1]} draws per model) was reached with "
            f"{len(undecided)} rows inconclusive (each row's `why` says why)"
        )
    elif not open_rows and any(s.decision == FUTILE for s in states):
        stop = (
            f"every row is settled, or futile ({sum(s.decision == FUTILE for s in states)}: "
            f"its chance of settling by {settings.stages[-1]} draws fell below "
            f"{settings.futility:.0%}, so it stopped buying draws) or inconclusive for good"
        )
    elif not open_rows:
        stop = (
            f"every row is settled or inconclusive for good ({len(undecided)}: a draw without a "
            "value, see their `why`)"
        )
    else:
        walls = ", ".join(
            f"{w / 3600:.1f} h on {n} cores"
            for n, w in (projections or {}).items()
            if math.isfinite(w)
        )
        cpu = f"{remaining_cpu:,.0f} s" if math.isfinite(remaining_cpu) else "not measured"
        stop = (
            f"the run stopped after stage {last.get('stage', 0)}; `cape question` continues it "
            f"(to the cap, if every open row stays open: at most {cpu} more CPU; wall time ≈ "
            f"{walls or 'not measured'}; the cluster's by this report's own list scheduling, "
            "without the SLURM profile's per-job overheads or queue waits)"
        )
    lines += ["", f"**Where it stopped:** {stop}.", ""]
    lines += [
        f"Seeds per draw (each draw its own: draw r's are r·{settings.seed_stride} + 0 … S − 1, "
        f"shared by the models of the draw): {settings.seeds} for the first "
        f"{settings.stages[0]} draws; later ones {seeds_said}"
        + (f"; as run: {seed_runs(stages[-1].get('seeds', []))}" if stages else "")
        + ".",
        "",
        *(
            [
                "One further draw costs, in CPU (its trainings and solvers, then its seeds' "
                "NMPC runs): "
                + "; ".join(
                    f"{m.upper()} {v:,.0f} s" if math.isfinite(v) else f"{m.upper()} not measured"
                    for m, v in further.items()
                )
                + ".",
                "",
            ]
            if further
            else []
        ),
        "## Rows",
        "",
        "Each row's first interval is valid over all its looks together (a repeated "
        "confidence interval at its row's α): the differences it excludes are ruled out, "
        "settled or not. *seeds' share*: of the variance of a draw's effect, the part its "
        "disturbance seeds make (the rest: the draws' own spread); *chance*: of settling by the "
        "cap under the current estimate, for rows left open or futile.",
        "",
        "| claim | comparison | decision | at draws | estimate | interval over all looks | "
        "interval (equivalence) | margin | seeds' share | chance | why |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in states:
        lk = s.looks[-1] if s.looks else None
        if lk is None:
            continue
        margin = "–" if s.row.margin is None else f"±{s.row.margin:g}"
        lines.append(
            f"| {s.row.name} | {s.row.comparison} | {s.decision} | {lk.draws} | "
            f"{_fmt(lk.estimate)} | [{_fmt(lk.low)}, {_fmt(lk.high)}] | "
            f"[{_fmt(lk.equivalence_low)}, {_fmt(lk.equivalence_high)}] | {margin} | "
            f"{_share(lk)} | {_pct(lk.chance)} | {lk.why} |"
        )
    if components is not None and not components.empty:
        lines += [
            "",
            "## What chose the latest seeds per draw",
            "",
            "The open rows' variance components at the last look that chose seeds, and their "
            "chance of settling at the next look on the seeds chosen.",
            "",
            "| claim | comparison | σ² between draws | σ² within a draw | seeds' share | "
            "chance at the next look |",
            "|---|---|---|---|---|---|",
        ]
        for _, r in components.iterrows():
            lines.append(
                f"| {r['claim']} | {r['comparison']} | {_fmt(r['between_var'])} | "
                f"{_fmt(r['within_var'])} | {_pct(r['seeds_share'])} | "
                f"{_pct(r['chance_next'])} |"
            )
    return "\n".join(lines) + "\n"


def final_rows(looks: pd.DataFrame) -> pd.DataFrame:
    """Table 10: every row of the question at its last look (looks.csv's last line per row)."""
    columns = ["claim", "comparison", "decision", "draws", "estimate", "low", "high",
               "equivalence_low", "equivalence_high", "margin", "seeds_share", "chance",
               "why"]  # fmt: skip
    if looks.empty:
        return pd.DataFrame(columns=columns)
    last = looks.sort_values("look", kind="stable").groupby(["claim", "comparison"], sort=False)
    return last.tail(1).reindex(columns=columns).reset_index(drop=True)
