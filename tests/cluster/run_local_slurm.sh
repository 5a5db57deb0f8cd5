#!/usr/bin/env bash
# A real SLURM check of the workflow: start a one-node SLURM cluster on this machine
# (slurmctld and slurmd on localhost, munge for authentication), run the smoke study through
# the repository's SLURM profile, run it again locally, and check that
#   - the jobs went through SLURM (the job-completion log lists every submission), the rollouts
#     in groups: at most one submission per 20 rollouts,
#   - every run's metrics.json is byte-identical between the two,
#   - the SLURM run took at most 1.5 × the local run's wall time (CAPE_SLURM_MAX_RATIO).
#
#   sudo bash tests/cluster/run_local_slurm.sh            # from the repository root, venv active
#   CAPE_SLURM_TARGETS="results/data/DYN-PP-ETHZ.npz" ...  # a quicker check of one target
#
# Needs root (it installs Debian's slurm-wlm and munge when missing, writes /etc/slurm and starts
# the daemons) and the Python environment of requirements.txt (which holds the profile's
# executor plugin). pytest runs it with `pytest -m cluster`.
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
TaskPlugin=task/affinity   # binds a job to its CPUs, as real clusters do (a group job sees its own)
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
# this cluster has no queue and answers at once, so the jobs' states are asked every 1 s, not
# every 10 s as the profile does for a real cluster (CAPE_SLURM_STATUS_SECONDS)
snakemake $TARGETS -s "$REPO/Snakefile" -d "$WORK/slurm" \
    --workflow-profile "$REPO/workflow/profiles/slurm" \
    --seconds-between-status-checks "${CAPE_SLURM_STATUS_SECONDS:-1}" \
    --configfile "$WORK/slurm/config/smoke.yaml" > "$WORK/slurm.log" 2>&1 \
    || { tail -40 "$WORK/slurm.log"; exit 1; }
slurm_s=$(( $(date +%s) - start ))
echo "SLURM run: $slurm_s s"

say "smoke study locally"
start=$(date +%s)
# shellcheck disable=SC2086
snakemake $TARGETS -s "$REPO/Snakefile" -d "$WORK/local" --cores "$CPUS" \
    --configfile "$WORK/local/config/smoke.yaml" > "$WORK/local.log" 2>&1 \
    || { tail -40 "$WORK/local.log"; exit 1; }
local_s=$(( $(date +%s) - start ))
echo "local run: $local_s s"

say "checks"
# every submission, from SLURM's job-completion log (the profile names jobs cape-<group or rule>)
completed=$(grep -c "JobState=COMPLETED" /var/log/slurm/jobcomp.log || true)
failed=$(grep -c "JobState=" /var/log/slurm/jobcomp.log | awk -v c="$completed" '{print $1 - c}')
submissions=$(grep -c "JobState=" /var/log/slurm/jobcomp.log || true)
rollout_submissions=$(grep -c "Name=cape-rollouts-" /var/log/slurm/jobcomp.log || true)
rollouts=$( (find "$WORK/slurm/results/runs" -name metrics.json 2>/dev/null || true) | wc -l)
echo "sbatch submissions: $submissions ($rollout_submissions of them for $rollouts rollouts," \
     "$((submissions - rollout_submissions)) for the other jobs); completed: $completed, failed: $failed"
grep -o "Name=cape-[^ ]*" /var/log/slurm/jobcomp.log | sort | uniq -c
[ "$submissions" -gt 0 ] || { echo "FAIL: no job went through SLURM" >&2; exit 1; }
[ "$failed" -eq 0 ] || { echo "FAIL: $failed SLURM jobs did not complete" >&2; exit 1; }
if [ "$rollouts" -gt 0 ] && [ $((rollout_submissions * 20)) -gt "$rollouts" ]; then
    echo "FAIL: $rollout_submissions submissions for $rollouts rollouts (at most one per 20)" >&2
    exit 1
fi

compared=0
while IFS= read -r file; do
    rel=${file#"$WORK/local/"}
    cmp -s "$file" "$WORK/slurm/$rel" || { echo "FAIL: $rel differs between SLURM and local" >&2; exit 1; }
    compared=$((compared + 1))
done < <(find "$WORK/local/results/runs" -name metrics.json 2>/dev/null | sort)
[ "$compared" -eq "$rollouts" ] || { echo "FAIL: $rollouts runs through SLURM, $compared locally" >&2; exit 1; }
for file in $TARGETS; do
    cmp -s "$WORK/local/$file" "$WORK/slurm/$file" || { echo "FAIL: $file differs" >&2; exit 1; }
done
echo "metrics.json byte-identical in $compared runs"

ratio=$(awk -v s="$slurm_s" -v l="$local_s" 'BEGIN {printf "%.2f", s / l}')
echo "wall time: SLURM $slurm_s s, local $local_s s, ratio $ratio (at most ${CAPE_SLURM_MAX_RATIO:-1.5})"
awk -v r="$ratio" -v m="${CAPE_SLURM_MAX_RATIO:-1.5}" 'BEGIN {exit !(r <= m)}' \
    || { echo "FAIL: SLURM took $ratio × the local run's time" >&2; exit 1; }
echo "PASS"
