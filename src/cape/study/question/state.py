"""The question's record between runs (results/question/looks.json): its design, the seeds each
draw index was given, every stage's line, and the wall time of a stage stopped before its look.

The design is fixed before the first look (SPEC §10, revision 7): a rerun whose design differs
from the one already looked at is refused, naming the changed key, and changes nothing. A
record that cannot be read is refused too (it holds the stages' wall times and the seeds
chosen, which the runs alone do not tell).
"""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cape.errors import CapeError
from cape.layout import paths

FORMAT = "cape-question/2"


def _json(path: Path, fix: str) -> Any:
    """``path``'s JSON; ``CapeError`` naming it and ``fix`` where it cannot be read as JSON."""
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError is a ValueError
        raise CapeError(
            f"{path}: not a record of `cape question` ({type(exc).__name__}: it holds the "
            f"design, the seeds chosen and the stages' wall times); {fix}"
        ) from exc


def commit() -> str | None:
    """The checkout's commit (``(src modified)`` where src/ differs from it), or None."""
    from cape.config import REPO_ROOT

    try:
        head = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=True)  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "src"],
                               capture_output=True, text=True, timeout=10, check=True)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + (" (src modified)" if dirty.stdout.strip() else "")


def _aside() -> str:
    return (
        f"to ask a new question, move {paths.QUESTION} to another folder (e.g. `mv "
        f"{paths.QUESTION} {paths.QUESTION}-earlier`: nothing deletes it) and run again"
    )


ABSENT = "(absent)"
"""How a key one design has and the other lacks is shown (not ``null``: a key set to null is
a value, and it differs from no key)."""


def changed_keys(before: Mapping[str, Any], now: Mapping[str, Any], prefix: str = "") -> list:
    """The dotted keys whose values differ between two designs, each with both values (a
    missing key: ``ABSENT``)."""
    out = []
    missing = object()
    for key in sorted(set(before) | set(now), key=str):
        a, b = before.get(key, missing), now.get(key, missing)
        name = f"{prefix}{key}"
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += changed_keys(a, b, name + ".")
        elif a is missing or b is missing or a != b:
            out.append((name, ABSENT if a is missing else a, ABSENT if b is missing else b))
    return out


def design_change(before: Mapping[str, Any], now: Mapping[str, Any]) -> str:
    """The first difference of two designs that differ, as a refusal says it: "`key` was X,
    now Y"."""
    changes = changed_keys(before, now)
    if not changes:  # equal key by key, yet not equal (a value that is not equal to itself)
        return "its keys' values are not equal to themselves"
    key, was, now_ = changes[0]

    def shown(value: Any) -> str:
        return value if value is ABSENT else json.dumps(value, default=str)

    return f"`{key}` was {shown(was)}, now {shown(now_)}"


def _whole(value: Any, what: str, least: int = 0) -> int:
    """``value`` as a whole number of at least ``least``: an integer (or a float that is one),
    never a bool, a string or an infinity; ``ValueError`` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} is {value!r}, not a whole number")
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise ValueError(f"{what} is {value!r}, not a whole number")
    if value < least:
        raise ValueError(f"{what} is {value!r}, less than {least}")
    return int(value)


def _seconds(value: Any, what: str) -> float:
    """``value`` as a finite number of seconds ≥ 0; ``ValueError`` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} is {value!r}, not a number of seconds")
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{what} is {value!r}, not a finite number of seconds ≥ 0")
    return float(value)


