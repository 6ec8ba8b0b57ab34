#!/usr/bin/env bash
# A lent machine's job that outlasts one device command (10 minutes) but not the machine's
# loan: `start` launches COMMAND in a session of its own (such a process outlives the call
# that started it and runs on until the machine goes back), against a copy of the carried
# run store in STATE/store ($REPLICATE_STORE, so every figure command uses it), and returns
# at once; each `wait` call then waits up to SECONDS for it to end and packs the finished
# runs into OUTDIR/runs.tgz (every 30 s too), with the end of every log in STATE (the
# command's output in job.log, and any log its jobs write there) in OUTDIR. Call `wait`
# again at once while it says "running": a machine left idle for half a minute is given
# back, and the job with it. STATE must be outside the repository copy (say /tmp/sitting),
# which each call refreshes. Leave a device command's limit some room: `wait` ends within
# a few seconds of SECONDS, then packs.
# usage: benchmarks/device_detached.sh start STATE COMMAND...
#        benchmarks/device_detached.sh wait STATE OUTDIR SECONDS
set -u
here=$(cd "$(dirname "$0")" && pwd)
usage="usage: device_detached.sh start STATE COMMAND... | wait STATE OUTDIR SECONDS"
action=${1:?$usage}
state=${2:?$usage}
alive() { [ -f "$state/pid" ] && kill -0 "$(cat "$state/pid")" 2>/dev/null; }
case $action in
start)
    shift 2
    if [ $# -eq 0 ]; then echo "$usage" >&2; exit 2; fi
    if [ ! -f "$state/rc" ] && alive; then
        echo "a job is already running in $state (pid $(cat "$state/pid"))" >&2; exit 2
    fi
    mkdir -p "$state/store"
    cp -r runs/. "$state/store/"
    rm -f "$state/rc" "$state/pid" "$state"/*.log
    # the wrapper records its own pid: setsid may fork, and then $! would be setsid's
    REPLICATE_STORE="$state/store" setsid bash -c \
        'echo $$ > "$0/pid"; "$@" > "$0/job.log" 2>&1; echo $? > "$0/rc"' \
        "$state" "$@" < /dev/null > /dev/null 2>&1 &
    for _ in $(seq 50); do [ -s "$state/pid" ] && break; sleep 0.1; done
    echo "started pid $(cat "$state/pid"), store $state/store, log $state/job.log"
    ;;
wait)
    out=${3:?$usage} seconds=${4:?$usage}
    if [ ! -f "$state/pid" ]; then
        echo "no job was started in $state (on this machine: a fresh one has none)" >&2; exit 2
    fi
    end=$((SECONDS + seconds)) next_pack=$((SECONDS + 30))
    while [ ! -f "$state/rc" ] && alive && [ $SECONDS -lt $end ]; do
        left=$((end - SECONDS))
        sleep $((left < 1 ? left : 1))
        if [ $SECONDS -ge $next_pack ] && [ $SECONDS -lt $end ]; then
            "$here/pack_runs.sh" "$state/store" "$out"
            next_pack=$((SECONDS + 30))
        fi
    done
    "$here/pack_runs.sh" "$state/store" "$out"
    for log in "$state"/*.log; do
        [ -f "$log" ] && tail -c 4000000 "$log" > "$out/$(basename "$log")"
    done
    if [ -f "$state/rc" ]; then echo "ended, exit status $(cat "$state/rc")"
    elif alive; then echo running
    else echo "died without an exit status (killed?)"; exit 1
    fi
    ;;
*)
    echo "$usage" >&2
    exit 2
    ;;
esac
