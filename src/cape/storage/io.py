"""Atomic output: write to a temporary file beside the target, then rename.

An interrupted job leaves either the old file or none, never a half-written one, so
Snakemake's rerun does exactly what is missing.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from collections.abc import Collection, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

from cape.errors import CapeError


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file in ``path``'s folder; on success rename it onto ``path``."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, mode) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def check_replaceable(path: str | os.PathLike[str], own: Collection[str], what: str) -> None:
    """Raise ``CapeError`` unless ``path`` may become a folder of ``what`` (a command's output
    folder): it is absent, an empty folder, or a folder holding only files named in ``own``
    (a previous output of the same command). Anything else is not this command's to replace:
    a user's folder, the repository, a file."""
    target = Path(path)
    if target.is_symlink():
        raise CapeError(f"{target}: is a symbolic link; give the folder itself as the output")
    if not target.exists():
        return
    if not target.is_dir():
        raise CapeError(f"{target}: exists and is not a folder; choose another output folder")
    foreign = sorted(p.name for p in target.iterdir() if p.name not in own or not p.is_file())
    if foreign:
        more = f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        shown = ", ".join(foreign[:5]) + more
        raise CapeError(
            f"{target}: holds files that are not {what} ({shown}); nothing was changed. Give a "
            "new or empty folder (a folder holding only an earlier output of this command is "
            "replaced)"
        )


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str], own: Collection[str], what: str) -> Iterator[Path]:
    """A temporary folder beside ``path`` to write a group of files into; on success it
    replaces ``path`` in one rename, so the files appear together or not at all (an
    interrupted writer leaves the old folder, or none).

    ``path`` is replaced only if ``check_replaceable`` allows it (checked before the files are
    written and again before the rename): a command replaces its own earlier output and
    nothing else. The old folder is renamed aside first and only the files named in ``own``
    are deleted from it."""
    target = Path(path)
    check_replaceable(target, own, what)
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        check_replaceable(target, own, what)  # again: it may have changed meanwhile
        old = None
        if target.exists():  # a rerun: the old output steps aside, the new takes its name
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.replace(target, old)  # onto the empty folder just made
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is not None:
        for name in own:
            with contextlib.suppress(FileNotFoundError):
                (old / name).unlink()
        try:
            old.rmdir()
        except OSError:  # something appeared in the instant between the check and the rename
            print(f"warning: kept {old}: it holds files not written here", file=sys.stderr)


def write_files(contents: Mapping[str | os.PathLike[str], bytes]) -> None:
    """Several files, all or none: each goes to a temporary file beside its target, and only
    when every one is complete (a full disk fails here) are they renamed into place, so a new
    file never stands beside an old one of the same group."""
    staged: list[tuple[str, Path]] = []
    try:
        for path, data in contents.items():
            target = Path(path)
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
            staged.append((tmp, target))
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            os.chmod(tmp, 0o666 & ~_umask())
        for tmp, target in staged:
            os.replace(tmp, target)
    except BaseException:
        for tmp, _ in staged:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def save_npz(path: str | os.PathLike[str], **arrays: np.ndarray) -> None:
    """``np.savez`` written atomically (and without NumPy appending a second suffix)."""
    with atomic_open(path, "wb") as handle:
        np.savez(handle, **arrays)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes(path, text.encode("utf-8"))


def read_npz(
    path: str | os.PathLike[str], keys: Collection[str] = (), what: str = "", fix: str = ""
) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path``, or ``CapeError`` naming the file and the fix
    (missing, empty, not an npz archive, damaged, or without one of ``keys``: then it is not
    ``what``, and ``fix`` says what to give instead)."""
    path = Path(path)
    rebuild = fix or f"build it with `snakemake --cores 2 {path}`"
    if not path.is_file():
        where = "is a folder" if path.is_dir() else "not found"
        raise CapeError(f"{path}: {where}; {rebuild}")
    import zipfile

    try:
        if not zipfile.is_zipfile(path):  # a text file, an .npy, an empty file: said as such
            raise ValueError("not a zip archive, which every .npz is")
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, AttributeError) as exc:
        raise CapeError(
            f"{path}: not a readable .npz ({type(exc).__name__}: {exc}); "
            + (fix or f"delete it and rebuild it with `snakemake --cores 2 {path}`")
        ) from None
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise CapeError(
            f"{path}: has no {', '.join(repr(k) for k in missing)} array"
            + (f", so it is not {what}" if what else "")
            + f"; {rebuild}"
        )
    return arrays


def read_json(path: str | os.PathLike[str], what: str, fix: str) -> Any:
    """The JSON document at ``path`` (``what`` it should be), or one ``CapeError`` naming the
    file, what is wrong and ``fix``: missing, unreadable, not JSON, or not a JSON object."""
    import json

    path = Path(path)
    try:
        body = json.loads(path.read_text())
    except FileNotFoundError:
        raise CapeError(f"{path}: missing; {fix}") from None
    except IsADirectoryError:
        raise CapeError(f"{path}: is a folder, not {what}; {fix}") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CapeError(f"{path}: not {what} ({type(exc).__name__}: {exc}); {fix}") from None
    if not isinstance(body, dict):
        raise CapeError(f"{path}: not {what} (not a JSON object); {fix}")
    return body


def read_csv(
    path: str | os.PathLike[str],
    missing: str,
    damaged: str,
    columns: Collection[str] = (),
    sep: str = ",",
    rows: bool = False,
    text: Collection[str] = (),
) -> Any:
    """``pandas.read_csv(path, sep=sep)``, or one ``CapeError`` naming the file: ``missing``
    (its fix) when it does not exist, ``damaged`` (what it is not, and the fix; ``{reason}``
    is replaced by pandas' reason) when pandas cannot read it, lacks one of ``columns``, or
    (``rows``) has no rows. ``text``: columns read as strings (a label such as "2.5" stays a
    label)."""
    import pandas as pd

    try:
        frame = pd.read_csv(
            path,
            sep=sep,
            dtype=dict.fromkeys(text, str) or None,
        )
    except FileNotFoundError:
        raise CapeError(f"{path}: missing; {missing}") from None
    except IsADirectoryError:
        raise CapeError(f"{path}: {damaged.format(reason='a folder')}") from None
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise CapeError(f"{path}: {damaged.format(reason=exc)}") from None
    lacking = [c for c in columns if c not in frame.columns]
    if lacking or (rows and frame.empty):
        reason = f"no column {', '.join(lacking)}" if lacking else "no rows"
        raise CapeError(f"{path}: {damaged.format(reason=reason)}")
    return frame


def read_benchmark(path: str | os.PathLike[str]) -> Any:
    """A Snakemake ``benchmark:`` file (a TSV of one or more rows with ``s`` and ``cpu_time``),
    or one ``CapeError`` naming the file and the fix."""
    fix = "rerun its rule (delete the file, then `snakemake --cores 2` again)"
    return read_csv(
        path,
        f"its rule has not run here; {fix}",
        "not a Snakemake benchmark record ({reason}); " + fix,
        columns=("s", "cpu_time"),
        sep="\t",
        rows=True,
    )
