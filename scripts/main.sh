#!/usr/bin/env bash
# The main job: set-up, then a short key-free campaign (TPE) on one family, its audit at a
# reduced seed count, and its report. Override with FAMILY=docking, RUNS=12, SEEDS=3.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/bootstrap.sh"
cd "$root"
family="${FAMILY:-rendezvous}"
campaign="${CAMPAIGN:-runs/main-${family}-tpe}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MPLBACKEND=Agg
echo "[main] warming the ${family} demonstration cache"
python "families/${family}/prepare.py" --warm-cache
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
echo "[main] campaign: TPE on ${family} -> ${campaign}"
autoresearch loop --family "$family" --proposer tpe --max-runs "${RUNS:-10}" --seed 0 \
  --campaign "$campaign" "${resume[@]}"
echo "[main] audit (seed noise if the family has none, reseeded verification, pruning, random arm)"
autoresearch audit --campaign "$campaign" --noise-seeds "${SEEDS:-3}" --top 2 --seeds "${SEEDS:-3}" \
  --count "${RUNS:-10}" --workers 2
echo "[main] report: $campaign/report.md"
