"""What the ``cape`` commands share: the registry of commands and the common arguments."""

from __future__ import annotations

import time

STARTED = time.perf_counter()  # as the process starts: a rollout reports its own start-up

import argparse  # noqa: E402
import math  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402
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
        COMMANDS[name] = (help, _noting_bounds(arguments), _checking_bounds(func))
        return func

    return register


# --- the bounds of numeric options --------------------------------------------------------------
# An option that overrides a config key takes the key's bounds from the packaged config schema
# (``bounded``), so the two can never differ; the others have the bounds below. Each is checked
# right after parsing, before a command reads its config, claims its outputs or does any work: a
# value outside is one line and exit status 2, as a bad config value is.


@dataclass(frozen=True)
class Limits:
    """What an option accepts: ``kind`` (int or float, always finite), ``least`` ≤ value ≤
    ``most``, ``above`` < value < ``below`` (None: no such bound), and where the bounds are
    from (``why``, as a message shows it)."""

    kind: type
    why: str
    least: float | None = None
    most: float | None = None
    above: float | None = None
    below: float | None = None

    def refusal(self, value: float) -> str | None:
        """None if ``value`` is within, else what to give instead."""
        low = (f"of at least {self.least}" if self.least is not None
               else f"above {self.above}" if self.above is not None else None)  # fmt: skip
        high = (f"of at most {self.most}" if self.most is not None
                else f"below {self.below}" if self.below is not None else None)  # fmt: skip
        if not math.isfinite(value):  # NaN and ±inf: no bound admits them
            said = " and ".join(s for s in (low, high) if s) or "that is finite"
        elif (self.least is not None and value < self.least) or (
            self.above is not None and value <= self.above
        ):
            said = low
        elif (self.most is not None and value > self.most) or (
            self.below is not None and value >= self.below
        ):
            said = high
        else:
            return None
        return f"give a number {said} ({self.why})"


class Bound:
    """An option's ``type=``: it parses the number (of the kind its limits say); the limits
    themselves are checked after parsing (``_checking_bounds``), where a refusal is a
    ``CapeError``. ``limits`` is called only when an option is given (it may read the schema)."""

    def __init__(self, limits: Callable[[], Limits]) -> None:
        self.limits = limits

    def __call__(self, text: str) -> float:
        kind = self.limits().kind
        try:
            return kind(text)
        except (TypeError, ValueError):  # argparse's own words for a value that is no number
            said = repr(text) if len(text) <= 40 else _shown(text)
            raise argparse.ArgumentTypeError(f"invalid {kind.__name__} value: {said}") from None


def schema_limits(key: str) -> Limits:
    """The bounds of config key ``key`` (dotted; ``*`` any name, e.g. ``models.*.train.epochs``)
    in the packaged config schema: ``minimum``, ``maximum`` and their exclusive forms."""
    from cape import schemas

    node: Any = schemas.load_schema(schemas.CONFIG)
    for part in key.split("."):
        node = node["additionalProperties"] if part == "*" else node["properties"][part]
    types = node["type"] if isinstance(node["type"], list) else [node["type"]]
    return Limits(
        int if "integer" in types else float,
        f"the bound of {key.replace('*', '<name>')} in the config schema",
        least=node.get("minimum"),
        most=node.get("maximum"),
        above=node.get("exclusiveMinimum"),
        below=node.get("exclusiveMaximum"),
    )


def bounded(key: str) -> Bound:
    """The ``type=`` of an option that overrides config key ``key``: the key's bounds."""
    return Bound(lambda: schema_limits(key))


def _draw_limits() -> Limits:
    count = schema_limits("training.replicates").most
    return Limits(int, f"a draw is below training.replicates, at most {count} in the config "
                  "schema", least=0, below=count)  # fmt: skip


DRAW = Bound(_draw_limits)
"""A draw (training replicate) r: 0 ≤ r < the most ``training.replicates`` allows (a config
names no draw at or beyond its ``training.replicates``)."""
SEED = Bound(lambda: Limits(int, "NumPy's seeds are 32-bit", least=0, most=2**32 - 1))
"""A run's seed (no config key: draw r's are r·study.seed_stride + 0 … study.seeds − 1, draw
0's 0 … study.seeds − 1): NumPy's 32-bit range."""
CORES = Bound(lambda: Limits(int, "a count of cores", least=1, most=1_000_000))
"""A number of cores (no config key)."""


