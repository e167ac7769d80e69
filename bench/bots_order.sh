#!/usr/bin/env bash
# The bot-ordering table of docs/benchmarks.md: one JSON line per match, 200 episodes each.
# Usage: bash bench/bots_order.sh [OUT]   (default bench/out/bots_order.jsonl)
set -euo pipefail
out="${1:-bench/out/bots_order.jsonl}"
mkdir -p "$(dirname "$out")"
: > "$out"
for seed in 0 1000; do
  for pair in "hard easy" "middle easy" "easy random" "hard middle"; do
    set -- $pair
    neuronsmae-match --blue "$1" --red "$2" --episodes 200 --seed "$seed" --json >> "$out"
  done
done
echo "wrote $out"
