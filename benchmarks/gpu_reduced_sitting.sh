#!/usr/bin/env bash
# One command on a lent GPU machine for the reduced profile's MuJoCo sweep points, as much
# as fits SECONDS: the threshold ablation on both envs (each point one seed batch of 3 on the
# GPU, two points at once per env), and beside it, on the spare cores, the Fig. 3 cells that
# need no T2 rule and train one run per process (PPO, PPO+BC). A 200k-step point needs more
# than the 10 minutes a device command has now (see gpu_short_cells_sitting.sh), so this is
# for a machine lent for longer. Only finished runs come back, packed into OUTDIR/runs.tgz by
# benchmarks/device_sitting.sh (unpack into runs/ here and commit); checkpoints are off
# because none could come back.
# usage: benchmarks/gpu_reduced_sitting.sh SECONDS OUTDIR
set -u
: "${2:?usage: benchmarks/gpu_reduced_sitting.sh SECONDS OUTDIR}"
if [ "$1" = --jobs ]; then  # the sitting's command: every job at once, stopped together
    out=$2 python=${PYTHON:-python3}
    trap 'kill $(jobs -p) 2>/dev/null' TERM
    for env_id in Ant-v5 Walker2d-v5; do
        "$python" -m replicate ablate-threshold --profile reduced --env "$env_id" --batch 3 \
            --workers 2 --device cuda --checkpoint-interval 0 > "$out/ablate-$env_id.log" 2>&1 &
    done
    "$python" -m replicate fig3 --profile reduced --algos ppo ppo-bc --workers 6 \
        --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" > "$out/fig3-ppo.log" 2>&1 &
    status=0
    for job in $(jobs -p); do wait "$job" || status=$?; done
    exit $status  # the last failure's, so that sitting.log does not say 0 over a failed job
fi
seconds=$1 out=$2
exec "$(dirname "$0")/device_sitting.sh" "$seconds" "$out" "$0" --jobs "$out"
