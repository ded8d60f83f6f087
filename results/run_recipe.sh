#!/usr/bin/env bash
# Issue 7 evidence: a family's recipe found by hand (docs/families.md), which neither key-free arm
# assembled, put through the audit. The campaign is the shared baseline plus the recipe in
# results/<family>/hand_recipe.json, enqueued (loop --enqueue); `verify` reseeds it at 10 fresh
# seeds and gates it (margin >= 2 seed-noise units, feasible on every seed), `prune` reverts each
# edit alone and re-verifies, and the report draws the family's key-free arms beside it.
# A docking run costs 3.5-13 minutes on one CPU thread here, a rendezvous run about 90 s.
# Run as: bash results/run_recipe.sh docking > results/logs/docking_recipe.txt 2>&1
set -euo pipefail
family="${1:?usage: run_recipe.sh docking|rendezvous}"
case "$family" in
  docking) timeout=1800 ;;
  rendezvous) timeout=600 ;;
  *) echo "run_recipe.sh: unknown family $family" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
campaign="results/$family/hand"
python "families/$family/prepare.py" --warm-cache
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
autoresearch loop --family "$family" --proposer tpe --seed 0 --enqueue "results/$family/hand_recipe.json" \
  --max-runs 2 --plateau-window 1000 --timeout-per-run "$timeout" --campaign "$campaign" --plain "${resume[@]}"
autoresearch verify --campaign "$campaign" --top 1 --seeds 10 --workers "${WORKERS:-2}"
autoresearch prune --campaign "$campaign" --workers "${WORKERS:-2}"
autoresearch report --campaign "$campaign" --arm "results/$family/tpe" --arm "results/$family/tpe-random"
