"""Snakemake run as a child process, as `cape question` runs it for each stage: the workflow's
Snakefile (``snakefile``) and one target run with config files, its output logged and its
progress shown every tenth (``Snakemake``)."""

from __future__ import annotations

import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cape.errors import CapeError
from cape.processes import run_logged

STOP_GRACE = 60.0  # s: how long a stopped Snakemake gets to end its jobs before SIGKILL
PROGRESS = re.compile(r"(\d+) of (\d+) steps \((\d+)%\) done")


def snakefile() -> str:
    """The workflow's Snakefile: the working folder's, else the checkout's the package is in."""
    from cape.config import REPO_ROOT

    here = Path("Snakefile")
    return str(here if here.is_file() else REPO_ROOT / "Snakefile")


@dataclass(frozen=True)
class Snakemake:
    """Snakemake with ``cores`` (unless ``extra`` names its own) and the arguments ``extra``
    added to every run."""

    cores: int
    extra: Sequence[str] = ()

    def __call__(self, files: Sequence[str], log: Path, what: str, target: str) -> None:
        """Run ``target`` with the config ``files``; Snakemake's output goes to ``log``, its
        progress to the terminal every tenth. A failure is one CapeError naming the log."""
        cmd = [sys.executable, "-m", "snakemake", "-s", snakefile(), target, "--configfile", *files]
        if not any(a.startswith(("--cores", "-c")) for a in self.extra):
            cmd += ["--cores", str(self.cores)]
        cmd += list(self.extra)
        shown = [-1]

        def seen(line: str) -> None:
            done = PROGRESS.search(line)
            if done and (int(done[3]) // 10 > shown[0] or done[1] == done[2]):
                shown[0] = int(done[3]) // 10
                print(f"  {what}: {done[0]}", flush=True)

        status = run_logged(cmd, log, seen, grace=STOP_GRACE)
        if status != 0:
            raise CapeError(
                f"{what}: Snakemake failed (exit {status}); its output, with the failed job and "
                f"its log, is in {log}. Fix that, then run `cape question` again: it resumes"
            )
