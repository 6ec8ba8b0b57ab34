#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 12 minutes of training), for
# benchmarks/device_detached.sh: one 200k-step MuJoCo seed batch of 5 on the GPU (SAC on
# Hopper-v5: claim 2's reference, which needs no T2 rule) and, at a lower priority on the
# cores, one-run cells (Fig. 3's PPO and PPO+BC, the sparse dm-control tasks' DDPGfD).
# Whether the batch fits the loan is not measured yet: the bench's H200 step times give
# about 10 minutes alone, and the first short-cells sitting's batches, sharing the GPU and
# about 27 processes on the 16 cores, ran at 133 batch steps/s, which would need 25. So
# only 8 one-run processes here, niced. Every grid trains only what the store lacks; each
# job's log is LOGDIR/<job>.log. dm-control must be installed there (gpu_carry.sh).
# usage (on the lent machine, after gpu_carry.sh's install line):
#   benchmarks/device_detached.sh start /tmp/sitting benchmarks/gpu_loan_jobs.sh /tmp/sitting
#   benchmarks/device_detached.sh wait /tmp/sitting $OUT 570     (again while "running")
set -u
logs=${1:?usage: benchmarks/gpu_loan_jobs.sh LOGDIR [--dry-run]} dry=${2:-}
python=${PYTHON:-python3}
sparse="dm_control/cartpole-swingup_sparse-v0 dm_control/ball_in_cup-catch-v0"
trap 'kill $(jobs -p) 2>/dev/null' TERM
# shellcheck disable=SC2086  # $sparse and $dry split on purpose
{
    "$python" -m replicate fig3 --profile reduced --algos sac --envs Hopper-v5 \
        --batch 5 --workers 1 --device cuda --checkpoint-interval 0 --out "$(mktemp -d)" \
        $dry > "$logs/fig3-sac.log" 2>&1 &
    nice -n 10 "$python" -m replicate fig3 --profile reduced --algos ppo ppo-bc --workers 4 \
        --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" $dry \
        > "$logs/fig3-ppo.log" 2>&1 &
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced --envs $sparse \
        --algos ddpgfd --workers 4 --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" \
        $dry > "$logs/rlfd-sparse-ddpgfd.log" 2>&1 &
}
status=0
for job in $(jobs -p); do wait "$job" || status=$?; done
exit $status
