#!/usr/bin/env bash
# Issue 35: a key-free agent (Optuna's GP sampler) on a family's search space with the algorithm axis
# (residual on the closed-form law, box-aware loss, DAgger, the expert's standoff, data at scale),
# warm-started from the family's earlier campaigns in the paper's space, every run granted a training
# time budget and scored as it stands; then the audit (seed noise, reseeded verification on the sealed
# test split under the runaway gate, leave-one-out pruning, the random arm) and its report.
#   bash results/agent-levers/run.sh docking > results/logs/agent_levers_docking.txt 2>&1
# Re-running resumes the campaign and the audit where they stopped. RUNS, BUDGET, SEEDS override the
# defaults below (chosen so that each family's campaign and audit take about 1.5-2 h on this 2-core
# machine, the two workers busy). WARM=0 starts the GP cold (campaign <family>-gp-cold): warm-started
# from the paper-space campaigns, whose runs all fly the baseline of the new axis, the docking GP
# never tried it (results/README.md). AUDIT=verify reseeds the best only (no pruning, no random arm).
# SUFFIX names a further campaign of the same kind (the space grew: rendezvous' costate form).
# WARM_FROM="DIR..." warm-starts from those campaigns instead; PROTOCOL=NAME searches under one of the
# family's protocols (docking's `fuel`: feasible only at most 1.5x the expert's energy).
# ENQUEUE=FILE runs that file's configurations first (loop --enqueue: a hand-found recipe the audit
# can then reseed like any other candidate; the campaign records it as enqueued, not proposed).
# WORKERS (default 2) runs that many trainings at once, in the campaign and its audit.
# PROPOSER (default gp) picks the key-free proposer (tpe: Optuna's TPE): campaign <family>-<PROPOSER>[-cold][-SUFFIX].
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
family=${1:?usage: run.sh rendezvous|docking|docking-constrained}
case "$family" in
  rendezvous) warm=(results/evidence/rendezvous-gp results/rendezvous/tpe); runs=20; budget=240 ;;
  docking) warm=(results/evidence/docking-gp results/docking/tpe); runs=16; budget=300 ;;
  docking-constrained) warm=(results/docking-constrained/gp); runs=12; budget=600 ;;
  *) echo "unknown family $family" >&2; exit 2 ;;
esac
RUNS=${RUNS:-$runs}
BUDGET=${BUDGET:-$budget}
SEEDS=${SEEDS:-5}
WORKERS=${WORKERS:-2}
PROPOSER=${PROPOSER:-gp}
dir=results/agent-levers/$family-$PROPOSER
warm_start=(--warm-start "${warm[@]}")
if [ "${WARM:-1}" = 0 ]; then dir=$dir-cold; warm_start=(); fi
if [ -n "${WARM_FROM:-}" ]; then read -ra warm <<< "$WARM_FROM"; warm_start=(--warm-start "${warm[@]}"); fi
protocol=(${PROTOCOL:+--protocol "$PROTOCOL"})
enqueue=(${ENQUEUE:+--enqueue "$ENQUEUE"})
dir=$dir${SUFFIX:+-$SUFFIX}  # e.g. SUFFIX=costate: a new campaign once the space has grown
python "families/$family/prepare.py" --warm-cache  # every pool the space can ask for (a no-op when cached)
start=$SECONDS
if [ -f "$dir/campaign.json" ]; then
  autoresearch loop --resume --campaign "$dir" --plain
else
  # The plateau rule off: the campaign spends its run budget (the target is a report line by default).
  autoresearch loop --family "$family" --proposer "$PROPOSER" --seed 0 --workers "$WORKERS" --max-runs "$RUNS" \
    --max-iters 1000 --plateau-window 1000 --max-failures 20 --time-budget "$BUDGET" --eval-allowance 300 \
    "${warm_start[@]}" "${protocol[@]}" "${enqueue[@]}" --campaign "$dir" --plain
fi
echo "[agent-levers] $family: campaign done at $((SECONDS - start)) s"
if [ "${AUDIT:-audit}" = verify ]; then
  autoresearch verify --campaign "$dir" --top 1 --seeds "$SEEDS" --workers "$WORKERS"
else
  autoresearch audit --campaign "$dir" --top 1 --seeds "$SEEDS" --workers "$WORKERS"
fi
echo "[agent-levers] $family: ${AUDIT:-audit} done at $((SECONDS - start)) s"
