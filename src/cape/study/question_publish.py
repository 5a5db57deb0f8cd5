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
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cape.errors import CapeError
from cape.study.question import RowState, evaluate, values_from_frame
from cape.study.question_plan import QuestionSettings
from cape.study.question_report import draw_meta, looks_frame
from cape.study.question_state import QuestionState, commit

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
    from cape.study.question_report import final_rows

    looks = pd.read_csv(folder / "looks.csv")
    (folder / "figures").mkdir(parents=True, exist_ok=True)
    save_figure(question_looks(looks), str(folder / DRAWN[0]), dpi=PNG_DPI)
    table = final_rows(looks)
    write_table(table, [str(folder / DRAWN[2]), str(folder / DRAWN[1])],
                formats=number_formats(table))  # fmt: skip


REQUIRED = ("looks.csv", "looks.json", "values.csv")
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
    settings = QuestionSettings.from_identity(state.design)
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
        "cpu_s": last.get("cpu_s"),
        "wall_s": round(sum(float(line.get("wall_s", 0.0)) for line in state.looks), 1),
    }


def read_folder(folder: Path) -> tuple[QuestionState, pd.DataFrame, pd.DataFrame]:
    """A published (or working) question folder's record, values and looks; ``CapeError``
    naming the file where one is missing or unreadable."""
    for name in REQUIRED:
        if not (folder / name).is_file():
            raise CapeError(
                f"{folder / name} not found: a published question holds {', '.join(REQUIRED)} "
                "(`cape question --publish` writes them)"
            )
    try:
        state = QuestionState.parse(json.loads((folder / "looks.json").read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CapeError(f"{folder / 'looks.json'}: not a question's record ({exc!r})") from exc
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
    the stages' draws and the most seeds each stage assumed: looks.csv's table."""
    try:
        settings = QuestionSettings.from_identity(state.design)
    except (KeyError, TypeError, ValueError) as exc:
        raise CapeError(
            f"looks.json: its design is not one `cape question` records ({exc!r})"
        ) from exc
    design = settings.design()
    states = [RowState(row) for row in settings.rows()]
    per_seed = values_from_frame(values)
    for k, line in enumerate(state.looks):
        if k >= len(design.looks) or int(line["look at draws"]) != design.looks[k]:
            raise CapeError(f"looks.json: stage {k + 1} is not the design's look {k + 1}")
        evaluate(per_seed, states, design, k, line.get("most seeds"))
    return looks_frame(states)


def differences(derived: pd.DataFrame, published: pd.DataFrame) -> list[str]:
    """Where the re-derived looks differ from the published ones: a row or look missing, a
    decision, or a number beyond ``TOLERANCE`` (both NaN is equal)."""
    key = ["claim", "comparison", "look"]
    out = []
    a = derived.set_index(key)
    b = published.set_index(key)
    for name in sorted(set(a.index) ^ set(b.index), key=str):
        out.append(f"{' / '.join(map(str, name))}: in one table only")
    for name in a.index.intersection(b.index):
        ra, rb = a.loc[name], b.loc[name]
        where = f"{name[0]} ({name[1]}), look {name[2]}"
        if str(ra["decision"]) != str(rb["decision"]):
            out.append(f"{where}: published {rb['decision']!r}, re-derived {ra['decision']!r}")
        for column in NUMERIC:
            if column not in a.columns or column not in b.columns:
                continue
            x, y = float(ra[column]), float(rb[column])
            if math.isnan(x) and math.isnan(y):
                continue
            if not math.isclose(x, y, rel_tol=TOLERANCE, abs_tol=1e-12):
                out.append(f"{where}: {column} published {y!r}, re-derived {x!r}")
    return out


class Published:
    """A published question to continue from (``cape question --reuse``): its record, and
    its values per claim and (model, draw). A draw is reused when the folder holds every claim's
    values of it on exactly the seeds the plan gives it."""

    def __init__(self, folder: Path, design: Mapping[str, Any]) -> None:
        from cape.study.question_state import changed_keys

        self.folder = folder
        self.state, values, _ = read_folder(folder)
        if self.state.design != design:
            key, was, now = changed_keys(self.state.design, design)[0]
            raise CapeError(
                f"{folder / 'looks.json'}: published under another design (`{key}` was "
                f"{json.dumps(was)}, now {json.dumps(now)}); only the same question's draws "
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
