"""One write policy: a command replaces only its own earlier output, and one writer at a time.

Every output a ``cape`` command or a benchmark writes is claimed before any work (``claim``, with
an ``Output``: its kind and identity). A refused claim names the path and the fix and changes
nothing. The owner record ``.<name>.owner`` beside the output holds the kind and identity and is
the writer's ``flock`` until the command ends (``release``). A failed command removes the record
and the folders it made for an output that did not exist. What a claim refuses: docs/modules.md.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import stat
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cape.errors import CapeError

Recognise = Callable[[Path], "str | None"]
"""An existing output without an owner record → the identity its own record names (a run
folder's metrics.json, a model folder's meta.json), or None when it is not one of the kind."""


@dataclass(frozen=True)
class Output:
    """An output to claim: its path, what it is (``kind``), which one (``identity``: what made
    it, e.g. a training's seed and recipe digest), the suffixes a file may have (empty: any)
    and whether it is a folder. ``option`` names it in messages."""

    path: Path
    kind: str
    identity: str = ""
    suffixes: tuple[str, ...] = ()
    folder: bool = False
    option: str = "--out"
    recognise: Recognise | None = field(default=None, compare=False)
    files: tuple[str, ...] = ()
    """A folder's own files: with none of them left (Snakemake deletes a job's outputs before
    it reruns it), the folder of an output of this kind is free for another identity."""

    def described(self) -> str:
        return f"{self.kind} {self.identity}".strip()


@dataclass
class _Held:
    output: Output
    fd: int
    record: Path
    existed: bool  # the output existed when claimed
    checked: bool = False  # the claim succeeded: the output may be written
    made: list[Path] = field(
        default_factory=list
    )  # folders the claim created, outermost first, then the record it made

    def output_exists(self) -> bool:
        path = self.output.path
        if self.output.folder:
            return path.is_dir() and not _empty(path)
        return path.exists()


_HELD: list[_Held] = []
UNLOCKABLE = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}
"""What flock says on a file system that cannot lock (an NFS or Lustre mount without it)."""


def owner_record(path: str | os.PathLike[str]) -> Path:
    """The owner record of the output at ``path``: ``.<name>.owner`` beside it."""
    path = Path(path)
    return path.parent / f".{path.name}.owner"


def _empty(folder: Path) -> bool:
    """A folder holding nothing but owner records (of outputs since deleted)."""
    return all(is_owner_record(p) for p in folder.iterdir())


def is_owner_record(path: Path) -> bool:
    """Whether ``path`` is an owner record (``.<name>.owner``)."""
    return path.name.startswith(".") and path.name.endswith(".owner")


def repository_root() -> Path | None:
    """The CAPE checkout this code runs from, if it runs from one."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "Snakefile").is_file() and (root / "src" / "cape").is_dir() else None


def _protected(path: Path) -> str | None:
    """Why ``path`` may never be an output, or None."""
    try:
        resolved = path.resolve()
        here = Path.cwd().resolve()
    except (OSError, RuntimeError):
        return None
    home = Path.home().resolve() if "HOME" in os.environ else None
    if resolved == Path(resolved.anchor):
        return "the file system's root"
    if home is not None and resolved == home:
        return "the home folder"
    if resolved == here or resolved in here.parents:
        return "the working folder or a folder above it"
    repo = repository_root()
    if repo is not None and (resolved == repo or resolved in repo.parents):
        return "the CAPE repository or a folder above it"
    return None


OWNER_FORMAT = "cape-owner/1"


def _read_owner(record: Path) -> tuple[str, str, bool] | None:
    """The kind and identity an owner record names, and whether it is from before records had
    a format (their identities held less); None when there is none (no file, or an empty one:
    a claim interrupted before it wrote); ``NotOursError`` when the file is not one."""
    try:
        text = record.read_text()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError):
        raise NotOursError(record) from None
    if not text:
        return None
    try:
        body = json.loads(text)
    except ValueError:
        raise NotOursError(record) from None
    fields = ("kind", "identity", "written_by")
    if not isinstance(body, dict) or not all(isinstance(body.get(k), str) for k in fields):
        raise NotOursError(record)
    if body.get("format", OWNER_FORMAT) != OWNER_FORMAT:  # records before the format: ours
        raise NotOursError(record)
    return body["kind"], body["identity"], "format" not in body


