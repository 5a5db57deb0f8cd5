"""A question's answer, published and re-derivable (docs/question.md, "Published answers").

``publish`` copies what `cape question` wrote after its last look (RESULTS.md, looks.csv,
looks.json, values.csv, the variance components, figure 15, table 10) into a folder and adds
``provenance.json``: the commit, the config's digest, the machine, the training and disturbance
seeds of every draw, and each stage's CPU and wall time. ``rederive`` re-decides every look
from such a folder's ``values.csv`` and ``looks.json`` alone, and ``differences`` compares the
result with its ``looks.csv``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cape.errors import CapeError
from cape.study.question.looks import RowState, evaluate, values_from_frame
from cape.study.question.plan import QuestionSettings
from cape.study.question.report import draw_meta, looks_frame
from cape.study.question.state import QuestionState, commit

COPIED = ("RESULTS.md", "looks.csv", "looks.json", "values.csv", "variance_components.csv")
"""What a published question copies from results/question/ (the same names in the folder)."""
DRAWN = ("figures/fig15_question_looks.png", "tables/table10_question.md",
         "tables/table10_question.csv")  # fmt: skip
"""What it draws from the looks it copies (figure 15, table 10), so they are of that look."""


def draw(folder: Path) -> None:
    """Figure 15 (PNG) and table 10 (CSV, Markdown) of ``folder``'s looks.csv, as the
    question's notebook draws them."""
    from cape.plots.question import question_looks
    from cape.plots.style import PNG_DPI, save_figure
    from cape.storage.tables import number_formats, write_table
    from cape.study.question.report import final_rows

    looks = pd.read_csv(folder / "looks.csv")
    (folder / "figures").mkdir(parents=True, exist_ok=True)
    save_figure(question_looks(looks), str(folder / DRAWN[0]), dpi=PNG_DPI)
    table = final_rows(looks)
    write_table(table, [str(folder / DRAWN[2]), str(folder / DRAWN[1])],
                formats=number_formats(table))  # fmt: skip


REQUIRED = ("looks.csv", "looks.json", "values.csv")
REPUBLISH = "`cape question --publish FOLDER` copies them from results/question/"
NUMERIC = ("estimate", "se", "low", "high", "equivalence_low", "equivalence_high", "chance")
TOLERANCE = 1e-9
"""Relative difference a re-derived number may have from the published one (another CPU's
floating-point path); decisions must be equal."""


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def config_digest(config: Mapping[str, Any]) -> str:
    """The SHA-256 of the config as canonical JSON (sorted keys)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


def machine() -> dict[str, Any]:
    """The CPU model, its cores and the Python version that made a published result."""
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "python": platform.python_version()}


def draw_record(r: int, meta: Mapping[str, Any], seeds: Iterable[int]) -> dict[str, Any]:
    """A draw's line of a provenance file, from its meta.json: its training seed, whether it
    trained, the trainings it was chosen among, and its disturbance seeds."""
    draw = meta.get("draw") or {}
    return {
        "draw": r,
        "training seed": meta.get("seed"),
        "trained": draw.get("trained"),
        "trainings tried": [
            {"seed": t.get("seed"), "trained": t.get("trained")} for t in draw.get("trainings", [])
        ],
        "disturbance seeds": list(seeds),
    }


def provenance(config: Mapping[str, Any], state: QuestionState) -> dict[str, Any]:
    """What made a question's answer: commit, config digest, machine, each model's draws with
    their training seeds (failed ones too) and disturbance seeds, and every stage's cost."""
    try:
        settings = QuestionSettings.from_identity(state.design)
    except ValueError as exc:
        raise CapeError(
            f"looks.json: its design is not one `cape question` records ({exc}); run `cape "
            "question` again, which rewrites it"
        ) from exc
    last = state.looks[-1] if state.looks else {}
    draws: dict[str, list[dict[str, Any]]] = {}
    for model, count in (last.get("draws") or {}).items():
        for r in range(int(count)):
            seeds = settings.draw_seeds(r, state.seeds[r]) if r < len(state.seeds) else []
            draws.setdefault(model, []).append(draw_record(r, draw_meta(model, r), seeds))
    stages = [
        {
            "stage": line.get("stage"),
            "look at draws": line.get("look at draws"),
            "draws": line.get("draws"),
            "cpu_s (cumulative)": line.get("cpu_s"),
            "wall_s": line.get("wall_s"),
            "trainings tried": line.get("trainings tried"),
            "trainings failed": line.get("trainings failed"),
            "run by commit": line.get("commit", "not recorded (before CAPE recorded it)"),
        }
        for line in state.looks
    ]
    return {
        "published by commit": commit(),
        "config_sha256": config_digest(config),
        "machine": machine(),
        "design": state.design,
        "draws": draws,
        "stages": stages,
        "training cpu_s, every part": trainings_cpu(draws),
        "cpu_s": last.get("cpu_s"),
        "wall_s": round(sum(float(line.get("wall_s", 0.0)) for line in state.looks), 1),
    }


