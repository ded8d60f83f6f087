#!/usr/bin/env bash
# The main job: set-up, then a short key-free campaign on rendezvous, its audit on the sealed test
# split and its report; at the end, the promoted recipe beside the family best and the classical
# controllers on the same split. Two jobs, one variable apart:
#
#   bash scripts/main.sh            # JOB=agent: the agent at its best, in about 10 minutes
#   JOB=paper bash scripts/main.sh  # the paper's protocol: a 4-experiment TPE campaign, whole audit
#
# JOB=agent: a GP campaign over the family's whole space (the algorithm axis included), warm-started
# from the committed campaign that found the family best (Optuna's add_trials: it starts from those
# 16 runs instead of from nothing), RUNS runs of BUDGET seconds of training, two at a time; then
# the audit without pruning (reseeded verification of its best at SEEDS fresh seeds on the sealed
# split, a random arm of COUNT draws under the same budget) and the report. Pruning is left out of
# the 10 minutes: a recipe of this space has 15-20 edits to revert one at a time
# (`autoresearch prune --campaign DIR` runs it afterwards).
# JOB=paper: TPE's seed 16 over the paper's protocol (benchmarks/pick_main_seed.py picked it because
# its first draw is cheap), the whole audit (seed noise if missing, verification, pruning, random
# arm). Knobs: FAMILY, PROPOSER, SPACE, PROTOCOL, SEED, RUNS, TIMEOUT, SEEDS, COUNT, BUDGET.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/bootstrap.sh"
cd "$root"
job="${JOB:-agent}"
family="${FAMILY:-rendezvous}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MPLBACKEND=Agg
start=$SECONDS
echo "[main] warming the ${family} demonstration cache"
python "families/${family}/prepare.py" --warm-cache
if [ "$job" = paper ]; then
  proposer="${PROPOSER:-tpe}"
  campaign="${CAMPAIGN:-runs/main-${family}-${proposer}}"
  resume=()
  [ -f "$campaign/campaign.json" ] && resume=(--resume)
  protocol=()
  [ -n "${PROTOCOL-paper}" ] && protocol=(--protocol "${PROTOCOL-paper}")
  echo "[main] campaign: ${proposer} over the ${SPACE:-random-range} space of ${family} (protocol: ${PROTOCOL-paper}) -> ${campaign}"
  autoresearch loop --family "$family" --proposer "$proposer" --space "${SPACE:-random-range}" "${protocol[@]}" \
    --max-iters "${RUNS:-4}" --max-failures 100 --plateau-window 100 --seed "${SEED:-16}" \
    --timeout-per-run "${TIMEOUT:-120}" --campaign "$campaign" --plain "${resume[@]}"
  echo "[main] audit: seed noise if the family has none, reseeded verification, pruning, random arm (gated on the sealed test split)"
  autoresearch audit --campaign "$campaign" --noise-seeds "${SEEDS:-3}" --top 1 --seeds "${SEEDS:-3}" \
    --count "${COUNT:-4}" --workers 2
elif [ "$job" = agent ]; then
  proposer="${PROPOSER:-gp}"
  campaign="${CAMPAIGN:-runs/main-${family}-agent}"
  warm="${WARM_FROM:-results/agent-levers/${family}-gp-cold-finetune}"
  resume=()
  [ -f "$campaign/campaign.json" ] && resume=(--resume)
  echo "[main] campaign: ${proposer} over the whole space of ${family}, warm-started from ${warm} -> ${campaign}"
  autoresearch loop --family "$family" --proposer "$proposer" --warm-start "$warm" --seed "${SEED:-0}" \
    --max-runs "${RUNS:-3}" --time-budget "${BUDGET:-110}" --workers 2 --max-failures 100 \
    --plateau-window 100 --campaign "$campaign" --plain "${resume[@]}"
  echo "[main] audit: reseeded verification on the sealed test split, a random arm under the same budget (pruning: autoresearch prune --campaign $campaign)"
  autoresearch verify --campaign "$campaign" --top 1 --seeds "${SEEDS:-2}" --workers 2
  autoresearch random --budget-from "$campaign" --count "${COUNT:-2}" --workers 2
  autoresearch report --campaign "$campaign"
else
  echo "[main] JOB must be agent or paper, got ${job}" >&2
  exit 2
fi
python - "$campaign" "$family" <<'EOF'
import json
import sys
from pathlib import Path

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.report import headline
from autoresearch.campaign.audit_log import read_audit

root, family = Path(sys.argv[1]), sys.argv[2]
audit = read_audit(root)
figures = ", ".join(sorted(p.name for p in root.glob("*.png")))
print(f"[main] report: {root / 'report.md'} (figures beside it: {figures})")
# What the audit promoted (the pruned recipe where it beat the full one): what policy.onnx holds
print(f"[main] headline: {headline(open_campaign(root, read_only=True), audit)}")
prune = audit.get("prune") or {}
if prune:
    print(f"[main] pruning: {prune.get('reason') or prune.get('status')}")
if (root / "policy.onnx").exists():
    print(f"[main] exported: {root / 'policy.onnx'}, the promoted policy")
# Beside it, the committed leaderboard on the same sealed split (benchmarks/leaderboard.py).
rows = [r for r in json.loads(Path("results/leaderboard.json").read_text()) if r["task"] == family]
print(f"[main] beside it on the sealed test split ({rows[0]['metric_name']}; results/leaderboard.md):")
for r in rows:
    if r["kind"] != "sb3" and r["controller"] != "open-loop expert":
        print(f"[main]   {r['controller']:<28} {r['metric']:.4g}")
EOF
echo "[main] wall time: $((SECONDS - start)) s"