def _bounded_actions(parser: argparse.ArgumentParser) -> list[tuple[str, str, Bound]]:
    return [(a.option_strings[0] if a.option_strings else a.dest, a.dest, a.type)
            for a in parser._actions if isinstance(a.type, Bound)]  # fmt: skip


def _noting_bounds(arguments: Arguments) -> Arguments:
    """``arguments``, then the bounded options noted in the parser's defaults (``_bounds``)."""

    def add(parser: argparse.ArgumentParser) -> None:
        arguments(parser)
        parser.set_defaults(_bounds=_bounded_actions(parser))

    return add


def check_bounds(args: argparse.Namespace) -> None:
    """``CapeError`` for the first bounded option given outside its bounds (each value of a
    repeated one)."""
    for option, dest, bound in getattr(args, "_bounds", ()):
        given = getattr(args, dest, None)
        for value in given if isinstance(given, list) else [given]:
            said = None if value is None else bound.limits().refusal(value)
            if said is not None:
                raise CapeError(f"{option} {_shown(value)}: {said}")


def _shown(value: float | str) -> str:
    """``value`` as a message shows it: at most about 40 characters of it."""
    text = str(value)
    return text if len(text) <= 40 else f"{text[:20]}…{text[-8:]} ({len(text)} characters)"


def _checking_bounds(func: Command) -> Command:
    """``func``, after ``check_bounds``: before it reads its config or claims its outputs."""

    def checked(args: argparse.Namespace) -> None:
        check_bounds(args)
        func(args)

    checked.__wrapped__ = func  # type: ignore[attr-defined]
    return checked


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


def _config(args: argparse.Namespace) -> dict[str, Any]:
    from cape.config import config_from_args

    return config_from_args(args.config, args.config_json, args.spec)


def _read_dataset(path: str) -> dict[str, Any]:
    from cape.data.bayesrace import read_dataset

    return read_dataset(path)


TABLE_SUFFIXES = (".csv", ".md", ".tex")
FIGURE_SUFFIXES = (".pdf", ".png", ".svg")
JSON_SUFFIXES = (".json",)


def claim(args: argparse.Namespace, *outputs: Any) -> None:
    """Claim this command's outputs (``cape.storage.ownership``) before any work: each refused
    with one line unless it is new or this command's own earlier output; held until the command
    ends."""
    from cape.storage import ownership

    ownership.claim(outputs, f"cape {args.command}")


def _files(
    paths: list[str],
    kind: str,
    suffixes: tuple[str, ...],
    option: str = "--out",
    identity: str = "",
) -> list:
    """The ``ownership.Output`` of each file of a repeatable output flag."""
    from cape.storage.ownership import Output

    return [Output(Path(p), kind, identity, suffixes=suffixes, option=option) for p in paths]


def model_made(item: str) -> tuple[str, int | None, str] | None:
    """A trained model ``NAME=DIR`` as an identity reads it: its name, draw (None: no draw,
    or a value loading the model will refuse) and weights digest; None without ``=``."""
    from cape.closedloop.provenance import model_replicate
    from cape.models.trained import read_meta

    name, sep, folder = item.partition("=")
    if not sep:
        return None
    meta = read_meta(Path(folder))
    try:
        replicate = model_replicate(meta)
    except (TypeError, ValueError):
        replicate = None
    return name, replicate, str(meta.get("weights_sha256"))


def _made_from(models: list[str], data: list[str], settings: Any) -> str:
    """The identity of an output computed from trained models (``NAME=DIR``), data files and
    settings (a typed specification): the models and their draws by name, and one digest of
    their weights, the data's bytes and the settings."""
    import hashlib

    from cape.specs import digest
    from cape.storage.integrity import file_digest

    named, parts = [], [digest(settings)]
    for item in models:
        made = model_made(item)
        if made is None:
            continue  # _load_models says what --model takes
        name, replicate, weights = made
        named.append(name if replicate is None else f"{name} draw {replicate}")
        parts.append(f"{name}:{weights}")
    for path in data:
        try:
            parts.append(file_digest(path))
        except OSError:
            parts.append(f"unreadable:{path}")  # its reader says what is wrong, in one line
    made = hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]
    return f"of {', '.join(named) or 'no models'} [{made}]"


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
    from cape.training.checkpoint import load_model

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
