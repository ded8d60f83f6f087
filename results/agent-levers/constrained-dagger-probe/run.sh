#!/usr/bin/env bash
# Issue 35 on constrained docking: does DAgger help once a round fits the budget? The cold campaign's
# best (it0005: residual, box-aware, 0.75 m standoff, DAGGER_ITERS=2 that never completed a round,
# since relabelling every visited state took 0.6 s a state) trained again under the same training
# budget with and without completed rounds:
#   bc         DAGGER_ITERS=0 (the same recipe as plain behaviour cloning, the control);
#   dagger     DAGGER_ITERS=2, DAGGER_STATES=128 (a random 128 of each round's visited states relabelled);
#   dagger-w0  the same, DAGGER_WEIGHT=0: the rounds' extra training alone, their labels weighing nothing;
#   dagger-w100 the same, DAGGER_WEIGHT=100: each relabelled pair weighing 100 demonstration pairs.
# Each at SEEDS, under AUTORESEARCH_TIME_BUDGET=BUDGET, scored on the search split (where the campaign
# selected; nothing here is strict-feasible-selected, so the sealed split stays untouched), then
# constrained_beside_classical.py sets them beside MPC, the law and PD on the same starts.
#   bash results/agent-levers/constrained-dagger-probe/run.sh > results/logs/agent_levers_constrained_dagger_probe.txt 2>&1
# Runs (weights, patched train.py) go under runs/ (not committed; a finished run is not run again),
# two at a time, one per core.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
SEEDS=${SEEDS:-"0 1"}
BUDGET=${BUDGET:-900}
STATES=${STATES:-128}
root=runs/constrained-dagger-probe
mkdir -p "$root"
ARMS=${ARMS:-"bc dagger dagger-w0 dagger-w100"}
for arm in $ARMS; do
  python - "$root/$arm.py" "$arm" "$STATES" <<'PY'
import json, sys
from pathlib import Path
from autoresearch.editable import patch
runs = Path("results/agent-levers/docking-constrained-gp-cold/runs.jsonl").read_text().splitlines()
config = next(json.loads(line)["config"] for line in runs if json.loads(line)["run_id"] == "it0005")
dagger = {"DAGGER_ITERS": 2, "DAGGER_STATES": int(sys.argv[3])}
arms = {"bc": {"DAGGER_ITERS": 0}, "dagger": dagger}
arms |= {"dagger-w0": dagger | {"DAGGER_WEIGHT": 0.0}, "dagger-w100": dagger | {"DAGGER_WEIGHT": 100.0}}
config |= arms[sys.argv[2]]
source = Path("families/docking-constrained/train.py").read_text()
Path(sys.argv[1]).write_text(patch(source, config))
print(sys.argv[2], "config:", json.dumps(config))
PY
done
FAMILY=docking-constrained
FIELDS="score success_rate violation_rates effort_ratio max_terminal_distance train_seconds budget_exhausted dagger"
source results/agent-levers/probe_lib.sh
probe_runs
runs=()
for arm in $ARMS; do runs+=("$root/$arm"-s*); done
python results/agent-levers/constrained_beside_classical.py "${runs[@]}"