def trainings_cpu(draws: Mapping[str, list[dict[str, Any]]]) -> dict[str, float | None]:
    """Per model, the CPU seconds of every training its draws were chosen among, each over all
    its parts (``report.training_cpu``): a stage line recorded before CAPE counted a
    resumed training's every part holds only its last; None where a record is missing."""
    from cape.layout import paths
    from cape.study.question.report import training_cpu

    out: dict[str, float | None] = {}
    for model, records in draws.items():
        seeds = {int(t["seed"]) for d in records for t in d["trainings tried"]}
        spent = [
            training_cpu(model, s, Path(paths.benchmark("train", model, f"seed{s}.tsv")))
            for s in sorted(seeds)
        ]
        out[model] = None if any(c is None for c in spent) else round(sum(spent), 1)  # type: ignore[arg-type]
    return out


def read_folder(folder: Path) -> tuple[QuestionState, pd.DataFrame, pd.DataFrame]:
    """A published (or working) question folder's record, values and looks; ``CapeError``
    naming the file where one is missing or unreadable."""
    for name in REQUIRED:
        if not (folder / name).is_file():
            raise CapeError(
                f"{folder / name} not found: a published question holds {', '.join(REQUIRED)} "
                "(`cape question --publish` writes them)"
            )
    state = QuestionState.load(folder / "looks.json", f"publish it again ({REPUBLISH})")
    try:
        values = pd.read_csv(folder / "values.csv")
        looks = pd.read_csv(folder / "looks.csv", keep_default_na=False, na_values=[""])
    except (OSError, ValueError) as exc:
        raise CapeError(f"{folder}: a CSV cannot be read ({exc})") from exc
    missing = {"metric", "model", "draw", "seed", "value"} - set(values.columns)
    if missing:
        raise CapeError(f"{folder / 'values.csv'}: lacks the columns {', '.join(sorted(missing))}")
    return state, values, looks


def rederive(state: QuestionState, values: pd.DataFrame) -> pd.DataFrame:
    """Every look re-decided from the per-(model, draw, seed) values and the recorded design,
    the stages' draws and the most seeds each stage assumed: looks.csv's table. ``CapeError``
    naming looks.json where its design or a stage's line is not one `cape question` records
    (``QuestionSettings.from_identity`` bounds the design as the config's schema does)."""
    try:
        settings = QuestionSettings.from_identity(state.design)
        design = settings.design()
        states = [RowState(row) for row in settings.rows()]
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError) as exc:
        why = f"`{exc.args[0]}` is missing" if isinstance(exc, KeyError) else str(exc)
        raise CapeError(
            f"looks.json: its design is not one `cape question` records ({why}); {REPUBLISH}"
        ) from exc
    per_seed = values_from_frame(values)
    for k, line in enumerate(state.looks):
        if k >= len(design.looks) or line.get("look at draws") != design.looks[k]:
            raise CapeError(f"looks.json: stage {k + 1} is not the design's look {k + 1}")
        evaluate(per_seed, states, design, k, line.get("most seeds"))
    return looks_frame(states)


KEY = ("claim", "comparison", "look")
"""What names a row of looks.csv: its claim, its comparison and the look."""


def _number(value: Any, where: str, column: str, source: str) -> float:
    """A number of looks.csv (empty: NaN); ``CapeError`` naming the cell where it is none."""
    if isinstance(value, str) and not value.strip():
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        raise CapeError(
            f"{source}: {where}: `{column}` is {value!r}, not a number; the file is not the "
            f"looks.csv `cape question` wrote ({REPUBLISH})"
        ) from None


