"""What the ``cape`` commands share: the registry of commands and the common arguments."""

from __future__ import annotations

import time

STARTED = time.perf_counter()  # as the process starts: a rollout reports its own start-up

import argparse  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from cape.errors import CapeError  # noqa: E402
from cape.layout import paths  # noqa: E402

Arguments = Callable[[argparse.ArgumentParser], None]
Command = Callable[[argparse.Namespace], None]
COMMANDS: dict[str, tuple[str, Arguments, Command]] = {}
"""Command name → (help, its arguments, the function), in the order they are listed."""


def command(name: str, help: str, arguments: Arguments) -> Callable[[Command], Command]:
    """Register ``func`` as ``cape NAME``, with the arguments ``arguments`` adds."""

    def register(func: Command) -> Command:
        COMMANDS[name] = (help, arguments, func)
        return func

    return register


def _add_config_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML config to read (default: config/config.yaml)",
    )
    parser.add_argument(
        "--config-json",
        metavar="JSON",
        help="config sections as a JSON object; overrides --config",
    )
    parser.add_argument(
        "--spec",
        metavar="FILE",
        help="the job's specification: a JSON file of the config sections it reads (how the "
        "workflow passes them, under results/specs/); overrides --config and --config-json",
    )


def _add_tracks_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--tracks-dir", help="folder of the verified track files (default: config tracks.dir)"
    )


def _tracks_dir(args: argparse.Namespace, tracks: Any) -> Path:
    """``--tracks-dir``, else the config's ``tracks.dir`` (``tracks``: a TracksSpec)."""
    return Path(args.tracks_dir or tracks.dir)


def _add_outputs(parser: argparse.ArgumentParser, flag: str, what: str) -> None:
    """A repeatable output flag: one file per format (the suffix chooses it)."""
    parser.add_argument(
        flag, action="append", required=True, metavar="PATH", help=f"{what} (repeat)"
    )


def _add_models(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model", action="append", required=True, metavar="NAME=DIR", help="trained model (repeat)"
    )


def _add_model_folders(parser: argparse.ArgumentParser) -> None:
    """Where a run's trained models are: ``--model NAME=DIR`` for the ones the workflow's rule
    declares as inputs, else ``--models-dir``/NAME."""
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="NAME=DIR",
        help="folder of a trained model this run reads (repeat; default: MODELS_DIR/NAME)",
    )
    parser.add_argument(
        "--models-dir",
        help="folder of the trained models' folders (default: results/models/rep<--replicate>)",
    )


def _model_folders(args: argparse.Namespace) -> Any:
    from cape.closedloop.setup import ModelFolders

    named = {}
    for item in args.model:
        name, sep, folder = item.partition("=")
        if not sep or not name or not folder:
            raise CapeError(f"--model {item}: expected NAME=DIR, e.g. epm={paths.model_dir('epm')}")
        _once(name, named, item)
        named[name] = Path(folder)
    root = args.models_dir or paths.models_of(getattr(args, "replicate", 0) or 0)
    return ModelFolders(Path(root), named)


def _entry(name: str, entries: Any, option: str, field: str) -> Any:
    """The config entry ``name`` of ``entries`` (the section ``field``), or an error naming the
    option, the field and the names it has."""
    if name not in entries:
        raise CapeError(f"{option} {name}: not in the config's `{field}` "
                        f"({', '.join(sorted(entries))})")  # fmt: skip
    return entries[name]


def _config(args: argparse.Namespace) -> dict[str, Any]:
    from cape.config import config_from_args

    return config_from_args(args.config, args.config_json, args.spec)


def _read_dataset(path: str) -> dict[str, Any]:
    from cape.data.bayesrace import read_dataset

    return read_dataset(path)


TABLE_SUFFIXES = (".csv", ".md", ".tex")
FIGURE_SUFFIXES = (".pdf", ".png", ".svg")
JSON_SUFFIXES = (".json",)


def _claim(args: argparse.Namespace, *outputs: Any) -> None:
    """Claim this command's outputs (``cape.storage.ownership``) before any work: each refused
    with one line unless it is new or this command's own earlier output; held until the command
    ends."""
    from cape.storage import ownership

    ownership.claim(outputs, f"cape {args.command}")


def _files(paths: list[str], kind: str, suffixes: tuple[str, ...], option: str = "--out") -> list:
    """The ``ownership.Output`` of each file of a repeatable output flag."""
    from cape.storage.ownership import Output

    return [Output(Path(p), kind, suffixes=suffixes, option=option) for p in paths]


PROVENANCE_COLUMNS = ("replicate", "weights_sha256")


def _with_provenance(table: Any, items: list[str]) -> Any:
    """``table`` (one row per model, column ``model``) with the training replicate and the
    weights digest of each ``NAME=DIR`` model it was computed from (cape.study.inputs checks
    them against the current models)."""
    from cape.closedloop.provenance import model_replicate
    from cape.models.trained import read_meta

    made = {}
    for item in items:
        name, _, folder = item.partition("=")
        meta = read_meta(folder)
        made[name] = (model_replicate(meta), str(meta.get("weights_sha256") or ""))
    table = table.copy()
    table["replicate"] = [made[m][0] for m in table["model"]]
    table["weights_sha256"] = [made[m][1] for m in table["model"]]
    return table


def _load_models(items: list[str]) -> dict[str, Any]:
    """``NAME=DIR`` pairs → trained models, in the order given."""
    from cape.models.checkpoint import load_model

    models = {}
    for item in items:
        name, sep, folder = item.partition("=")
        if not sep:
            raise CapeError(
                f"--model {item}: expected NAME=FOLDER, e.g. epm={paths.model_dir('epm')}"
            )
        _once(name, models, item)
        models[name] = load_model(folder, expected_name=name)
    return models


def _once(name: str, given: dict[str, Any], item: str) -> None:
    """A model named twice by ``--model``: which one would be meant cannot be known."""
    if name in given:
        raise CapeError(f"--model {item}: names {name!r} a second time; give each model once")
