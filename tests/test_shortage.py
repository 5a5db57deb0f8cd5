"""A machine that runs short (no thread, no process, no memory) ends a `cape` command with one
line naming the resource and the limit, exit status 2, never a traceback (issue 53)."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from cape.cli import main
from cape.cli.common import COMMANDS


@pytest.mark.parametrize(
    ("error", "said"),
    [
        (RuntimeError("can't start new thread"), "would not start another thread or process"),
        (OSError(errno.EAGAIN, "Resource temporarily unavailable"), "ulimit -u"),
        (MemoryError(), "out of memory"),
        (RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate 8 GB"),
         "out of memory"),
        (OSError(errno.ENOMEM, "Cannot allocate memory"), "ulimit -v"),
    ],
)  # fmt: skip
def test_a_shortage_is_one_line_naming_the_limit(
    error: BaseException, said: str, tmp_path: Path, monkeypatch, capsys
) -> None:
    help_text, arguments, _ = COMMANDS["train"]

    def short(_args: object) -> None:
        raise error

    monkeypatch.setitem(COMMANDS, "train", (help_text, arguments, short))
    argv = ["train", "--model", "dpm", "--data", "x.npz", "--out", str(tmp_path / "m")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("cape train: error: ") and said in err, err
    assert "run it again" in err


def test_another_runtime_error_is_a_bug_with_its_traceback(monkeypatch, tmp_path: Path) -> None:
    help_text, arguments, _ = COMMANDS["train"]

    def broken(_args: object) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setitem(COMMANDS, "train", (help_text, arguments, broken))
    with pytest.raises(RuntimeError, match="a bug"):
        main(["train", "--model", "dpm", "--data", "x.npz", "--out", str(tmp_path / "m")])
