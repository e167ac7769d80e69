#!/usr/bin/env bash
# The bot-ordering table of docs/contexts.md ("Bots"): one JSON line per match, 200 episodes
# each (seeds S .. S+199), at S = 0 and S = 1000, default contexts, 2 v 2.
# Usage: bash bench/bots_order.sh [OUT]   (default docs/data/bots_order.jsonl)
# MATCH=/path/to/neuronsmae-match picks the command (default: the one on PATH).
set -euo pipefail
out="${1:-docs/data/bots_order.jsonl}"
match="${MATCH:-neuronsmae-match}"
mkdir -p "$(dirname "$out")"
: > "$out"
# blue red: the paper's order (hard > middle > easy), easy against random, released 1 against
# released 0, and each of this project's variants against its paper counterpart and easy.
pairs=(
  "hard easy" "middle easy" "hard middle" "easy random" "1 0"
  "middle_spread middle" "hard_flank hard" "middle_spread easy" "hard_flank easy"
)
for seed in 0 1000; do
  for pair in "${pairs[@]}"; do
    set -- $pair
    "$match" --blue "$1" --red "$2" --episodes 200 --seed "$seed" --json >> "$out"
  done
done
echo "wrote $out"
