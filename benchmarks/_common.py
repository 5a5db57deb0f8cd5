"""What the benchmark scripts share: how they end, the config they read, the files they write.

- ``run(main)``: a problem the user can fix (``CapeError``, a failed read or write) ends the
  script as one line on stderr, ``<script>: error: <message>``, and exit status 2, never a
  traceback; Ctrl-C as one line and 130, and SIGTERM where a script turns it into
  ``cape.cli.Interrupted`` (scheduler_threads.py) as one line and 143.
- ``add_config(parser)`` / ``study_config(args)``: the study's config as the workflow reads
  it, ``config/config.yaml`` with each ``--configfile`` merged over it as Snakemake's
  ``--configfile`` does (the smoke study: ``--configfile config/smoke.yaml``).
- ``json_output(path, script)``: a ``--json PATH`` claimed through the project's write policy
  (``cape.storage.ownership``) before any work, written atomically.

Every path under ``results/`` comes from ``cape.layout.paths``, the workflow's own names,
relative to the working folder: run the scripts from the study's folder.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from cape.errors import CapeError

DEFAULT_CONFIG = Path("config/config.yaml")


def script_name() -> str:
    return Path(sys.argv[0]).name or "benchmark"


def run(main: Callable[[], int | None]) -> int:
    """``main()``'s exit status (0 when it returns None); a ``CapeError`` or ``OSError`` is
    one line on stderr and status 2, Ctrl-C one line and 130."""
    from cape.cli import Interrupted, told
    from cape.storage import ownership

    succeeded = False
    try:
        status = main() or 0
        succeeded = True
        return status
    except BrokenPipeError:  # `… | head`: the reader has had enough
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (CapeError, OSError, KeyboardInterrupt, Interrupted) as exc:
        status, message = told(exc)
        print(f"{script_name()}: {message}", file=sys.stderr)
        return status
    finally:
        ownership.release(succeeded)


# --- the config -------------------------------------------------------------------------------
def add_config(parser: argparse.ArgumentParser) -> None:
    """``--config`` and ``--configfile``: the config the study was built with."""
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG,
                        help="the study's config (default config/config.yaml)")  # fmt: skip
    parser.add_argument("--configfile", "--overlay", type=Path, nargs="+", default=[],
                        metavar="FILE",
                        help="overlays merged over --config as Snakemake's --configfile does "
                        "(the smoke study: config/smoke.yaml)")  # fmt: skip


def merged(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over`` merged into ``base`` key by key, recursively (Snakemake's ``--configfile``)."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, Mapping) and isinstance(out.get(key), Mapping)
        out[key] = merged(out[key], value) if both else value
    return out


def load_overlaid(config: Path, overlays: list[Path]) -> dict[str, Any]:
    """``config`` with the overlays merged over it, validated as a whole, in Snakemake's order:
    it starts from the overlays, merges the Snakefile's ``configfile`` into them, then the
    overlays again, so an overlay's keys come first (the grid's run order, and so which study
    computes a shared run, depends on it)."""
    from cape.config import load_config, validate_config

    base = load_config(config)
    if not overlays:
        return base
    import yaml

    over: dict[str, Any] = {}
    for overlay in overlays:
        try:
            loaded = yaml.safe_load(Path(overlay).read_text())
        except FileNotFoundError:
            raise CapeError(f"--configfile {overlay}: not found; give the overlay the study "
                            "was built with") from None  # fmt: skip
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise CapeError(f"--configfile {overlay}: unreadable ({type(exc).__name__}); fix "
                            "the file") from None  # fmt: skip
        if not isinstance(loaded, dict):
            raise CapeError(f"--configfile {overlay}: not a YAML mapping of config sections")
        over = merged(over, loaded)
    whole = merged(merged(over, base), over)
    return validate_config(whole, " + ".join(str(p) for p in [config, *overlays]))


def study_config(args: argparse.Namespace) -> dict[str, Any]:
    return load_overlaid(args.config, list(args.configfile))


# --- what a script writes ---------------------------------------------------------------------
@contextlib.contextmanager
def json_output(path: Path | None, script: str, option: str = "--json") -> Iterator[
    Callable[[Any], None]
]:  # fmt: skip
    """Claim ``path`` (when given) as this script's results before any work; yields
    ``write(document)``, which writes it as JSON atomically (a no-op without a path)."""
    from cape.storage.io import write_text
    from cape.storage.ownership import Output, claimed

    if path is None:
        yield lambda _document: None
        return
    output = Output(Path(path), f"results of benchmarks/{script}", suffixes=(".json",),
                    option=option)  # fmt: skip

    def write(document: Any) -> None:
        write_text(path, json.dumps(document, indent=2, default=str) + "\n")

    with claimed([output], f"benchmarks/{script}"):
        yield write


# --- what a script reads ----------------------------------------------------------------------
def require_file(path: str | Path, fix: str | None = None) -> Path:
    """``path``, or ``CapeError`` naming it and how to build it."""
    path = Path(path)
    if not path.is_file():
        raise CapeError(f"{path}: missing; {fix or f'build it with `snakemake --cores 2 {path}`'}")
    return path


def listed(items: list[str], limit: int = 6) -> str:
    """At most ``limit`` items, then how many more."""
    shown = ", ".join(items[:limit])
    return shown + (f" and {len(items) - limit} more" if len(items) > limit else "")