class NotOursError(Exception):
    """A file named as an owner record that no CAPE command wrote."""


def _refuse(out: Output, why: str) -> CapeError:
    return CapeError(f"{out.option} {out.path}: {why}; nothing was changed")


def _check_place(out: Output) -> None:
    path = out.path
    if not out.folder and out.suffixes and path.suffix.lower() not in out.suffixes:
        raise _refuse(out, f"a {out.kind} is written as {', '.join(out.suffixes)}; give one of "
                           "those suffixes")  # fmt: skip
    why = _protected(path)
    if why is not None:
        raise _refuse(out, f"is {why}, never an output; give a new path (e.g. under results/)")
    if path.name in ("", ".", ".."):
        raise _refuse(out, "is not a name a file or folder can be written to; give one")
    if path.is_symlink():
        raise _refuse(out, "is a symbolic link; give the path itself")
    if path.exists() and path.is_dir() != out.folder:
        which, wanted = ("a folder", "a file") if path.is_dir() else ("a file", "a folder")
        raise _refuse(out, f"is {which}, not {wanted} (a {out.kind} is {wanted}); give another "
                           "path")  # fmt: skip
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise _refuse(out, f"{parent} is a file, not a folder; give another path")
        if parent.exists():
            break


def _check_owner(out: Output, record: Path) -> None:
    """Refuse unless the output is absent, an empty folder, or the same output; and a file
    at the owner record's name that is not one (a user's, never overwritten)."""
    path = out.path
    try:
        owner = _read_owner(record)
    except NotOursError:
        raise _refuse(out, f"{record} is not an owner record CAPE wrote (a file of yours?), "
                           "and CAPE keeps its record of this output there; rename that file, "
                           "or give another path") from None  # fmt: skip
    if not path.exists() or (out.folder and _empty(path)):
        return
    if owner is not None:
        kind, identity, older = owner
        if (kind, identity) == (out.kind, out.identity):
            return
        if out.files and kind == out.kind and not any((path / f).exists() for f in out.files):
            return  # its own files deleted: what is left is no output of that identity
        if older and kind == out.kind and out.identity.startswith(identity):
            raise _refuse(out, f"holds a {kind} an earlier CAPE recorded without what made it, "
                               f"so whether it is {out.described()} cannot be told; delete it to "
                               "write it again, or give another path")  # fmt: skip
        raise _refuse(out, f"holds {f'{kind} {identity}'.strip()}, not {out.described()}, "
                           "so it is not this command's to replace; give another path")  # fmt: skip
    if out.recognise is not None and out.recognise(path) == out.identity:
        return
    if out.folder:
        names = sorted(p.name for p in path.iterdir())
        shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
        what = f"a folder of other files ({shown})"
    else:
        what = "a file"
    raise _refuse(out, f"is {what} that CAPE did not write as {out.described()} (no owner record "
                       f"{record.name} says so), and CAPE replaces only what it wrote; give "
                       "another path")  # fmt: skip


UNWRITABLE = {errno.EACCES, errno.EPERM, errno.EROFS}
"""What opening a new file says in a folder that cannot be written: another user's, a
read-only mount, or an immutable folder (``chattr +i``)."""


def _unopenable(record: Path, exc: OSError) -> str:
    """Why the owner record ``record`` cannot be opened, in the refusal's words: the folder
    cannot be written (the usual reason), a symbolic link planted as the record, or what the
    system said."""
    said = exc.strerror or str(exc)
    if exc.errno == errno.ELOOP:
        return (f"its owner record {record} is a symbolic link, not a plain file CAPE wrote; "
                "give another path")  # fmt: skip
    if exc.errno in UNWRITABLE:
        return (f"its folder {record.parent} cannot be written ({said}: read-only, immutable "
                "or not yours); make it writable, or give another path")  # fmt: skip
    return f"its owner record {record} cannot be opened ({said}); give another path"


