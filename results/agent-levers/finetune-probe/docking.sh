#!/usr/bin/env bash
# Issue 35 on docking: can closed-loop fine-tuning (FINETUNE_STEPS; its loss the flown terminal
# distance, the keep-out intrusion below the filter's standoff and FINETUNE_ENERGY x the energy over
# the expert's) bring the family best's energy (2.9-3.3x the expert's) down without losing its score?
# The family best (the cold GP's residual recipe, family.json: 1024 demonstrations, 1 x 128 tanh,
# 88 epochs, the CBF filter on; it spends its whole 300 s budget cloning) with half its epochs, so
# that FT_STEPS fine-tuning steps at FT_LR fit in the same 300 s, then:
#   ft         FINETUNE_ENERGY = 0 (distance and keep-out only);
#   ft-energy  FINETUNE_ENERGY = ENERGY.
# Each at SEEDS under AUTORESEARCH_TIME_BUDGET=BUDGET, scored on the 512 starts of the search split
# (flown through the filter, as always): a hand probe, so the sealed test split stays for the audit.
#   bash results/agent-levers/finetune-probe/docking.sh > results/logs/agent_levers_finetune_probe_docking.txt 2>&1
# Runs (weights, patched train.py) go under runs/ (not committed; a finished run is not run again),
# two at a time, one per core.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
SEEDS=${SEEDS:-"0 1"}
BUDGET=${BUDGET:-300}
FT_STEPS=${FT_STEPS:-200}
FT_LR=${FT_LR:-0.0001}
ENERGY=${ENERGY:-0.01}
root=runs/finetune-probe-docking
mkdir -p "$root"
ARMS=${ARMS:-"ft ft-energy"}
python families/docking/prepare.py --warm-cache
for arm in $ARMS; do
  python - "$root/$arm.py" "$arm" "$FT_STEPS" "$FT_LR" "$ENERGY" <<'PY'
import json, sys
from pathlib import Path
from autoresearch.editable import patch
config = json.loads(Path("families/docking/family.json").read_text())["best"]["config"]
tuned = {"EPOCHS": config["EPOCHS"] // 2, "FINETUNE_STEPS": int(sys.argv[3]), "FINETUNE_LR": float(sys.argv[4])}
arms = {"ft": tuned, "ft-energy": tuned | {"FINETUNE_ENERGY": float(sys.argv[5])}}
config |= arms[sys.argv[2]]
source = Path("families/docking/train.py").read_text()
Path(sys.argv[1]).write_text(patch(source, config))
print(sys.argv[2], "config:", json.dumps(config))
PY
done
FAMILY=docking
FIELDS="score median_terminal_distance max_terminal_distance success_rate strict_feasible effort_ratio cbf_active_rate train_seconds budget_exhausted finetune"
source results/agent-levers/probe_lib.sh
probe_runs
