"""``cape tracks``, ``data``, ``plot-tracks``, ``raceline``: the track files, the BayesRace
data sets and CAPE's reference raceline (SPEC §2–§3).

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cape.cli.common import (
    FIGURE_SUFFIXES,
    _add_config_args,
    _add_outputs,
    _add_tracks_dir,
    _config,
    _files,
    _tracks_dir,
    bounded,
    claim,
    command,
)
from cape.errors import CapeError
from cape.specs import entry_of


def _tracks_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dest", help="destination folder (default: config tracks.dir)")
    p.add_argument(
        "--mirror", help="local folder holding the files (default: config tracks.mirror)"
    )
    p.add_argument("--url", help="URL template with {commit} and {file}; '' disables download")
    _add_config_args(p)


@command("tracks", "obtain and verify the BayesRace track files (SPEC §2)", _tracks_arguments)
def cmd_tracks(args: argparse.Namespace) -> None:
    from cape.specs.tracks import TracksSpec
    from cape.storage.ownership import Output, is_owner_record
    from cape.tracks.fetch import BAYESRACE_FILES, obtain_tracks

    spec = TracksSpec.from_config(_config(args))
    mirror = args.mirror if args.mirror is not None else spec.mirror
    dest = Path(args.dest or spec.dir)

    def tracks_only(folder: Path) -> str | None:  # a folder this command filled before
        held = [p for p in folder.iterdir() if not is_owner_record(p)]
        return "" if all(p.name in BAYESRACE_FILES for p in held) else None

    option = "--dest" if args.dest else "tracks.dir"
    where = dest.resolve() if dest.is_symlink() else dest  # a link to the files' folder: there
    claim(args, Output(where, "folder of track files", folder=True, option=option,
                        recognise=tracks_only))  # fmt: skip
    obtain_tracks(
        dest=dest,
        mirror=Path(mirror) if mirror else None,
        url_template=spec.upstream_url if args.url is None else (args.url or None),
        timeout=spec.download_timeout,
    )
    print(f"all track files verified in {dest}")


def _data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--track", required=True, help="track name, e.g. ETHZ or ETHZMobil")
    p.add_argument("--out", required=True, help="output .npz path")
    _add_tracks_dir(p)
    _add_config_args(p)


@command("data", "generate a DYN-PP data set by the BayesRace protocol (SPEC §3)", _data_arguments)
def cmd_data(args: argparse.Namespace) -> None:
    from cape.data.bayesrace import ProtocolSettings, generate_dataset
    from cape.specs.tracks import DataSpec
    from cape.storage.io import save_npz
    from cape.storage.ownership import Output
    from cape.tracks.track import load_raceline
    from cape.vehicle.params import GROUND_TRUTH

    spec = DataSpec.from_config(_config(args))
    raceline_file = entry_of(spec.racelines, args.track, "--track", "data.tracks")
    claim(args, Output(Path(args.out), "data set", args.track, (".npz",)))
    tracks_dir = _tracks_dir(args, spec.tracks)
    settings = ProtocolSettings.of(spec.data, args.track)
    raceline = load_raceline(tracks_dir, raceline_file)
    dataset = generate_dataset(raceline, GROUND_TRUTH, settings)
    save_npz(args.out, **dataset)
    print(f"wrote {args.out}: " + ", ".join(f"{k} {v.shape}" for k, v in dataset.items()))


def _plot_tracks_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data",
        action="append",
        required=True,
        metavar="TRACK=PATH",
        help="a data set to draw (repeat)",
    )
    _add_outputs(p, "--out", "output file, .pdf or .png")
    _add_tracks_dir(p)
    _add_config_args(p)


@command(
    "plot-tracks", "figure of the tracks, racelines and generated data", _plot_tracks_arguments
)
def cmd_plot_tracks(args: argparse.Namespace) -> None:
    from cape.data.bayesrace import read_dataset
    from cape.plots.style import save_figure
    from cape.plots.tracks import TrackPanel, plot_tracks
    from cape.specs.tracks import DataSpec
    from cape.tracks.track import load_raceline, load_track

    spec = DataSpec.from_config(_config(args))
    catalogue, data_tracks = spec.tracks.catalogue, spec.racelines
    tracks_dir = _tracks_dir(args, spec.tracks)
    claim(args, *_files(args.out, "figure of the tracks", FIGURE_SUFFIXES))
    panels, drawn = [], set()
    for item in args.data:
        name, sep, path = item.partition("=")
        if name in drawn:
            raise CapeError(f"--data {item}: names {name!r} a second time; give each track once")
        drawn.add(name)
        if not sep or name not in catalogue or name not in data_tracks:
            raise CapeError(
                f"--data {item}: expected TRACK=PATH with TRACK one of {sorted(data_tracks)}"
            )
        entry = catalogue[name]
        dataset = read_dataset(path)
        panels.append(
            TrackPanel(
                track=load_track(tracks_dir, name, entry.prefix, entry.width),
                raceline=load_raceline(tracks_dir, data_tracks[name]),
                dataset=dataset,
            )
        )
    save_figure(plot_tracks(panels), *args.out)
    print("wrote " + ", ".join(args.out))


def _raceline_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--track", required=True, help="track name from `tracks.catalogue`")
    p.add_argument("--out", required=True, help="output .npz (x, y, speed, s, heading, curvature)")
    p.add_argument(
        "--figure", action="append", metavar="PATH", help="figure beside BayesRace's (repeat)"
    )
    p.add_argument(
        "--time-limit",
        type=bounded("rollout.time_limit"),
        help="the runs' time limit (s, rollout.time_limit): refused if shorter than the line's "
        "ideal lap, before any run starts",
    )
    _add_tracks_dir(p)
    _add_config_args(p)


def _raceline_arrays(line: Any) -> dict[str, Any]:
    """What a raceline file holds: the line, its speed, and its path's s, heading, curvature."""
    path = line.path
    return {"x": line.x, "y": line.y, "speed": line.speed, "s": path.s_points,
            "heading": path.heading(path.s_points),
            "curvature": path.curvature(path.s_points)}  # fmt: skip


