#!/usr/bin/env bash
# The main job: set-up, then a short key-free campaign (TPE) on one family, its audit at a
# reduced seed count, and its report. Override with FAMILY=rendezvous, RUNS=12, SEEDS=3.
# Docking is the default: its search space is bounded so that a run takes seconds to minutes; the
# rendezvous space (EPOCHS up to 1000, N_DEMOS up to 1024) can draw runs of many minutes on a CPU.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/bootstrap.sh"
cd "$root"
family="${FAMILY:-docking}"
campaign="${CAMPAIGN:-runs/main-${family}-tpe}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MPLBACKEND=Agg
echo "[main] warming the ${family} demonstration cache"
python "families/${family}/prepare.py" --warm-cache
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
echo "[main] campaign: TPE on ${family} -> ${campaign}"
autoresearch loop --family "$family" --proposer tpe --max-runs "${RUNS:-8}" --seed 0 \
  --max-seconds 300 --timeout-per-run 120 --campaign "$campaign" "${resume[@]}"
echo "[main] audit (seed noise if the family has none, reseeded verification, pruning, random arm)"
autoresearch audit --campaign "$campaign" --noise-seeds "${SEEDS:-3}" --top 2 --seeds "${SEEDS:-3}" \
  --count "${RUNS:-8}" --workers 2
echo "[main] report: $campaign/report.md"
