#!/usr/bin/env bash
# One command on a lent machine: run a grid command against the carried run store (runs/)
# for at most SECONDS, packing every finished run directory (small files only: no
# checkpoint, buffer, lock or unfinished run) into OUTDIR/runs.tgz every 30 s and at the
# end, so that a command cut short still returns what finished. Unpack into runs/ here.
# usage: benchmarks/device_sitting.sh SECONDS OUTDIR python3 -m replicate compare-rlfd ...
set -u
seconds=$1 out=$2
shift 2
mkdir -p runs
pack() {  # each pack writes its own temporary file: a late one cannot corrupt another
    local tmp
    tmp=$(mktemp -p "$out" .pack.XXXXXX)
    tar czf "$tmp" -C runs --exclude='./.*' --exclude='*.pt' --exclude='*.db' . \
        && mv "$tmp" "$out/runs.tgz"
}
(while sleep 30; do pack; done) & packer=$!
timeout "$seconds" "$@" > "$out/sitting.log" 2>&1
echo "exit status $?" >> "$out/sitting.log"
kill $packer
wait $packer 2>/dev/null
pack