@command("raceline", "CAPE's minimum-curvature reference raceline (SPEC §2)", _raceline_arguments)
def cmd_raceline(args: argparse.Namespace) -> None:
    from cape.plots.style import save_figure
    from cape.plots.tracks import plot_raceline
    from cape.specs.tracks import RacelineSpec
    from cape.storage.integrity import sealed_arrays
    from cape.storage.io import save_npz
    from cape.storage.ownership import Output
    from cape.tracks.raceline import build_raceline, lap_time
    from cape.tracks.reference import check_time_limit, ideal_lap_time
    from cape.tracks.track import load_raceline, load_track
    from cape.vehicle.params import ACTUATOR_LIMITS, GROUND_TRUTH

    spec = RacelineSpec.from_config(_config(args))
    settings = spec.reference
    entry = entry_of(spec.tracks.catalogue, args.track, "--track", "tracks.catalogue")
    claim(args, Output(Path(args.out), "raceline", args.track, (".npz",)),
           *_files(args.figure or [], "raceline figure", FIGURE_SUFFIXES, "--figure"))  # fmt: skip
    tracks_dir = _tracks_dir(args, spec.tracks)
    track = load_track(tracks_dir, args.track, entry.prefix, entry.width)
    line = build_raceline(track, settings, GROUND_TRUTH, ACTUATOR_LIMITS)
    path = line.path
    ideal = ideal_lap_time(path, line.speed, settings)
    if args.time_limit is not None:  # before anything is written: no run could finish
        check_time_limit(args.time_limit, ideal)
    save_npz(args.out, **sealed_arrays(_raceline_arrays(line)))
    title = (
        f"{args.track}: CAPE raceline {path.length:.2f} m; ideal lap {lap_time(line):.2f} s at "
        f"v_path,\n{ideal:.2f} s at the reference speed (scale {settings.scale}, "
        f"clipped to [{settings.v_min}, {settings.v_max}] m/s)"
    )
    print(title)
    if args.figure:
        bayesrace = load_raceline(tracks_dir, f"{entry.prefix}_raceline.npz")
        save_figure(
            plot_raceline(track, line.x, line.y, line.speed, bayesrace, title), *args.figure
        )
