#!/usr/bin/env bash
# Issue 35 on rendezvous: does closed-loop fine-tuning (FINETUNE_STEPS: gradient steps on the mean
# terminal distance, backpropagated through the flown dynamics) move the starts that end metres off?
# The hand recipe (family.json's best: 1024 demonstrations, 50 epochs, 4 x 256 GELU, direct; about
# 100 s of training here) trained again with:
#   hand         the recipe as it is (the control);
#   hand-ft      then FT_STEPS fine-tuning steps at FT_LR;
#   residual-ft  the recipe in the residual form (a correction to the closed-form law), then the same;
#   law-ft       the residual form barely cloned (64 demonstrations, 5 epochs: the law plus a near-zero
#                correction), then LAW_FT_STEPS fine-tuning steps: does the law need the clone at all?
# Each at SEEDS under AUTORESEARCH_TIME_BUDGET=BUDGET (the GP campaigns' 240 s), scored on the 512
# starts of the search split: a hand probe, so the sealed test split stays for the audit.
#   bash results/agent-levers/finetune-probe/run.sh > results/logs/agent_levers_finetune_probe.txt 2>&1
# Runs (weights, patched train.py) go under runs/ (not committed; a finished run is not run again),
# two at a time, one per core.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
SEEDS=${SEEDS:-"0 1"}
BUDGET=${BUDGET:-240}
FT_STEPS=${FT_STEPS:-250}  # ~0.44 s a step for 4 x 256 (measured alone): fits after the ~100 s clone
LAW_FT_STEPS=${LAW_FT_STEPS:-450}
FT_LR=${FT_LR:-0.0001}
root=runs/finetune-probe
mkdir -p "$root"
ARMS=${ARMS:-"hand hand-ft residual-ft law-ft"}
python families/rendezvous/prepare.py --warm-cache
for arm in $ARMS; do
  python - "$root/$arm.py" "$arm" "$FT_STEPS" "$FT_LR" "$LAW_FT_STEPS" <<'PY'
import json, sys
from pathlib import Path
from autoresearch.editable import patch
config = json.loads(Path("families/rendezvous/family.json").read_text())["best"]["config"]
tuned = {"FINETUNE_STEPS": int(sys.argv[3]), "FINETUNE_LR": float(sys.argv[4])}
arms = {"hand": {}, "hand-ft": tuned, "residual-ft": tuned | {"POLICY_FORM": "residual"}}
arms["law-ft"] = arms["residual-ft"] | {"N_DEMOS": 64, "EPOCHS": 5, "FINETUNE_STEPS": int(sys.argv[5])}
config |= arms[sys.argv[2]]
source = Path("families/rendezvous/train.py").read_text()
Path(sys.argv[1]).write_text(patch(source, config))
print(sys.argv[2], "config:", json.dumps(config))
PY
done
FAMILY=rendezvous
FIELDS="mean_terminal_distance median_terminal_distance max_terminal_distance success_rate effort_ratio train_seconds budget_exhausted finetune"
source results/agent-levers/probe_lib.sh
probe_runs
