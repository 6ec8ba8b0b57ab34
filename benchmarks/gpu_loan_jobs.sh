#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 11 minutes of training), for
# benchmarks/device_detached.sh. A checkpoint cannot come back (over the 16 MiB a returned
# file may have), so only runs that finish inside the loan count. Every grid trains only
# what the store lacks; each job's log is LOGDIR/<job>.log; the simulators and optuna must
# be installed there (gpu_carry.sh).
# On the GPU, alone: the reduced Fig. 3's DRL-EG-GMM on Hopper-v5 (or $GMM_ENV) as one seed
# batch of 5 (200k steps). Whether a 200k MuJoCo batch fits a loan is what this measures:
# the bench's H200 rates for DRL-EG (not GMM) with nothing beside it give about 8-10
# minutes, the rates of loans whose batches shared the GPU and the cores about 25; its log's
# progress bar gives the rate either way. The cores stay free for the batch's env workers.
# (CPU-only grids, such as the quick threshold ablation, train on the sessions' own machine:
# its report checks T2 = 0 against SAC runs bit for bit, and those were trained here.)
# Earlier lists trained the comparison's sparse cells (RLPD batches of 5 in 310-316 s on an
# H200, two sharing it; JSRL 643-661 s a run on its cores); all of them are in runs/.
# usage (on the lent machine, after gpu_carry.sh's install line):
#   benchmarks/device_detached.sh start /tmp/sitting benchmarks/gpu_loan_jobs.sh /tmp/sitting
#   benchmarks/device_detached.sh wait /tmp/sitting $OUT 570     (again while "running")
set -u
logs=${1:?usage: benchmarks/gpu_loan_jobs.sh LOGDIR [--dry-run]} dry=${2:-}
python=${PYTHON:-python3}
# Hopper's and Walker2d's seeds 0-2 are in runs/ (CPU batches), so there the grid trains
# seeds 3-4 (a batch of 2); HalfCheetah's and Ant's 0-2 train as CPU batches on the
# sessions' machine, resumed from its checkpoints: pick an env those do not cover
env_id=${GMM_ENV:-Hopper-v5}
trap 'kill $(jobs -p) 2>/dev/null' TERM
# shellcheck disable=SC2086  # $dry splits on purpose
{
    "$python" -m replicate fig3 --profile reduced --algos drl-eg-gmm --envs "$env_id" \
        --batch 5 --workers 1 --device cuda --checkpoint-interval 0 --out "$(mktemp -d)" \
        $dry > "$logs/fig3-gmm-batch.log" 2>&1 &
}
status=0
for job in $(jobs -p); do wait "$job" || status=$?; done
exit $status
