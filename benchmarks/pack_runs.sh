#!/usr/bin/env bash
# Pack the finished runs of STORE (small files only: no checkpoint, buffer, lock or
# unfinished run, which live in hidden entries) into OUTDIR/runs.tgz, through a temporary
# file first, so that a pack that fails leaves the last good one in place. Exit status 1
# when nothing was packed.
# usage: benchmarks/pack_runs.sh STORE OUTDIR
set -u
store=$1 out=$2
tmp=$(mktemp -p "$out" .pack.XXXXXX)
tar czf "$tmp" -C "$store" --exclude='./.*' --exclude='*.pt' --exclude='*.db' .
# status 1: a file changed while it was read (the store's listing, as a run lands); every
# finished run directory is still whole, since a run enters the store by one rename
if [ $? -le 1 ]; then mv "$tmp" "$out/runs.tgz"; else rm -f "$tmp"; exit 1; fi
