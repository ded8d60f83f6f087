#!/usr/bin/env bash
# Issue 28 evidence for the third family, families/docking-constrained, key-free and unchanged
# autoresearch: its data, a 16-run GP campaign and its audit (seed noise at K=10, reseeded
# verification of the top 3 at 10 fresh seeds on the sealed test split, leave-one-out pruning, a
# 16-draw random arm), then the PD law with the multi-constraint filter on the same starts.
# Run as: bash results/run_docking_constrained.sh > results/logs/docking_constrained.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
(cd families/docking-constrained && python prepare.py --warm-cache)  # 1,536 constrained solves, once
autoresearch loop --family docking-constrained --proposer gp --seed 0 --max-iters 16 --plateau-window 1000 \
  --timeout-per-run 600 --campaign results/docking-constrained/gp --workers 2 --plain
autoresearch audit --campaign results/docking-constrained/gp --top 3 --seeds 10 --count 16 --workers 2
python results/docking-constrained/pd_law.py > results/docking-constrained/pd_law.md