@dataclass
class QuestionState:
    """What looks.json holds: the design, the seeds of each draw index so far, the stages'
    lines, and the wall time (s) of a stage stopped before its look, by stage number."""

    design: dict[str, Any]
    seeds: list[int] = field(default_factory=list)
    looks: list[dict[str, Any]] = field(default_factory=list)
    stopped: dict[int, float] = field(default_factory=dict)

    @classmethod
    def read(cls, design: dict[str, Any], path: str = paths.QUESTION_STATE) -> QuestionState:
        """The record of this question, or a new one where none was looked at. ``CapeError``
        (nothing changed) for a record that cannot be read or whose design differs."""
        file = Path(path)
        if not file.exists():
            return cls(design)
        state = _json(file, f"restore it, or {_aside()}")
        if not isinstance(state, dict) or state.get("format") != FORMAT:
            looked = isinstance(state, dict) and bool(state.get("looks"))
            if not looked:  # nothing looked at: an earlier record without looks starts anew
                return cls(design)
            raise CapeError(
                f"{path}: a record of an earlier CAPE (before each draw had its own seeds, "
                f"CHANGELOG); its looks were taken on other runs: {_aside()}"
            )
        recorded = cls.checked(state, path, f"restore the file (`cape question` writes it), or "
                                            f"{_aside()}")  # fmt: skip
        if recorded.looks and recorded.design != design:
            raise CapeError(
                f"{path}: this question was looked at under another design: "
                f"{design_change(recorded.design, design)}; a design is fixed before the first "
                f"look (docs/question.md). Restore the config to continue it, or {_aside()}"
            )
        if not recorded.looks:
            recorded.design = design  # nothing looked at yet: the new design stands
        return recorded

    @classmethod
    def load(cls, path: str | Path, fix: str) -> QuestionState:
        """The record in ``path`` (a question folder's looks.json), whatever design it has;
        ``CapeError`` naming the file, what is wrong and ``fix`` where it is not one."""
        state = _json(Path(path), fix)
        if not isinstance(state, dict):
            raise CapeError(f"{path}: not a record of `cape question` (not a JSON object); {fix}")
        return cls.checked(state, path, fix)

    @classmethod
    def checked(cls, state: dict[str, Any], path: str | Path, fix: str) -> QuestionState:
        """``parse``, its refusal one ``CapeError`` naming ``path``, the field and ``fix``."""
        try:
            return cls.parse(state)
        except (KeyError, TypeError, ValueError) as exc:
            why = f"field {exc.args[0]!r} is missing" if isinstance(exc, KeyError) else str(exc)
            raise CapeError(
                f"{path}: not a record of `cape question` as it writes it ({why}); {fix}"
            ) from exc

    @classmethod
    def parse(cls, state: dict[str, Any]) -> QuestionState:
        """A record from looks.json's parsed JSON; KeyError, TypeError or ValueError where a
        field is missing or of the wrong type (``checked`` turns them into one line)."""
        if not isinstance(state, Mapping):
            raise TypeError("the record is not a JSON object")
        design = state["design"]
        if not isinstance(design, dict):
            raise TypeError("its `design` is not a mapping")
        if not isinstance(state["seeds"], list):
            raise TypeError("its `seeds` is not a list")
        seeds = [_whole(n, f"`seeds[{r}]`", 1) for r, n in enumerate(state["seeds"])]
        if not isinstance(state["looks"], list):
            raise TypeError("its `looks` is not a list")
        looks = list(state["looks"])
        for k, line in enumerate(looks):
            if not isinstance(line, dict):
                raise TypeError(f"`looks[{k}]` is not a mapping")
            _whole(line["stage"], f"`looks[{k}].stage`", 1)
            _seconds(line["wall_s"], f"`looks[{k}].wall_s`")
            if "look at draws" in line:
                _whole(line["look at draws"], f"`looks[{k}].look at draws`", 1)
            if line.get("most seeds") is not None:
                _whole(line["most seeds"], f"`looks[{k}].most seeds`", 1)
        stopped_ = state.get("stopped", {})
        if not isinstance(stopped_, dict):
            raise TypeError("its `stopped` is not a mapping of stage → seconds")
        stopped = {}
        for key, value in stopped_.items():
            try:
                stage = int(key)
            except ValueError:
                raise ValueError(f"`stopped` names stage {key!r}, not a number") from None
            stopped[stage] = _seconds(value, f"`stopped.{key}`")
        return cls(design, seeds, looks, stopped)

    def wall_before(self, stage: int) -> float:
        """Wall seconds an earlier run spent in stage ``stage`` (1-based) without looking."""
        return self.stopped.get(stage, 0.0)

    def as_json(self) -> str:
        return json.dumps(
            {
                "format": FORMAT,
                "design": self.design,
                "seeds": self.seeds,
                "looks": self.looks,
                "stopped": {str(k): v for k, v in self.stopped.items()},
            },
            indent=1,
            default=str,
        )
