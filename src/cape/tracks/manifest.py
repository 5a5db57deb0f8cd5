"""The ten BayesRace track files the study needs, with their published SHA-256.

These identify the data (they are what "verified" means), so they live in code rather than in
the study's configuration; where the files are fetched from is configuration.
"""

from __future__ import annotations

UPSTREAM_COMMIT = "0a23cf950d5ec97c12c373622a4606c2321ad7ed"

BAYESRACE_FILES: dict[str, str] = {
    "ethz_center.txt": "9d34978ca0974e39bde2d83dcb9c4f512f207dfe8e6247b712a23d5a3e33aa78",
    "ethz_inner.txt": "a1ef7438cbcefbafad4663aa76ad1a6d25b78902f06662cbbd91a25c83e91416",
    "ethz_outer.txt": "75ecfbb65baeb21fe98d75ac7d07f0740db03137966ada208a03035a027758f7",
    "ethzMobil_center.txt": "32d65467e7ea2e56993a86a54e9a9df9319b84fd6c5a0a254dc192f607a9357e",
    "ethzMobil_inner.txt": "8266d9afc568379fca2e615a861fab0ae5863d4358f7aa6df4fe435236777192",
    "ethzMobil_outer.txt": "1660145ce07761609231f92589d76f7d42a0b2b122252f0528c6e85b6076b59f",
    "ethz_raceline.npz": "886122cd1fc75a05a730973e159170fe84fe6296b9816b27bb08bab3677fe28e",
    "ethz_raceline_long.npz": "64fcde891151b16d9633e1d763c65fd3cb4c69015b76768c51afa054cd4b0a94",
    "ethzMobil_raceline.npz": "61713403af7fd3549e135ee05ffce3cff52aff4ff83b5667a75e0a2a0695ff3d",
    "ethzMobil_raceline_long.npz": "f08f3bfd42ed49786ad16185bc23df9298125069ef7d717692ee3efa734ff3d8",
}
"""File name → SHA-256 hex digest, as listed in the project's SOURCE.md of the mirror."""
