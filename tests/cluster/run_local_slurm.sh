#!/usr/bin/env bash
# A real SLURM check of the workflow: start a one-node SLURM cluster on this machine
# (slurmctld and slurmd on localhost, munge for authentication), run the smoke study through
# the repository's SLURM profile, run it again locally, and check that
#   - the jobs went through SLURM (sbatch submitted them; the job-completion log lists them),
#   - every run's metrics.json is byte-identical between the two.
#
#   sudo bash tests/cluster/run_local_slurm.sh            # from the repository root, venv active
#   CAPE_SLURM_TARGETS="results/data/DYN-PP-ETHZ.npz" ...  # a quicker check of one target
#
# Needs root (it installs Debian's slurm-wlm and munge when missing, writes /etc/slurm and starts
# the daemons) and the Python environment of requirements.txt; it installs
# requirements-cluster.txt into that environment. pytest runs it with `pytest -m cluster`.
set -euo pipefail

REPO=$(cd "$(dirname "$0")/../.." && pwd)
WORK=${CAPE_SLURM_WORK:-$(mktemp -d /tmp/cape-slurm.XXXXXX)}
TARGETS=${CAPE_SLURM_TARGETS:-}
say() { printf '\n== %s\n' "$*"; }

if [ "$(id -u)" -ne 0 ]; then
    echo "run_local_slurm.sh: needs root (installs packages, starts the SLURM daemons)" >&2
    exit 2
fi
command -v snakemake >/dev/null || { echo "activate the environment of requirements.txt first" >&2; exit 2; }

say "packages"
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi
pip install -q -r "$REPO/requirements-cluster.txt"
slurmctld -V

say "munge"
if [ ! -s /etc/munge/munge.key ]; then
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key status=none
fi
chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
mkdir -p /run/munge && chown munge:munge /run/munge
pgrep -x munged >/dev/null || runuser -u munge -- /usr/sbin/munged
munge -n | unmunge >/dev/null && echo "munge works"

say "slurm.conf"
HOST=$(hostname -s)
CPUS=$(nproc)
MEM=$(awk '/MemTotal/ {print int($2 / 1024 * 0.8)}' /proc/meminfo)
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat > /etc/slurm/slurm.conf <<CONF
ClusterName=cape-test
SlurmctldHost=$HOST
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/pgid
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=/var/log/slurm/jobcomp.log
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
MinJobAge=3600
ReturnToService=2
MpiDefault=none
NodeName=$HOST CPUs=$CPUS RealMemory=$MEM State=UNKNOWN
PartitionName=cape Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
CONF
echo "node $HOST: $CPUS CPUs, $MEM MB"

say "daemons"
pkill -x slurmctld 2>/dev/null || true
pkill -x slurmd 2>/dev/null || true
sleep 1
: > /var/log/slurm/jobcomp.log
slurmctld -c      # clean start: no state from an earlier test
slurmd
for _ in $(seq 30); do
    sinfo -h -o '%T' 2>/dev/null | grep -qE '^(idle|mixed)' && break
    sleep 1
done
sinfo

say "working directories in $WORK"
for where in slurm local; do
    mkdir -p "$WORK/$where/config"
    python - "$REPO" "$WORK/$where/config/config.yaml" <<'PY'
import sys
from pathlib import Path

import yaml

repo, out = Path(sys.argv[1]), Path(sys.argv[2])
cfg = yaml.safe_load((repo / "config" / "config.yaml").read_text())
mirror = cfg["tracks"]["mirror"]
cfg["tracks"]["mirror"] = str((repo / mirror).resolve()) if mirror else None
out.write_text(yaml.safe_dump(cfg))
PY
    cp "$REPO/config/smoke.yaml" "$WORK/$where/config/smoke.yaml"
done

say "smoke study through SLURM"
start=$(date +%s)
# shellcheck disable=SC2086
# this test cluster keeps no accounting database, so job states come from squeue (MinJobAge
# above keeps finished jobs listed), not from sacct as on most real clusters
snakemake $TARGETS -s "$REPO/Snakefile" -d "$WORK/slurm" \
    --workflow-profile "$REPO/workflow/profiles/slurm" --jobs "$CPUS" \
    --slurm-status-command squeue --slurm-init-seconds-before-status-checks 5 \
    --configfile "$WORK/slurm/config/smoke.yaml" > "$WORK/slurm.log" 2>&1 \
    || { tail -40 "$WORK/slurm.log"; exit 1; }
echo "SLURM run: $(( $(date +%s) - start )) s"

say "smoke study locally"
start=$(date +%s)
# shellcheck disable=SC2086
snakemake $TARGETS -s "$REPO/Snakefile" -d "$WORK/local" --cores "$CPUS" \
    --configfile "$WORK/local/config/smoke.yaml" > "$WORK/local.log" 2>&1 \
    || { tail -40 "$WORK/local.log"; exit 1; }
echo "local run: $(( $(date +%s) - start )) s"

say "checks"
submitted=$(grep -c "submitted" "$WORK/slurm.log" || true)
completed=$(grep -c "JobState=COMPLETED" /var/log/slurm/jobcomp.log || true)
failed=$(grep -c "JobState=FAILED" /var/log/slurm/jobcomp.log || true)
echo "sbatch submissions in the log: $submitted; jobs completed by SLURM: $completed, failed: $failed"
[ "$completed" -gt 0 ] || { echo "FAIL: no job completed through SLURM" >&2; exit 1; }
[ "$failed" -eq 0 ] || { echo "FAIL: $failed SLURM jobs failed" >&2; exit 1; }
grep -q "slurm" "$WORK/slurm.log" || { echo "FAIL: the run did not use the SLURM executor" >&2; exit 1; }

compared=0
while IFS= read -r file; do
    rel=${file#"$WORK/local/"}
    cmp -s "$file" "$WORK/slurm/$rel" || { echo "FAIL: $rel differs between SLURM and local" >&2; exit 1; }
    compared=$((compared + 1))
done < <(find "$WORK/local/results/runs" -name metrics.json 2>/dev/null | sort)
n_slurm=$( (find "$WORK/slurm/results/runs" -name metrics.json 2>/dev/null || true) | wc -l)
[ "$compared" -eq "$n_slurm" ] || { echo "FAIL: $n_slurm runs through SLURM, $compared locally" >&2; exit 1; }
for file in $TARGETS; do
    cmp -s "$WORK/local/$file" "$WORK/slurm/$file" || { echo "FAIL: $file differs" >&2; exit 1; }
done
echo "metrics.json byte-identical in $compared runs"
echo "PASS"
