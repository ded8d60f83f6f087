#!/usr/bin/env bash
# Issue 8 evidence: 3 independent repeats each of TPE and random search on docking (small budget:
# 10 iterations each, plateau stop widened), then `autoresearch compare`.
# Run as: bash results/run_compare.sh > results/logs/compare.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
for proposer in tpe random; do
  autoresearch loop --family docking --proposer "$proposer" --seed 0 --repeats 3 --max-iters 10 \
    --plateau-window 1000 --timeout-per-run 300 --campaign "results/compare/dock-$proposer" --workers 2
done
autoresearch compare results/compare/dock-tpe results/compare/dock-random --out results/compare/docking
