#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 11 minutes of training), for
# benchmarks/device_detached.sh. A checkpoint cannot come back (over the 16 MiB a returned
# file may have), so only runs that finish inside the loan count. Every grid trains only
# what the store lacks; the job's log is LOGDIR/fig3-batch.log; the simulators and optuna
# must be installed there (gpu_carry.sh).
# On the GPU, alone: one reduced Fig. 3 cell at 200k steps as one seed batch of the seeds
# the store lacks, the first open cell of CELLS (claim 2's SAC and DRL-EG on Hopper and
# HalfCheetah first: seeds 3-4 make their paired seeds 5). A 200k MuJoCo batch alone fits a
# loan: DRL-EG-GMM's Hopper seeds 3-4 (a batch of 2) trained in 497 s on a lent H200
# (2026-11-27), where batches that shared the GPU and the cores ran at a rate that would
# need about 25 minutes, so one cell per loan. The cores stay free for the env workers.
# (CPU-only grids, such as the quick threshold ablation, train on the sessions' own machine:
# its report checks T2 = 0 against SAC runs bit for bit, and those were trained here.)
# Earlier lists trained the comparison's sparse cells (RLPD batches of 5 in 310-316 s on an
# H200, two sharing it; JSRL 643-661 s a run on its cores); all of them are in runs/.
# `--dry-run` names the cell it would train and its plan, on any machine (DEVICE=cpu
# trains on CPU instead, for a check).
# usage (on the lent machine, after gpu_carry.sh's install line):
#   benchmarks/device_detached.sh start /tmp/sitting benchmarks/gpu_loan_jobs.sh /tmp/sitting
#   benchmarks/device_detached.sh wait /tmp/sitting $OUT 570     (again while "running")
set -u
usage="usage: benchmarks/gpu_loan_jobs.sh LOGDIR [--dry-run]"
logs=${1:?$usage} dry=${2:-}
case $dry in ''|--dry-run) ;; *) echo "$usage" >&2; exit 2 ;; esac
python=${PYTHON:-python3}
device=${DEVICE:-cuda}
cells=${CELLS:-"sac:Hopper-v5 drl-eg:Hopper-v5 sac:HalfCheetah-v5 drl-eg:HalfCheetah-v5
sac:Walker2d-v5 drl-eg:Walker2d-v5 sac:Ant-v5 drl-eg:Ant-v5 drl-eg-gmm:Walker2d-v5
drl-eg-gmm:HalfCheetah-v5 drl-eg-gmm:Ant-v5"}
grid() {  # grid ALGO ENV DEVICE [extra args]: the reduced Fig. 3 cell as one seed batch
    local algo=$1 env_id=$2 on=$3; shift 3
    # exec: the TERM trap below then reaches python itself, not a wrapping shell
    exec "$python" -m replicate fig3 --profile reduced --algos "$algo" --envs "$env_id" \
        --batch 5 --workers 1 --device "$on" --checkpoint-interval 0 \
        --out "$(mktemp -d)" "$@"
}
for cell in $cells; do
    algo=${cell%%:*} env_id=${cell#*:}
    # what the store lacks does not depend on the device: plan on CPU, so that a
    # machine without a GPU can check the choice too
    plan=$(grid "$algo" "$env_id" cpu --dry-run 2>&1) || { echo "$plan" >&2; exit 2; }
    if ! grep -q ' 0 to train' <<< "$plan"; then
        echo "open cell: $algo on $env_id"
        echo "$plan"
        if [ "$dry" = --dry-run ]; then exit 0; fi
        trap 'kill $(jobs -p) 2>/dev/null' TERM
        grid "$algo" "$env_id" "$device" > "$logs/fig3-batch.log" 2>&1 &
        wait $!
        exit $?
    fi
done
echo "every cell of CELLS is whole in the store; nothing to train"