def _lock(out: Output, record: Path) -> int:
    """Open and lock ``record`` (created if absent, never through a symbolic link); the same
    inode as the path's, so a record removed meanwhile by a failed writer is never the one
    locked."""
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    for _ in range(5):
        try:
            fd = os.open(record, flags, 0o666)
        except FileNotFoundError:  # its folder removed meanwhile by a failed claim: again
            record.parent.mkdir(parents=True, exist_ok=True)
            continue
        except OSError as exc:
            raise _refuse(out, _unopenable(record, exc)) from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise _refuse(out, f"its owner record {record} is not a plain file CAPE wrote; give "
                               "another path")  # fmt: skip
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _refuse(out, "another command is writing it right now; wait for it to end, or "
                               "give another path") from None  # fmt: skip
        except OSError as exc:
            if exc.errno not in UNLOCKABLE:
                os.close(fd)
                raise
            # a file system without flock (some cluster mounts): the record still says whose
            # output it is; only two hand-run writers at once go unnoticed (Snakemake never
            # runs two jobs with one output)
        try:
            same = os.fstat(fd).st_ino == os.stat(record, follow_symlinks=False).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise _refuse(out, "its owner record keeps changing under another writer; try again")


def claim(outputs: Sequence[Output], command: str) -> None:
    """Check every output and take each one's lock (all of them before any owner record is
    written, so a refusal changes nothing), then write the owner records; raise ``CapeError``
    naming the first output that may not be written. Held until ``release``."""
    seen: dict[Path, Output] = {}
    for out in outputs:
        _check_place(out)
        key = Path(os.path.abspath(out.path))
        if key in seen:
            raise _refuse(out, f"is given twice ({seen[key].option} and {out.option}); give "
                               "each output its own path")  # fmt: skip
        seen[key] = out
    held: list[_Held] = []
    try:
        for out in outputs:
            made = [p for p in reversed(out.path.parents) if not p.exists()]
            out.path.parent.mkdir(parents=True, exist_ok=True)
            record = owner_record(out.path)
            existed_record = record.exists()
            fd = _lock(out, record)
            existed = out.path.exists()
            if out.folder and not existed:
                made.append(out.path)  # an empty folder left by a failure is removed too
            entry = _Held(out, fd, record, existed, made=made)
            held.append(entry)
            if not existed_record:
                entry.made.append(record)  # removed again if it is refused or fails
            _check_owner(out, record)
        for entry in held:
            out = entry.output
            body = {"format": OWNER_FORMAT, "kind": out.kind, "identity": out.identity,
                    "written_by": command}  # fmt: skip
            data = (json.dumps(body, sort_keys=True) + "\n").encode()
            os.ftruncate(entry.fd, 0)
            os.pwrite(entry.fd, data, 0)
            entry.checked = True
    except BaseException:
        _release(held, success=False)
        raise
    _HELD.extend(held)


def _release(held: list[_Held], success: bool) -> None:
    for entry in reversed(held):
        if not success and (not entry.checked or not entry.output_exists()):
            for made in reversed(entry.made):
                with contextlib.suppress(OSError):
                    if made == entry.record:
                        made.unlink()
                    else:
                        made.rmdir()
        os.close(entry.fd)


def _close_in_child() -> None:
    """A process forked while outputs are held (a solver's worker) drops its copies of the
    locks' descriptors: the lock is the parent's, released when the parent lets go."""
    for entry in _HELD:
        with contextlib.suppress(OSError):
            os.close(entry.fd)
    _HELD.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_in_child)


def release(success: bool = True) -> None:
    """Let go of every output this process claimed. After a failure, an output that does not
    exist loses the owner record and the folders its claim made."""
    held = list(_HELD)
    _HELD.clear()
    _release(held, success)


@contextlib.contextmanager
def claimed(outputs: Sequence[Output], command: str) -> Iterator[None]:
    """``claim`` for the block, ``release`` after it (success unless it raised): for scripts
    and tests that are not a ``cape`` command."""
    claim(outputs, command)
    try:
        yield
    except BaseException:
        release(success=False)
        raise
    release(success=True)
