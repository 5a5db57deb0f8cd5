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


def changed_keys(before: Mapping[str, Any], now: Mapping[str, Any], prefix: str = "") -> list:
    """The dotted keys whose values differ between two designs."""
    out = []
    for key in sorted(set(before) | set(now), key=str):
        a, b = before.get(key), now.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += changed_keys(a, b, name + ".")
        elif a != b:
            out.append((name, a, b))
    return out


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
        try:
            state = json.loads(file.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise CapeError(
                f"{path}: not a record of `cape question` ({type(exc).__name__}: it holds the "
                f"design, the seeds chosen and the stages' wall times); restore it, or {_aside()}"
            ) from exc
        if not isinstance(state, dict) or state.get("format") != FORMAT:
            looked = isinstance(state, dict) and bool(state.get("looks"))
            if not looked:  # nothing looked at: an earlier record without looks starts anew
                return cls(design)
            raise CapeError(
                f"{path}: a record of an earlier CAPE (before each draw had its own seeds, "
                f"CHANGELOG); its looks were taken on other runs: {_aside()}"
            )
        try:
            recorded = cls.parse(state)
        except (KeyError, TypeError, ValueError) as exc:
            raise CapeError(
                f"{path}: a field is missing or of the wrong type ({exc!r}); restore the file "
                f"(`cape question` writes it), or {_aside()}"
            ) from exc
        if recorded.looks and recorded.design != design:
            key, was, now = changed_keys(recorded.design, design)[0]
            raise CapeError(
                f"{path}: this question was looked at under another design: `{key}` was "
                f"{json.dumps(was)}, now {json.dumps(now)}; a design is fixed before the first "
                f"look (docs/question.md). Restore the config to continue it, or {_aside()}"
            )
        if not recorded.looks:
            recorded.design = design  # nothing looked at yet: the new design stands
        return recorded

    @classmethod
    def parse(cls, state: dict[str, Any]) -> QuestionState:
        """A record from looks.json's parsed JSON; KeyError, TypeError or ValueError where a
        field is missing or of the wrong type (``read`` turns them into one line)."""
        design = state["design"]
        seeds = [int(n) for n in state["seeds"]]
        looks = list(state["looks"])
        if not isinstance(design, dict) or any(n < 1 for n in seeds):
            raise ValueError("design must be a mapping, seeds positive")
        for line in looks:
            if not isinstance(line, dict):
                raise TypeError("a look must be a mapping")
            int(line["stage"]), float(line["wall_s"])
        stopped = {int(k): float(v) for k, v in state.get("stopped", {}).items()}
        if any(not math.isfinite(v) or v < 0 for v in stopped.values()):
            raise ValueError("a stopped stage's wall time must be a finite number of seconds")
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
