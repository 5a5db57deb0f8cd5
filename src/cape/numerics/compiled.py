"""NLP solvers whose functions are compiled C, built once per problem structure and cached.

CasADi evaluates an NLP's functions (cost, constraints, their Jacobian and the Lagrangian's
Hessian) in its SX virtual machine; compiled to C they run several times faster, which is most of
an NMPC step. Compiling takes seconds, so it must not happen per run: the generated C source is
hashed, compiled once into ``<cache>/<plugin>_<hash>.so`` (temp file, then rename, so concurrent
jobs never see half a library) and reused by every later run with the same structure — only
parameters change between runs. Without a compiler the solver falls back to the SX virtual
machine and says so once.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import casadi as ca

from cape.errors import CapeError
from cape.layout.paths import SOLVERS
from cape.storage.integrity import check_sidecar, file_digest, sidecar
from cape.storage.io import write_text

_warned = False


def make_nlpsol(
    name: str,
    plugin: str,
    problem: Callable[[], dict[str, Any]],
    opts: dict[str, Any],
    compile_settings: dict[str, Any] | None,
    fingerprint: str | None = None,
) -> tuple[ca.Function, Path | None]:
    """``ca.nlpsol`` on ``problem()`` (its expressions), and the compiled library it runs
    (None: uncompiled). With ``compile_settings = {enabled, cache, compiler, flags}`` its
    functions are loaded from a cached compiled library: keyed by ``fingerprint`` when given (a
    digest of everything the problem depends on; a cached one loads without calling
    ``problem``), else by the hash of the generated code."""
    enabled = bool(compile_settings and compile_settings.get("enabled", False))
    if enabled and fingerprint is not None:
        assert compile_settings is not None
        library = cached_library(
            fingerprint,
            compile_settings,
            lambda tmp: _generate(ca.nlpsol(name, plugin, problem(), opts), tmp),
            prefix=f"{plugin}_nlp",
        )
        if library is not None:
            return ca.nlpsol(name, plugin, str(library), opts), library
    solver = ca.nlpsol(name, plugin, problem(), opts)
    if not enabled:
        return solver, None
    assert compile_settings is not None
    compiler = str(compile_settings.get("compiler", "gcc"))
    if shutil.which(compiler) is None:
        _warn_once(f"compiler {compiler!r} not found; NLP functions run uncompiled (slower)")
        return solver, None
    flags = [str(f) for f in compile_settings.get("flags", ["-O1"])]
    cache = Path(str(compile_settings.get("cache", SOLVERS)))
    library = compiled_library(solver, plugin, cache, compiler, flags)
    return ca.nlpsol(name, plugin, str(library), opts), library


def cached_functions(
    names: dict[str, str], fingerprint: str, compile_settings: dict[str, Any]
) -> tuple[dict[str, ca.Function], Path] | None:
    """The functions ``names`` (key → function name) from the cached library of a problem with
    ``fingerprint`` (a digest of everything its generated code depends on), or None when that
    library is not cached yet. Loading skips building the functions' expressions, which costs
    a second or more."""
    library = _fingerprinted(fingerprint, compile_settings)
    if library is None or not library.is_file():
        return None
    verify_library(library)
    return {key: ca.external(name, str(library)) for key, name in names.items()}, library


def source_digest(*modules: Any) -> str:
    """A digest of the source files of ``modules`` (what a cached function is built by: any
    edit of them gives a new key, so a stale cache entry is never read)."""
    h = hashlib.sha256()
    for module in modules:
        h.update(Path(module.__file__).read_bytes())
    return h.hexdigest()


def serialized_function(
    name: str, key: str, build: Callable[[], ca.Function], settings: dict[str, Any] | None
) -> ca.Function:
    """``build()``, or the same function read back from the cache (``settings``: the
    ``rollout.compile`` entry; its ``cache`` folder, when ``enabled``).

    Building a function from the shared equations costs tens of milliseconds of Python per
    rollout job; deserialising it, under a millisecond. The serialised form evaluates the same
    instructions in CasADi's virtual machine, so the same numbers. ``key`` must name
    everything the function depends on (its constants, and ``source_digest`` of the code that
    builds it); the file carries a checksum beside it, as the compiled libraries do."""
    if not settings or not settings.get("enabled", False) or not settings.get("cache"):
        return build()
    digest = hashlib.sha256(f"{name}|{key}|{ca.__version__}".encode()).hexdigest()[:16]
    path = Path(str(settings["cache"])) / "functions" / f"{name}_{digest}.casadi"
    if path.is_file():
        check_sidecar(path, f"delete {path} (and its .sha256); the next run rebuilds it")
        return ca.Function.deserialize(path.read_text())
    function = build()
    write_text(path, function.serialize())
    write_text(sidecar(path), file_digest(path) + "\n")
    return function


def verify_library(library: Path) -> None:
    """Raise ``CapeError`` unless a cached library matches the checksum written beside it when
    it was compiled: loading a damaged native library would crash the process."""
    check_sidecar(library, f"delete {library} (and its .sha256); the next run rebuilds it")


def _fingerprinted(
    fingerprint: str, compile_settings: dict[str, Any], prefix: str = "condensed"
) -> Path | None:
    compiler = str(compile_settings.get("compiler", "gcc"))
    if shutil.which(compiler) is None:
        return None
    flags = [str(f) for f in compile_settings.get("flags", ["-O1"])]
    cache = Path(str(compile_settings.get("cache", SOLVERS)))
    key = hashlib.sha256(" ".join([fingerprint, ca.__version__, compiler, *flags]).encode())
    return cache / f"{prefix}_{key.hexdigest()[:16]}.so"


def cached_library(
    fingerprint: str,
    compile_settings: dict[str, Any],
    generate: Callable[[Path], Path],
    prefix: str = "condensed",
    what: str = "the NLP",
    setting: str = "the controller's `compile.enabled: false`",
) -> Path | None:
    """The cached library of the code with ``fingerprint`` (a digest of everything the code
    depends on), its checksum verified; compiled from the C file ``generate(folder)`` writes
    when it is not cached yet. None when the compiler is missing (said once: ``what`` runs
    uncompiled). ``setting`` turns the compilation off."""
    compiler = str(compile_settings.get("compiler", "gcc"))
    library = _fingerprinted(fingerprint, compile_settings, prefix)
    if library is None:
        _warn_once(f"compiler {compiler!r} not found; {what} runs uncompiled (slower)")
        return None
    if library.is_file():  # compiled before, or meanwhile by a concurrent job
        verify_library(library)
    else:
        flags = [str(f) for f in compile_settings.get("flags", ["-O1"])]
        _compile(generate, library, compiler, flags, what, setting)
    return library


def compiled_functions(
    name: str,
    functions: dict[str, ca.Function],
    compile_settings: dict[str, Any],
    fingerprint: str,
) -> tuple[dict[str, ca.Function], Path | None]:
    """The same functions, loaded from one compiled library cached under ``fingerprint``
    (compiled now when missing), and that library; unchanged, with None, when the compiler is
    missing."""

    def generate(directory: Path) -> Path:
        gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
        for function in functions.values():
            gen.add(function)
        return generated(gen, f"{name}.c", directory)

    library = cached_library(fingerprint, compile_settings, generate)
    if library is None:
        return functions, None
    return {key: ca.external(f.name(), str(library)) for key, f in functions.items()}, library


def generated(gen: ca.CodeGenerator, file_name: str, directory: Path) -> Path:
    """Write ``gen``'s C file ``file_name`` into ``directory`` and return its path (CasADi
    writes generated code to the working directory)."""
    here = Path.cwd()
    os.chdir(directory)
    try:
        gen.generate()
    finally:
        os.chdir(here)
    return directory / file_name


def compiled_library(
    solver: ca.Function, plugin: str, cache: Path, compiler: str, flags: list[str]
) -> Path:
    """The cached shared library of ``solver``'s NLP functions, compiled when missing."""
    return _compiled(lambda tmp: _generate(solver, tmp), plugin, cache, compiler, flags)


