#!/usr/bin/env bash
# One command on a lent GPU machine: train ENV's expert as a seed batch for MINUTES, keep
# the best member, and pack the work directory (every member's best policy and curve; no
# checkpoint or buffer) into OUTDIR/expert-<env>.tgz for `python -m replicate expert
# --export-only --root <unpacked>` on the machine that commits it.
# usage: benchmarks/gpu_expert_batch.sh ENV SEEDS MINUTES OUTDIR [DEVICE]
set -u
env_id=$1 seeds=$2 minutes=$3 out=$4 device=${5:-cuda}
name=${env_id//\//__}
root=$(mktemp -d)
pack() {  # each pack writes its own temporary file: a late one cannot corrupt another
    local tmp
    tmp=$(mktemp -p "$out" .pack.XXXXXX)
    tar czf "$tmp" -C "$root" . && mv "$tmp" "$out/expert-$name.tgz"
}
# a pack a minute, so that a command cut short by the device's time still returns the best so far
(while sleep 60; do pack; done) & packer=$!
python3 -m replicate expert --env "$env_id" --algo sac-twin-q --steps 1000000 \
    --seeds "$seeds" --minutes "$minutes" --root "$root" --device "$device" \
    > "$out/expert-$name.log" 2>&1
echo "exit status $?" >> "$out/expert-$name.log"
kill $packer
wait $packer 2>/dev/null
pack
