#!/usr/bin/env bash
# Issue 7 evidence for docking: the recipe found by hand (docs/families.md), which neither key-free
# arm reached in 24 draws, put through the audit's reseeded verification. The campaign is the shared
# baseline plus the recipe, enqueued (loop --enqueue); `verify` then reseeds it at 10 fresh seeds
# and gates it (margin >= 2 seed-noise units, strict-feasible on every seed). A run costs 3.5-13
# minutes on one CPU thread here, hence the 1800 s per-run limit.
# Run as: bash results/run_docking_recipe.sh > results/logs/docking_recipe.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
campaign=results/docking/hand
python families/docking/prepare.py --warm-cache
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
autoresearch loop --family docking --proposer tpe --seed 0 --enqueue results/docking/hand_recipe.json \
  --max-runs 2 --plateau-window 1000 --timeout-per-run 1800 --campaign "$campaign" --plain "${resume[@]}"
autoresearch verify --campaign "$campaign" --top 1 --seeds 10 --workers "${WORKERS:-2}"
# Leave-one-out pruning of the promoted recipe, its re-verification, and the report (with the
# key-free arms of results/run_evidence.sh drawn beside it).
autoresearch prune --campaign "$campaign" --workers "${WORKERS:-2}"
autoresearch report --campaign "$campaign" --arm results/docking/tpe --arm results/docking/tpe-random
