#!/usr/bin/env bash
# The rendezvous recipe found by hand (docs/families.md), which neither key-free arm assembled in 40
# capped draws, put through the audit: enqueued after the shared baseline (loop --enqueue), then
# reseeded at 10 fresh seeds and gated by `verify`, then pruned. About 90 s a run on one CPU thread.
# Run as: bash results/run_rendezvous_recipe.sh > results/logs/rendezvous_recipe.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
campaign=results/rendezvous/hand
python families/rendezvous/prepare.py --warm-cache
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
autoresearch loop --family rendezvous --proposer tpe --seed 0 --enqueue results/rendezvous/hand_recipe.json \
  --max-runs 2 --plateau-window 1000 --timeout-per-run 600 --campaign "$campaign" --plain "${resume[@]}"
autoresearch verify --campaign "$campaign" --top 1 --seeds 10 --workers "${WORKERS:-2}"
autoresearch prune --campaign "$campaign" --workers "${WORKERS:-2}"
autoresearch report --campaign "$campaign" --arm results/rendezvous/tpe --arm results/rendezvous/tpe-random
