#!/usr/bin/env bash
# The jobs of one whole GPU loan (about 11 minutes of training), for
# benchmarks/device_detached.sh, chosen so that every run can finish inside the loan (a
# checkpoint cannot come back: over the 16 MiB a returned file may have). On the GPU: the
# comparison's RLPD on both sparse tasks as seed batches of 5 at the reduced budget (50k
# steps; the SAC and DRL-EG batches of 5 took 377-480 s there on an H100, two sharing it;
# RLPD's ten critics cost more), after a two-seed batch of it trains there (the batched
# RLPD had not met a GPU when this was written: if that check fails, its log,
# rlpd-gpu-check.log, says why and the GPU stays idle). On the cores, niced: IBRL on both sparse tasks and JSRL on
# ball_in_cup, one run per process (15 runs; on the last loan's cores JSRL took about 700 s
# a run, DDPGfD 610-650 s, 15 at once). Every grid trains only what the store lacks; each
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
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced --envs $sparse \
        --algos ibrl --workers 10 --device cpu --checkpoint-interval 0 \
        --out "$(mktemp -d)" $dry > "$logs/rlfd-sparse-ibrl.log" 2>&1 &
    nice -n 10 "$python" -m replicate compare-rlfd --profile reduced \
        --envs dm_control/ball_in_cup-catch-v0 --algos jsrl --workers 5 --device cpu \
        --checkpoint-interval 0 --out "$(mktemp -d)" $dry > "$logs/rlfd-cup-jsrl.log" 2>&1 &
}
status=0
for job in $(jobs -p); do wait "$job" || status=$?; done
exit $status
