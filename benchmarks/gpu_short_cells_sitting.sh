#!/usr/bin/env bash
# One command on a lent GPU machine for the open cells whose runs finish inside one device
# command (at most 10 minutes). A 200k-step MuJoCo batch does not: about 2.3 ms a gradient
# step plus five 1000-step evaluation episodes every 5000 steps is over 9 minutes on an
# H200 alone (reports/bench/batched_gpu.json), and no checkpoint can come back.
# What does, side by side until SECONDS (every grid trains only what the store lacks):
#  - on the GPU, the comparison's sparse dm-control tasks at the reduced budget (50k steps):
#    SAC and DRL-EG as seed batches of 5, two at a time; IBRL and JSRL one run per process
#    (--batch 1: IBRL's batched trainer had not met a GPU when it was added);
#  - on the spare cores, the same tasks' DDPGfD and Fig. 3's rule-free PPO and PPO+BC cells.
# Measured in its first sitting (H100, 480 s, 2026-11-26; quick's RLPD and JSRL in place of
# IBRL, JSRL and DDPGfD): a cartpole-swingup_sparse batch of 5 ran 133 batch steps/s (50k in
# 377 s) with four one-run RLPD processes on the GPU beside it; those ran 86-98 env steps/s
# each; PPO 730-1070 env steps/s per run on 8 workers (a 200k run in 3-4.5 min).
# Only finished runs come back, packed into OUTDIR/runs.tgz by benchmarks/device_sitting.sh
# (unpack into runs/ here and commit). The machine needs the simulators first:
# benchmarks/gpu_carry.sh builds them here and says how to install them there.
# usage: benchmarks/gpu_short_cells_sitting.sh SECONDS OUTDIR [--dry-run]
set -u
: "${2:?usage: benchmarks/gpu_short_cells_sitting.sh SECONDS OUTDIR [--dry-run]}"
sparse="dm_control/cartpole-swingup_sparse-v0 dm_control/ball_in_cup-catch-v0"
if [ "$1" = --jobs ]; then  # the sitting's command: every job at once, stopped together
    out=$2 dry=${3:-} python=${PYTHON:-python3}
    trap 'kill $(jobs -p) 2>/dev/null' TERM
    # shellcheck disable=SC2086  # $sparse and $dry split on purpose
    {
        "$python" -m replicate compare-rlfd --profile reduced --envs $sparse --algos sac drl-eg \
            --batch 5 --workers 2 --device cuda --checkpoint-interval 0 --out "$(mktemp -d)" \
            $dry > "$out/rlfd-sparse-batched.log" 2>&1 &
        "$python" -m replicate compare-rlfd --profile reduced --envs $sparse --algos ibrl jsrl \
            --batch 1 --workers 4 --device cuda --checkpoint-interval 0 --out "$(mktemp -d)" \
            $dry > "$out/rlfd-sparse-one-run.log" 2>&1 &
        "$python" -m replicate compare-rlfd --profile reduced --envs $sparse --algos ddpgfd \
            --workers 4 --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" $dry \
            > "$out/rlfd-sparse-ddpgfd.log" 2>&1 &
        "$python" -m replicate fig3 --profile reduced --algos ppo ppo-bc --workers 4 \
            --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" $dry \
            > "$out/fig3-ppo.log" 2>&1 &
    }
    status=0
    for job in $(jobs -p); do wait "$job" || status=$?; done
    exit $status  # the last failure's, so that sitting.log does not say 0 over a failed job
fi
seconds=$1 out=$2
exec "$(dirname "$0")/device_sitting.sh" "$seconds" "$out" "$0" --jobs "$out" ${3:-}
