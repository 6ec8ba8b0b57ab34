#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 12 minutes of training), for
# benchmarks/device_detached.sh, chosen so that every run can finish inside the loan (a
# checkpoint cannot come back: over the 16 MiB a returned file may have). On the GPU: the
# comparison's ball_in_cup SAC and DRL-EG, seed batches of 5 at the reduced budget (50k
# steps; cartpole's batches of 5 took 377 s each on an H100 beside other work). On the
# cores, niced, the one-run cells that fit beside them: DDPGfD on both sparse tasks and
# JSRL on the sparse cartpole (15 runs; at MountainCar's speed on this repository's CPU
# a 50k-step run is about 6 min for DDPGfD and 9 for JSRL). IBRL, RLPD (30 min a run on a
# core) and Fig. 3's PPO on Ant are left to CPU sittings. A 200k-step MuJoCo seed
# batch is left to CPU sittings: whether it fits a loan is not measured (the bench's H200
# step times give about 10 minutes alone, more beside other work). Every grid trains only
# what the store lacks; each job's log is LOGDIR/<job>.log. dm-control must be installed
# there (gpu_carry.sh).
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
    "$python" -m replicate compare-rlfd --profile reduced --envs dm_control/ball_in_cup-catch-v0 \
        --algos sac drl-eg --batch 5 --workers 2 --device cuda --checkpoint-interval 0 \
        --out "$(mktemp -d)" $dry > "$logs/rlfd-cup-batches.log" 2>&1 &
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced --envs $sparse \
        --algos ddpgfd --workers 10 --device cpu --checkpoint-interval 0 \
        --out "$(mktemp -d)" $dry > "$logs/rlfd-sparse-ddpgfd.log" 2>&1 &
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced --envs "${sparse%% *}" \
        --algos jsrl --workers 5 --device cpu --checkpoint-interval 0 \
        --out "$(mktemp -d)" $dry > "$logs/rlfd-cartpole-jsrl.log" 2>&1 &
}
status=0
for job in $(jobs -p); do wait "$job" || status=$?; done
exit $status
