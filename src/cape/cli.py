"""The ``cape`` command: the entry points the Snakemake rules call.

Each subcommand does one job of the workflow and writes its outputs atomically. Problems the
user can fix are reported as one clear message (exit status 2), never as a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cape.errors import CapeError


def _add_config_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML config to read (default: config/config.yaml)",
    )
    parser.add_argument(
        "--config-json",
        metavar="JSON",
        help="config sections as a JSON object (how the workflow passes them); overrides --config",
    )


def _config(args: argparse.Namespace) -> dict[str, Any]:
    from cape.config import config_from_args

    return config_from_args(args.config, args.config_json)


# --- cape tracks ---------------------------------------------------------------------------
def cmd_tracks(args: argparse.Namespace) -> None:
    from cape.config import section
    from cape.tracks.fetch import obtain_tracks

    cfg = section(_config(args), "tracks")
    mirror = args.mirror if args.mirror is not None else cfg.get("mirror")
    dest = Path(args.dest or cfg["dir"])
    obtain_tracks(
        dest=dest,
        mirror=Path(mirror) if mirror else None,
        url_template=cfg["upstream_url"] if args.url is None else (args.url or None),
        timeout=float(cfg.get("download_timeout", 30)),
    )
    print(f"all track files verified in {dest}")


# --- cape data -----------------------------------------------------------------------------
def cmd_data(args: argparse.Namespace) -> None:
    from cape.config import section
    from cape.data.bayesrace import ProtocolSettings, generate_dataset
    from cape.io import save_npz
    from cape.tracks.track import load_raceline
    from cape.vehicle.params import GROUND_TRUTH

    config = _config(args)
    data_cfg = section(config, "data")
    if args.track not in data_cfg["tracks"]:
        raise CapeError(
            f"--track {args.track}: not a track of the config's `data.tracks` "
            f"({', '.join(sorted(data_cfg['tracks']))})"
        )
    tracks_dir = Path(args.tracks_dir or section(config, "tracks")["dir"])
    settings = ProtocolSettings.from_config(data_cfg, args.track)
    raceline = load_raceline(tracks_dir, data_cfg["tracks"][args.track]["raceline"])
    dataset = generate_dataset(raceline, GROUND_TRUTH, settings)
    save_npz(args.out, **dataset)
    print(f"wrote {args.out}: " + ", ".join(f"{k} {v.shape}" for k, v in dataset.items()))


# --- cape plot-tracks ----------------------------------------------------------------------
def cmd_plot_tracks(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.config import section
    from cape.plots.style import save_figure
    from cape.plots.tracks import TrackPanel, plot_tracks
    from cape.tracks.track import load_raceline, load_track

    config = _config(args)
    catalogue = section(config, "tracks")["catalogue"]
    data_tracks = section(config, "data")["tracks"]
    tracks_dir = Path(args.tracks_dir or config["tracks"]["dir"])
    panels = []
    for item in args.data:
        name, sep, path = item.partition("=")
        if not sep or name not in catalogue or name not in data_tracks:
            raise CapeError(
                f"--data {item}: expected TRACK=PATH with TRACK one of {sorted(data_tracks)}"
            )
        entry = catalogue[name]
        with np.load(path) as npz:
            dataset = {k: npz[k] for k in npz.files}
        panels.append(
            TrackPanel(
                track=load_track(tracks_dir, name, entry["prefix"], entry["width"]),
                raceline=load_raceline(tracks_dir, data_tracks[name]["raceline"]),
                dataset=dataset,
            )
        )
    save_figure(plot_tracks(panels), *args.out)
    print("wrote " + ", ".join(args.out))


def build_parser() -> argparse.ArgumentParser:
    from cape import __version__

    parser = argparse.ArgumentParser(
        prog="cape",
        description="CAPE: control algorithm performance evaluation under learned vehicle "
        "dynamics models. Subcommands are the steps of the Snakemake workflow.",
    )
    parser.add_argument("--version", action="version", version=f"cape {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("tracks", help="obtain and verify the BayesRace track files (SPEC §2)")
    p.add_argument("--dest", help="destination folder (default: config tracks.dir)")
    p.add_argument(
        "--mirror", help="local folder holding the files (default: config tracks.mirror)"
    )
    p.add_argument("--url", help="URL template with {commit} and {file}; '' disables download")
    _add_config_args(p)
    p.set_defaults(func=cmd_tracks)

    p = sub.add_parser(
        "data", help="generate a DYN-PP data set by the BayesRace protocol (SPEC §3)"
    )
    p.add_argument("--track", required=True, help="track name, e.g. ETHZ or ETHZMobil")
    p.add_argument("--out", required=True, help="output .npz path")
    p.add_argument(
        "--tracks-dir", help="folder of the verified track files (default: config tracks.dir)"
    )
    _add_config_args(p)
    p.set_defaults(func=cmd_data)

    p = sub.add_parser("plot-tracks", help="figure of the tracks, racelines and generated data")
    p.add_argument(
        "--data",
        action="append",
        required=True,
        metavar="TRACK=PATH",
        help="a data set to draw (repeat)",
    )
    p.add_argument(
        "--out",
        action="append",
        required=True,
        metavar="PATH",
        help="output file, .pdf or .png (repeat)",
    )
    p.add_argument(
        "--tracks-dir", help="folder of the verified track files (default: config tracks.dir)"
    )
    _add_config_args(p)
    p.set_defaults(func=cmd_plot_tracks)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; a ``CapeError`` becomes a one-line message and exit status 2."""
    args = build_parser().parse_args(argv)
    func: Callable[[argparse.Namespace], None] = args.func
    try:
        func(args)
    except CapeError as exc:
        print(f"cape {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
