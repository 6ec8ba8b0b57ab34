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
lock=$(mktemp)
# one pack at a time, so that the last pack started (the final one) is the last to land
pack() { flock "$lock" "$(dirname "$0")/pack_runs.sh" runs "$out"; }
(while sleep 30; do pack; done) & packer=$!
timeout "$seconds" "$@" > "$out/sitting.log" 2>&1
echo "exit status $?" >> "$out/sitting.log"
kill $packer
wait $packer 2>/dev/null
pack
rm -f "$lock"
# a call returns 16 MiB a file and 64 MiB in all: a log over 8 MB comes back as its last 4 MB
for log in "$out"/*.log; do
    if [ "$(stat -c %s "$log")" -gt 8000000 ]; then
        tail -c 4000000 "$log" > "$log.tail" && mv "$log.tail" "$log"
    fi
done
