#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 11 minutes of training), for
# benchmarks/device_detached.sh, chosen so that every run can finish inside the loan (a
# checkpoint cannot come back: over the 16 MiB a returned file may have). Every grid trains
# only what the store lacks; each job's log is LOGDIR/<job>.log; the simulators and optuna
# must be installed there (gpu_carry.sh). On the GPU: the comparison's RLPD on both sparse
# tasks as seed batches of 5 at the reduced budget (50k steps), after a two-seed batch of it
# trains there (if that check fails, rlpd-gpu-check.log says why and the GPU stays idle).
# The H200 loan of 2026-11-27 trained both batches in 310-316 s, sharing the GPU. On the
# cores, niced: JSRL on ball_in_cup (that loan: 643-661 s a run) and the quick threshold
# ablation on MountainCar, whose committed report predates the run store (its missing runs,
# about 250 s each on one core, 8 workers; that loan lacked optuna, so it did not run).
# IBRL's sparse cells train as CPU seed batches on the sessions' own cores.
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
    {
        if [ -n "$dry" ] || "$python" - > "$logs/rlpd-gpu-check.log" 2>&1 <<'CHECK'
import tempfile
from pathlib import Path
from replicate.runner import execute_batch, prepare
from replicate.spec import RunSpec
tiny = {"hidden_sizes": (16, 16), "batch_size": 16, "learning_starts": 100, "utd": 2}
specs = [RunSpec("rlpd", "MountainCarContinuous-v0", s, 600, 200, 1, tiny) for s in (0, 1)]
outcome = execute_batch([prepare(s) for s in specs], Path(tempfile.mkdtemp()), device="cuda")
assert not outcome.failed and len(outcome.runs) == 2, outcome.failed
print("batched RLPD trained on the GPU with graphs")
# batched IBRL's first GPU run too; its outcome is only logged (its grid trains on the cores)
ibrl = {"hidden_sizes": (16, 16), "batch_size": 16, "learning_starts": 100}
specs = [RunSpec("ibrl", "MountainCarContinuous-v0", s, 600, 200, 1, ibrl) for s in (0, 1)]
try:
    outcome = execute_batch([prepare(s) for s in specs], Path(tempfile.mkdtemp()),
                            device="cuda")
    print("batched IBRL on the GPU:", "failed" if outcome.failed else "trained", outcome.failed)
except Exception as error:  # logged for the next session; RLPD's batches go on
    print(f"batched IBRL on the GPU raised {type(error).__name__}: {error}")
CHECK
        then
            "$python" -m replicate compare-rlfd --profile reduced --envs $sparse --algos rlpd \
                --batch 5 --workers 2 --device cuda --checkpoint-interval 0 \
                --out "$(mktemp -d)" $dry > "$logs/rlfd-sparse-rlpd-batches.log" 2>&1
        fi
    } &
    if [ -z "$dry" ]; then  # the ablation has no dry run
        nice -n 10 "$python" -m replicate ablate-threshold --profile quick --workers 8 \
            --device cpu --checkpoint-interval 0 --out "$(mktemp -d)" \
            > "$logs/ablate-quick.log" 2>&1 &
    fi
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced \
        --envs dm_control/ball_in_cup-catch-v0 --algos jsrl --workers 5 --device cpu \
        --checkpoint-interval 0 --out "$(mktemp -d)" $dry > "$logs/rlfd-cup-jsrl.log" 2>&1 &
}
status=0
for job in $(jobs -p); do wait "$job" || status=$?; done
exit $status
