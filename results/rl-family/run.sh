#!/usr/bin/env bash
# Issue 60, item 3: the loop tuning reinforcement learning through the family contract. The family
# families/docking-rl trains SB3 PPO (optionally residual on the closed-form law) within the loop's
# time budget and is scored like its behaviour-cloning sibling on the same sealed starts. Arms, each
# a campaign of RUNS runs of BUDGET training seconds, the family's default recipe (the zoo-style
# PPO settings of benchmarks/rl_baselines.py) first in each as its baseline:
#   bash results/rl-family/run.sh gp  > results/logs/rl_family_gp.txt 2>&1   # the agent: key-free GP, cold
#   bash results/rl-family/run.sh tpe > results/logs/rl_family_tpe.txt 2>&1  # the zoo's way: `rl_zoo3
#        -optimize` is Optuna TPE with a median pruner on intermediate evaluations (here the run's
#        PROGRESS lines, four a run)
#   bash results/rl-family/run.sh audit > results/logs/rl_family_audit.txt 2>&1  # the GP arm's audit:
#        seed noise of the default recipe (the zoo-default row), reseeded verification on the sealed
#        split, leave-one-out pruning, the matched random arm
# Re-running an arm resumes it. RUNS (default 10), BUDGET (300 s, the family's), WORKERS (1: the
# other core trains the long RL rows) and SEEDS (5, the audit's reseeds) override the defaults.
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
arm=${1:?usage: run.sh gp|tpe|audit}
RUNS=${RUNS:-10}
BUDGET=${BUDGET:-300}
WORKERS=${WORKERS:-1}
SEEDS=${SEEDS:-5}
root=results/rl-family
python families/docking-rl/prepare.py --warm-cache
start=$SECONDS
case "$arm" in
  gp | tpe)
    dir=$root/docking-rl-$arm
    early=()
    if [ "$arm" = tpe ]; then early=(--early-stop median); fi
    if [ -f "$dir/campaign.json" ]; then
      autoresearch loop --resume --campaign "$dir" --max-runs "$RUNS" --plain
    else
      # The plateau rule off: each arm spends its whole run budget, so the two are matched.
      autoresearch loop --family docking-rl --proposer "$arm" --seed 0 --workers "$WORKERS" \
        --max-runs "$RUNS" --max-iters 1000 --plateau-window 1000 --max-failures 20 \
        --time-budget "$BUDGET" --eval-allowance 300 "${early[@]}" --campaign "$dir" --plain
    fi
    ;;
  audit)
    autoresearch audit --campaign "$root/docking-rl-gp" --top 1 --seeds "$SEEDS" --workers "$WORKERS"
    ;;
  *) echo "unknown arm $arm (gp, tpe or audit)" >&2; exit 2 ;;
esac
echo "[rl-family] $arm done at $((SECONDS - start)) s"
