"""The ``cape`` command line: subcommands, outputs, and clear errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cape.cli import main


def test_help_lists_subcommands() -> None:
    out = subprocess.run(["cape", "--help"], capture_output=True, text=True, check=True).stdout
    for command in ("tracks", "data", "plot-tracks"):
        assert command in out


def test_a_rollout_process_imports_neither_pytorch_nor_pandas() -> None:
    """Thousands of rollout jobs each start a process: what the closed loop and the NMPC
    import must stay light (PyTorch alone costs seconds to import)."""
    code = (
        "import sys, cape.cli, cape.closedloop.setup, cape.controllers.registry as r;"
        "import cape.storage.io;"
        "[r.controller_class(n) for n in ('pid', 'rise', 'nmpc', 'anmpc', 'rnmpc')];"
        "import cape.models.network, cape.models.trained;"
        "import cape.layout.record;"
        "print(sorted(m for m in ('torch', 'pandas', 'scipy.interpolate', 'matplotlib', 'pyarrow')"
        " if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_data_command_writes_the_published_set(
    track_dir: Path, tmp_path: Path, config, datasets
) -> None:
    out = tmp_path / "DYN-PP-ETHZMobil.npz"
    cfg = json.dumps({"tracks": config["tracks"], "data": config["data"]})
    code = main(
        [
            "data",
            "--track",
            "ETHZMobil",
            "--out",
            str(out),
            "--tracks-dir",
            str(track_dir),
            "--config-json",
            cfg,
        ]
    )
    assert code == 0
    with np.load(out) as npz:
        assert sorted(npz.files) == sorted(["time", "states", "dstates", "inputs", "vrefs"])
        np.testing.assert_array_equal(npz["dstates"], datasets["ETHZMobil"]["dstates"])
    # written atomically, no leftovers; its owner record beside it (cape.storage.ownership)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([out.name, f".{out.name}.owner"])


def test_unknown_track_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["data", "--track", "Monza", "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "--track Monza" in err and "ETHZMobil" in err


def test_missing_track_files_point_to_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        ["data", "--track", "ETHZ", "--out", str(tmp_path / "x.npz"), "--tracks-dir", str(tmp_path)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "track file missing" in err and "snakemake" in err


def test_plot_tracks(track_dir: Path, tmp_path: Path, datasets, config) -> None:
    paths = {}
    for track, data in datasets.items():
        paths[track] = tmp_path / f"{track}.npz"
        np.savez(paths[track], **data)
    pdf, png = tmp_path / "fig.pdf", tmp_path / "fig.png"
    args = ["plot-tracks", "--tracks-dir", str(track_dir), "--out", str(pdf), "--out", str(png)]
    for track, path in paths.items():
        args += ["--data", f"{track}={path}"]
    assert main(args) == 0
    assert pdf.read_bytes().startswith(b"%PDF") and png.read_bytes().startswith(b"\x89PNG")


def test_module_entry_point() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "cape.cli", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.startswith("cape ")


@pytest.mark.parametrize("content", [b"", b"not a zip archive", b"PK\x03\x04 truncated"])
def test_a_data_set_that_is_not_an_npz_is_one_line_and_exit_2(
    tmp_path: Path, content: bytes
) -> None:
    """`cape train --data` of an empty, foreign or truncated file: one line naming the file and
    the fix, exit 2, no traceback, and the output folder never made."""
    data = tmp_path / "broken data.npz"
    data.write_bytes(content)
    out = tmp_path / "model"
    done = subprocess.run(
        [sys.executable, "-m", "cape.cli", "train", "--model", "dpm", "--data", str(data),
         "--out", str(out)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert f"{data}: not a readable .npz" in done.stderr and "snakemake --cores 2" in done.stderr
    assert not out.exists()
