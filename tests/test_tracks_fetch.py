"""Obtaining the track files (SPEC §2): mirror, checksums, clear failures."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from cape.cli import main
from cape.errors import CapeError
from cape.tracks.fetch import obtain_tracks, sha256, verify_file
from cape.tracks.manifest import BAYESRACE_FILES
from cape.tracks.track import load_track

UNREACHABLE = (
    "http://127.0.0.1:9/{commit}/{file}"  # the discard port: refused at once, no network needed
)


def test_manifest_lists_the_ten_files() -> None:
    assert len(BAYESRACE_FILES) == 10
    assert all(len(digest) == 64 for digest in BAYESRACE_FILES.values())


def test_every_obtained_file_matches_its_digest(track_dir: Path) -> None:
    for name, digest in BAYESRACE_FILES.items():
        assert sha256((track_dir / name).read_bytes()) == digest


def test_copy_from_mirror_without_network(track_dir: Path, tmp_path: Path) -> None:
    dest = tmp_path / "dest"
    written = obtain_tracks(dest, mirror=track_dir, url_template=UNREACHABLE, log=lambda _m: None)
    assert sorted(p.name for p in written) == sorted(BAYESRACE_FILES)
    assert sorted(p.name for p in dest.iterdir()) == sorted(BAYESRACE_FILES)  # no temp files left


def test_corrupted_mirror_file_fails_the_checksum(track_dir: Path, tmp_path: Path) -> None:
    mirror = tmp_path / "mirror"
    shutil.copytree(track_dir, mirror)
    victim = mirror / "ethzMobil_center.txt"
    victim.write_bytes(victim.read_bytes().replace(b"1.2", b"1.3", 1))
    dest = tmp_path / "dest"
    with pytest.raises(CapeError) as err:
        obtain_tracks(dest, mirror=mirror, url_template=UNREACHABLE, log=lambda _m: None)
    msg = str(err.value)
    assert "ethzMobil_center.txt" in msg and "fails its checksum" in msg
    assert "tracks.mirror" in msg and "upstream" in msg  # names both ways of providing it
    assert not (dest / "ethzMobil_center.txt").exists()  # nothing unverified is written


def test_corrupted_file_in_place_is_caught_when_loaded(track_dir: Path, tmp_path: Path) -> None:
    local = tmp_path / "tracks"
    shutil.copytree(track_dir, local)
    (local / "ethz_outer.txt").write_bytes(b"0,1\n0,1\n")
    with pytest.raises(CapeError, match=r"ethz_outer.txt: SHA-256 mismatch .* delete it"):
        load_track(local, "ETHZ", "ethz", 0.37)
    with pytest.raises(CapeError, match="track file missing"):
        verify_file(tmp_path / "ethz_center.txt")


def test_no_mirror_and_no_network_gives_the_clear_message(tmp_path: Path) -> None:
    with pytest.raises(CapeError) as err:
        obtain_tracks(
            tmp_path / "dest",
            mirror=tmp_path / "absent",
            url_template=UNREACHABLE,
            log=lambda _m: None,
        )
    msg = str(err.value)
    assert "cannot obtain track file" in msg
    assert (
        "local mirror folder" in msg and "tracks.mirror" in msg and str(tmp_path / "absent") in msg
    )
    assert "network access to the pinned upstream commit" in msg and "0a23cf95" in msg


def test_cli_reports_failure_without_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "tracks",
            "--dest",
            str(tmp_path / "d"),
            "--mirror",
            str(tmp_path / "absent"),
            "--url",
            UNREACHABLE,
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("cape tracks: error: cannot obtain track file")
    assert "Traceback" not in err


def test_present_verified_files_are_kept(track_dir: Path, tmp_path: Path) -> None:
    dest = tmp_path / "dest"
    shutil.copytree(track_dir, dest)
    messages: list[str] = []
    obtain_tracks(dest, mirror=None, url_template=None, log=messages.append)
    assert all("already present and verified" in m for m in messages) and len(messages) == 10