def differences(
    derived: pd.DataFrame, published: pd.DataFrame, source: str = "looks.csv"
) -> list[str]:
    """Where the re-derived looks differ from the published ones (``source``: the published
    file, for a refusal): a row or look missing, a decision, or a number beyond ``TOLERANCE``
    (both NaN is equal). ``CapeError`` where the published table is not one looks.csv can be:
    a column missing, a row named twice, a number that is none."""
    missing = [c for c in (*KEY, "decision") if c not in published.columns]
    if missing:
        raise CapeError(
            f"{source}: lacks the column(s) {', '.join(missing)}; the file is not the looks.csv "
            f"`cape question` wrote ({REPUBLISH})"
        )
    published = published.assign(look=[_look(v, source) for v in published["look"]])
    repeated = published.duplicated(list(KEY))
    if repeated.any():
        first = published.loc[repeated.idxmax(), list(KEY)]
        raise CapeError(
            f"{source}: the row {' / '.join(map(str, first))} is there twice; the file is not "
            f"the looks.csv `cape question` wrote ({REPUBLISH})"
        )
    out = []
    a = derived.set_index(list(KEY))
    b = published.set_index(list(KEY))
    for name in sorted(set(a.index) ^ set(b.index), key=str):
        out.append(f"{' / '.join(map(str, name))}: in one table only")
    for name in a.index.intersection(b.index, sort=False):
        ra, rb = a.loc[name], b.loc[name]
        where = f"{name[0]} ({name[1]}), look {name[2]}"
        if str(ra["decision"]) != str(rb["decision"]):
            out.append(f"{where}: published {rb['decision']!r}, re-derived {ra['decision']!r}")
        for column in NUMERIC:
            if column not in a.columns or column not in b.columns:
                continue
            x, y = float(ra[column]), _number(rb[column], where, column, source)
            if math.isnan(x) and math.isnan(y):
                continue
            if not math.isclose(x, y, rel_tol=TOLERANCE, abs_tol=1e-12):
                out.append(f"{where}: {column} published {y!r}, re-derived {x!r}")
    return out


def _look(value: Any, source: str) -> Any:
    """A look's number as looks.csv holds it (an integer); ``CapeError`` where it is none."""
    try:
        number = float(value)
        if number.is_integer():
            return int(number)
    except (TypeError, ValueError, OverflowError):
        pass
    raise CapeError(
        f"{source}: a row's `look` is {value!r}, not a look's number; the file is not the "
        f"looks.csv `cape question` wrote ({REPUBLISH})"
    )


class Published:
    """A published question to continue from (``cape question --reuse``): its record, and
    its values per claim and (model, draw). A draw is reused when the folder holds every claim's
    values of it on exactly the seeds the plan gives it."""

    def __init__(self, folder: Path, design: Mapping[str, Any]) -> None:
        from cape.study.question.state import design_change

        self.folder = folder
        self.state, values, _ = read_folder(folder)
        if self.state.design != design:
            raise CapeError(
                f"{folder / 'looks.json'}: published under another design "
                f"({design_change(self.state.design, design)}); only the same question's draws "
                "can be reused"
            )
        self.values = values_from_frame(values)

    def covers(self, model: str, draw: int, seeds: range, claims: list[str]) -> bool:
        """Whether every claim has this draw's values on exactly ``seeds``."""
        for claim in claims:
            series = self.values.get(claim, {}).get((model, draw))
            if series is None or list(series.index) != list(seeds):
                return False
        return True

    def merge(self, values: dict[str, Any], reused: frozenset[tuple[str, int]]) -> dict:
        """``values`` with the reused draws' published values in."""
        for claim, per in self.values.items():
            target = dict(values.get(claim, {}))
            for key in reused:
                if key in per:
                    target[key] = per[key]
            values[claim] = target
        return values

    def stage(self, k: int) -> dict[str, Any] | None:
        """The published record of stage ``k`` (0-based), if it has one."""
        return self.state.looks[k] if k < len(self.state.looks) else None

    def reused(self, settings: Any, draws: Mapping[str, int], seeds: Sequence[int]) -> frozenset:
        """The stage's draws whose values this question holds on their planned seeds."""
        claims = sorted({row.name for row in settings.rows()})
        return frozenset(
            (m, r)
            for m, d in draws.items()
            for r in range(d)
            if self.covers(m, r, settings.draw_seeds(r, seeds[r]), claims)
        )

    def as_published(self, line: dict[str, Any], plan: Any, k: int) -> dict[str, Any]:
        """Stage ``k``'s line; where every draw of the stage was reused, its CPU, wall time and
        trainings are the published stage's (nothing ran here to measure them)."""
        every = {(m, r) for m, d in plan.draws.items() for r in range(d)}
        earlier = self.stage(k)
        if earlier is None or not every or not every <= plan.reused:
            return line
        keep = ("cpu_s", "wall_s", "trainings tried", "trainings failed", "cpu by model", "runs_s")
        return {**line, **{key: earlier[key] for key in keep if key in earlier}, "reused": True}

    def most(self, plan: Any, k: int, measured: int) -> int:
        """The most seeds futility assumes at stage ``k``: the published stage's where all its
        draws were reused (its costs were measured there, not here), else ``measured``."""
        earlier = self.stage(k)
        every = {(m, r) for m, d in plan.draws.items() for r in range(d)}
        if earlier is not None and every <= plan.reused and earlier.get("most seeds") is not None:
            return int(earlier["most seeds"])
        return measured
