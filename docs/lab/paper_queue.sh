#!/usr/bin/env bash
# The paper table's queue on the 2-core lab machine: cells one at a time from a `git archive`
# snapshot, each followed by its six re-tests (docs/lab/results-log.md records each run).
#
#   bash docs/lab/paper_queue.sh start COMMIT [QUEUE]   # QUEUE: lines "alg level seed"
#   bash docs/lab/paper_queue.sh stop                   # the running cell checkpoints (rc 130)
#   bash docs/lab/paper_queue.sh sync                   # the table and run logs into docs/data
#
# `start` builds the snapshot (/work/snap/COMMIT, its own venv over the system's packages,
# which must hold the project's dependencies: `pip install -e ".[train]"` in the checkout),
# seeds $TABLE/paper_table.json from docs/data on a new machine, and runs QUEUE (default
# $TABLE/queue.txt) in the background. A cell stopped half-way resumes from its checkpoint
# and replay in $TABLE/runs when the same cell is started again on the same machine; a new
# machine has lost them, and the cell starts afresh. The log is $TABLE/driver.log.
set -euo pipefail
TABLE=${TABLE:-/work/table}
REPO=$(git -C "$(dirname "$0")" rev-parse --show-toplevel)
RETESTS=("coef=0.5" "level=0" "level=1" "level=easy" "level=middle" "level=hard")
log() { echo "$(date -Is) $*" >>"$TABLE/driver.log"; }

snapshot() {  # the snapshot of $1 with its venv; prints its folder
  local full snap
  full=$(git -C "$REPO" rev-parse --verify "$1^{commit}")
  snap=/work/snap/${full:0:7}
  if [ ! -x "$snap/.venv/bin/python" ]; then
    rm -rf "$snap" && mkdir -p "$snap"
    git -C "$REPO" archive "$full" | tar -x -C "$snap"
    python -m venv --system-site-packages "$snap/.venv"
    "$snap/.venv/bin/pip" install -q --no-deps "$snap" >&2
  fi
  echo "$snap"
}

run_queue() {  # $1 snapshot folder, $2 queue file
  local py=$1/.venv/bin/python rc
  local table=(--learner paper --runs "$TABLE/runs" --out "$TABLE/paper_table.json")
  cd "$1"
  while read -r alg level seed _; do
    [ -z "${alg:-}" ] || [ "${alg:0:1}" = "#" ] && continue
    if [ -e "$TABLE/stop" ]; then log "stop file: not starting $alg $level s$seed"; return 0; fi
    log "start $alg $level s$seed ($1)"
    rc=0
    "$py" -m bench.paper_table "${table[@]}" --algs "$alg" --levels "$level" --seeds "$seed" \
      >>"$TABLE/run_${alg}_${level}_s${seed}.log" 2>&1 || rc=$?
    log "end $alg $level s$seed rc=$rc"
    [ "$rc" -ne 0 ] && return "$rc"
    for at in "${RETESTS[@]}"; do
      rc=0
      "$py" -m bench.paper_table "${table[@]}" --test-at "$at" \
        >>"$TABLE/run_${alg}_${level}_s${seed}.log" 2>&1 || rc=$?
      log "re-test $at rc=$rc"
    done
  done <"$2"
  log "queue done"
}

case "${1:-}" in
  start)
    [ $# -ge 2 ] || { echo "usage: $0 start COMMIT [QUEUE]" >&2; exit 2; }
    mkdir -p "$TABLE/runs"
    queue=$(realpath "${3:-$TABLE/queue.txt}")
    [ -f "$queue" ] || { echo "no queue file $queue (lines: alg level seed)" >&2; exit 2; }
    [ -f "$TABLE/paper_table.json" ] || cp "$REPO/docs/data/paper_table.json" "$TABLE/"
    snap=$(snapshot "$2")
    rm -f "$TABLE/stop"
    setsid nohup bash "$0" _run "$snap" "$queue" >/dev/null 2>&1 &
    echo "queue $queue started from $snap; log $TABLE/driver.log"
    ;;
  _run) run_queue "$2" "$3" ;;
  stop)
    touch "$TABLE/stop"
    if pkill -TERM -f "bench.paper_table --learner paper --runs $TABLE/runs"; then
      log "stopped by hand (touch stop; SIGTERM)"
    fi
    ;;
  sync)
    cp "$TABLE/paper_table.json" "$REPO/docs/data/paper_table.json"
    if [ -d "$TABLE/paper_table_runs" ]; then
      cp -r "$TABLE/paper_table_runs/." "$REPO/docs/data/paper_table_runs/"
    fi
    git -C "$REPO" status --short -- docs/data
    ;;
  *) echo "usage: $0 start COMMIT [QUEUE] | stop | sync" >&2; exit 2 ;;
esac
