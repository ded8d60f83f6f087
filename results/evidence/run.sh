#!/usr/bin/env bash
# Issue 13, item 2: a key-free evidence campaign on one family, then its audit (reseeded
# verification at n=10, leave-one-out pruning, a small random arm on the same space).
# Run as: bash results/evidence/run.sh rendezvous > results/logs/evidence_rendezvous.txt 2>&1
# Knobs (environment): PROPOSER, SPACE, ITERS, TIMEOUT (per run), SECONDS_BUDGET (campaign wall
# clock, s), EARLY_STOP, TOP (candidates reseeded), COUNT (random-arm draws), AUDIT (audit: the
# whole audit; verify: the reseeded verification only, for docking, whose runs take minutes each).
set -euo pipefail
family="$1"
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
proposer="${PROPOSER:-gp}"
campaign="results/evidence/${family}-${proposer}"
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
start=$SECONDS
autoresearch loop --family "$family" --proposer "$proposer" --space "${SPACE:-random-range}" \
  --seed 0 --max-iters "${ITERS:-80}" --max-seconds "${SECONDS_BUDGET:-2700}" \
  --plateau-window 1000 --max-failures 20 --timeout-per-run "${TIMEOUT:-120}" \
  --early-stop "${EARLY_STOP:-median}" --workers 2 --campaign "$campaign" --plain "${resume[@]}"
echo "[evidence] campaign wall time: $((SECONDS - start)) s"
if [ "${AUDIT:-audit}" = verify ]; then
  autoresearch verify --campaign "$campaign" --top "${TOP:-2}" --seeds 10 --workers 2
  autoresearch report --campaign "$campaign"
else
  autoresearch audit --campaign "$campaign" --top "${TOP:-2}" --seeds 10 --count "${COUNT:-8}" --workers 2
fi
echo "[evidence] total wall time: $((SECONDS - start)) s"