def _compiled(generate: Any, prefix: str, cache: Path, compiler: str, flags: list[str]) -> Path:
    """Generate C source with ``generate(folder)``, and return the cached library built from
    it (``<cache>/<prefix>_<hash of source and flags>.so``), compiling it when missing."""
    with tempfile.TemporaryDirectory() as tmp:
        source = generate(Path(tmp))
        text = source.read_bytes()
        key = hashlib.sha256(text + " ".join([compiler, *flags]).encode()).hexdigest()[:16]
        library = cache / f"{prefix}_{key}.so"
        if library.is_file():
            verify_library(library)
        else:
            _compile(lambda _: source, library, compiler, flags)
    return library


def _compile(
    generate: Any,
    library: Path,
    compiler: str,
    flags: list[str],
    what: str = "the NLP",
    setting: str = "the controller's `compile.enabled: false`",
) -> None:
    """Generate C source with ``generate(folder)`` and compile it into ``library`` (temp file,
    then rename: concurrent jobs never see half a library). ``what`` and ``setting`` name the
    code and the setting that turns it off, for the error."""
    with tempfile.TemporaryDirectory() as tmp:
        source = generate(Path(tmp))
        library.parent.mkdir(parents=True, exist_ok=True)
        partial = Path(tmp) / library.name
        cmd = [compiler, *flags, "-fPIC", "-shared", str(source), "-o", str(partial)]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise CapeError(
                f"compiling {what} with `{' '.join(cmd)}` failed:\n{done.stderr.strip()}\n"
                f"Set {setting} to run without a compiler."
            )
        # copy beside the target, then rename: atomic on the cache's file system; the checksum
        # first, so that a library without one is never mistaken for a complete one
        staged = library.with_suffix(f".{os.getpid()}.tmp")
        shutil.copyfile(partial, staged)
        write_text(sidecar(library), file_digest(staged) + "\n")
        os.replace(staged, library)


def _generate(solver: ca.Function, directory: Path) -> Path:
    """CasADi writes generated code to the working directory: do it inside ``directory``."""
    here = Path.cwd()
    os.chdir(directory)
    try:
        name = solver.generate_dependencies("nlp.c", {"with_header": False})
    finally:
        os.chdir(here)
    return directory / name


def _warn_once(message: str) -> None:
    global _warned
    if not _warned:
        print(f"cape: {message}", file=sys.stderr)
        _warned = True
