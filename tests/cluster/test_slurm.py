"""The workflow on a real (one-node, localhost) SLURM cluster, through the repository's profile.

Runs ``run_local_slurm.sh``: the smoke study through SLURM and locally; at most one
submission per 20 rollouts, every run's metrics byte-identical, the SLURM wall time within 1.5×
the local one. Needs root and Debian's packages, so it is marked ``cluster`` and runs only when
asked for: ``pytest -m cluster``.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).with_name("run_local_slurm.sh")


@pytest.mark.cluster
def test_the_smoke_study_through_slurm_equals_the_local_one(tmp_path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("starting SLURM daemons needs root")
    env = {**os.environ, "CAPE_SLURM_WORK": str(tmp_path)}
    done = subprocess.run(
        ["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=3600
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    assert "PASS" in done.stdout
    assert "sbatch submissions:" in done.stdout and "byte-identical in" in done.stdout
    summary = [line for line in done.stdout.splitlines() if line.startswith(("sbatch", "wall"))]
    print("\n".join(summary))  # shown with -rP: the numbers of the acceptance
