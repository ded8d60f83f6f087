#!/usr/bin/env bash
# Issue 35 on rendezvous: does the costate form (POLICY_FORM = "costate": the network corrects the
# closed-form law's multiplier and is fit to the expert's whole remaining plan) beat the residual
# form? The cold GP campaign's best (it0010: residual, DAgger x3 from 64 starts, box-aware loss,
# 11,738 demonstrations, 7 x 384 GELU; 0.111 m on the sealed split) trained again with:
#   residual    the recipe as the campaign ran it (the control);
#   costate     the same recipe, POLICY_FORM = "costate";
#   costate-bc  that, without DAgger (DAGGER_ITERS = 0);
#   residual-dagger, costate-dagger  the recipe made small enough for its DAgger rounds to run within
#               the budget (1024 demonstrations, 3 x 256, no dropout, 8 epochs a round, 3 rounds of
#               256 starts), in each form (ARMS="residual-dagger costate-dagger").
# Each at SEEDS under AUTORESEARCH_TIME_BUDGET=BUDGET (the campaign's 240 s), scored on the 512
# starts of the search split: a hand probe, so the sealed test split stays for the audit.
#   bash results/agent-levers/costate-probe/run.sh > results/logs/agent_levers_costate_probe.txt 2>&1
# Runs (weights, patched train.py) go under runs/ (not committed; a finished run is not run again),
# two at a time, one per core.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
SEEDS=${SEEDS:-"0 1"}
BUDGET=${BUDGET:-240}
root=runs/costate-probe
mkdir -p "$root"
ARMS=${ARMS:-"residual costate costate-bc"}
python families/rendezvous/prepare.py --warm-cache
for arm in $ARMS; do
  python - "$root/$arm.py" "$arm" <<'PY'
import json, sys
from pathlib import Path
from autoresearch.editable import patch
runs = Path("results/agent-levers/rendezvous-gp-cold/runs.jsonl").read_text().splitlines()
config = next(json.loads(line)["config"] for line in runs if json.loads(line)["run_id"] == "it0010")
arms = {"residual": {}, "costate": {"POLICY_FORM": "costate"}}
arms["costate-bc"] = arms["costate"] | {"DAGGER_ITERS": 0}
small = {"N_DEMOS": 1024, "HIDDEN_DIM": 256, "N_LAYERS": 3, "DROPOUT": 0.0, "EPOCHS": 8}
small |= {"DAGGER_ITERS": 3, "DAGGER_STARTS": 256}
arms |= {f"{form}-dagger": small | {"POLICY_FORM": form} for form in ("residual", "costate")}
config |= arms[sys.argv[2]]
source = Path("families/rendezvous/train.py").read_text()
Path(sys.argv[1]).write_text(patch(source, config))
print(sys.argv[2], "config:", json.dumps(config))
PY
done
FAMILY=rendezvous
FIELDS="mean_terminal_distance median_terminal_distance max_terminal_distance success_rate effort_ratio train_seconds budget_exhausted n_train_pairs dagger"
source results/agent-levers/probe_lib.sh
probe_runs
