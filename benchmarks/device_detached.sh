#!/usr/bin/env bash
# A lent machine's job that outlasts one device command (10 minutes) but not the machine's
# loan: `start` launches COMMAND in a session of its own (such a process outlives the call
# that started it and runs on until the machine goes back), against a copy of the carried
# run store in STATE/store ($REPLICATE_STORE, so every figure command uses it), and returns
# at once; each `wait` call then waits up to SECONDS for it to end and packs the finished
# runs into OUTDIR/runs.tgz (every 30 s too), with the log's end in OUTDIR/job.log. Call
# `wait` again at once while it says "running": a machine left idle for half a minute is
# given back, and the job with it. STATE must be outside the repository copy (say
# /tmp/sitting), which each call refreshes.
# usage: benchmarks/device_detached.sh start STATE COMMAND...
#        benchmarks/device_detached.sh wait STATE OUTDIR SECONDS
set -u
here=$(cd "$(dirname "$0")" && pwd)
action=${1:?usage: device_detached.sh start STATE COMMAND... | wait STATE OUTDIR SECONDS}
state=${2:?STATE: a folder outside the repository}
case $action in
start)
    shift 2
    if [ -f "$state/pid" ] && [ ! -f "$state/rc" ]; then
        echo "a job is already running in $state (pid $(cat "$state/pid"))" >&2; exit 2
    fi
    mkdir -p "$state/store"
    cp -r runs/. "$state/store/"
    rm -f "$state/rc"
    REPLICATE_STORE="$state/store" setsid bash -c '"$@" > "$0/job.log" 2>&1; echo $? > "$0/rc"' \
        "$state" "$@" < /dev/null > /dev/null 2>&1 &
    echo $! > "$state/pid"
    echo "started pid $(cat "$state/pid"), store $state/store, log $state/job.log"
    ;;
wait)
    out=${3:?OUTDIR} seconds=${4:?SECONDS}
    end=$((SECONDS + seconds))
    while [ ! -f "$state/rc" ] && [ $SECONDS -lt $end ]; do
        sleep 5
        if [ $(((end - SECONDS) % 30)) -lt 5 ]; then "$here/pack_runs.sh" "$state/store" "$out"; fi
    done
    "$here/pack_runs.sh" "$state/store" "$out"
    tail -c 4000000 "$state/job.log" > "$out/job.log"
    if [ -f "$state/rc" ]; then echo "ended, exit status $(cat "$state/rc")"; else echo running; fi
    ;;
*)
    echo "usage: device_detached.sh start STATE COMMAND... | wait STATE OUTDIR SECONDS" >&2
    exit 2
    ;;
esac
