"""Obtain the BayesRace track files: copy from a local mirror or download from the pinned
upstream commit, and verify every SHA-256 before anything is written (SPEC §2).

Nothing unverified ever lands in the destination folder, and the loaders check the digests
again, so the study never runs on files that differ from the published ones.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

from cape.errors import CapeError
from cape.storage.io import write_bytes
from cape.tracks.manifest import BAYESRACE_FILES, UPSTREAM_COMMIT


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _fix_hint(mirror: Path | None, url_template: str | None) -> str:
    where = str(mirror) if mirror is not None else "(none configured)"
    url = url_template or "(none configured)"
    return (
        "Two ways to provide them:\n"
        f"  1. a local mirror folder holding the ten files: set `tracks.mirror` in the config "
        f"(now: {where}), or pass --mirror DIR;\n"
        f"  2. network access to the pinned upstream commit {UPSTREAM_COMMIT}: "
        f"`tracks.upstream_url` (now: {url}).\n"
        "The expected files and SHA-256 digests are listed in src/cape/tracks/manifest.py."
    )


def verify_file(path: Path, expected: str | None = None) -> None:
    """Raise ``CapeError`` unless ``path`` exists and has its published SHA-256."""
    expected = expected or BAYESRACE_FILES.get(path.name)
    if expected is None:
        raise CapeError(f"{path}: not one of the BayesRace track files {sorted(BAYESRACE_FILES)}")
    if not path.is_file():
        raise CapeError(
            f"{path}: track file missing. Run `snakemake --cores 1 tracks` (or `cape tracks`) "
            "to obtain and verify the track files."
        )
    got = sha256(path.read_bytes())
    if got != expected:
        raise CapeError(
            f"{path}: SHA-256 mismatch (expected {expected}, got {got}). The file is corrupt or "
            "not the published version; delete it and run `snakemake --cores 1 tracks` again."
        )


def _download(url: str, timeout: float) -> bytes:
    import urllib.request  # here, not at the top: no rollout job imports http, email and ssl

    with urllib.request.urlopen(url, timeout=timeout) as response:
        return response.read()


def obtain_tracks(
    dest: Path,
    mirror: Path | None,
    url_template: str | None,
    timeout: float = 30.0,
    log: Callable[[str], None] = print,
) -> list[Path]:
    """Put every file of the manifest into ``dest``, verified; return their paths.

    Files already in ``dest`` with the right digest are kept. Otherwise the mirror is tried
    first, then the download. A digest mismatch from either source is an error of its own
    (it means a corrupt copy, not a missing one); if no source delivers a file, the error
    names both ways of providing it.
    """
    dest.mkdir(parents=True, exist_ok=True)
    mirror_ok = mirror is not None and mirror.is_dir()
    if mirror is not None and not mirror_ok:
        log(f"mirror folder {mirror} does not exist; trying the upstream download")
    written: list[Path] = []
    for name, expected in BAYESRACE_FILES.items():
        target = dest / name
        if target.is_file() and sha256(target.read_bytes()) == expected:
            log(f"{name}: already present and verified")
            written.append(target)
            continue
        data: bytes | None = None
        source = ""
        problems: list[str] = []
        if mirror_ok and (mirror / name).is_file():
            data, source = (mirror / name).read_bytes(), f"mirror {mirror / name}"
        elif mirror_ok:
            problems.append(f"not in mirror {mirror}")
        if data is None and url_template:
            url = url_template.format(commit=UPSTREAM_COMMIT, file=name)
            try:
                data, source = _download(url, timeout), f"download {url}"
            except (OSError, ValueError) as exc:  # urllib's URLError is an OSError
                problems.append(f"download from {url} failed ({exc})")
        if data is None:
            raise CapeError(
                f"cannot obtain track file {name}: "
                + ("; ".join(problems) or "no mirror folder and no upstream URL")
                + ".\n"
                + _fix_hint(mirror, url_template)
            )
        got = sha256(data)
        if got != expected:
            raise CapeError(
                f"track file {name} from {source} fails its checksum "
                f"(expected SHA-256 {expected}, got {got}); it was not used.\n"
                + _fix_hint(mirror, url_template)
            )
        write_bytes(target, data)
        log(f"{name}: {source}, SHA-256 verified")
        written.append(target)
    return written
