# Shared helpers: config validation and the names of files the rules produce.

import json

from snakemake.utils import validate

from cape.config import check_consistency
from cape.tracks.manifest import BAYESRACE_FILES


validate(config, "../schemas/config.schema.yaml")
check_consistency(config, "config (config/config.yaml and any --configfile)")

# The software environment of every rule for `--sdm conda` (relative to workflow/rules/).
CAPE_ENV = "../envs/cape.yaml"

TRACK_DIR = config["tracks"]["dir"]
DATA_TRACKS = sorted(config["data"]["tracks"])


wildcard_constraints:
    track="|".join(DATA_TRACKS),


def track_files():
    """The ten verified BayesRace files under the resources folder."""
    return [f"{TRACK_DIR}/{name}" for name in BAYESRACE_FILES]


def config_json(*sections):
    """Only the named config sections, as JSON for a command's --config-json.

    Passing just what a job reads means editing one section reruns only the jobs that use it.
    """
    return json.dumps({name: config[name] for name in sections}, sort_keys=True)


def dataset_path(track):
    return f"results/data/DYN-PP-{track}.npz"


def all_targets():
    return [
        *(dataset_path(t) for t in DATA_TRACKS),
        "results/figures/tracks_and_data.pdf",
        "results/figures/tracks_and_data.png",
    ]
