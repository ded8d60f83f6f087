#!/usr/bin/env bash
# Issue 13: random, TPE and GP compared like with like on rendezvous: the same space (random-range),
# the same budget (12 experiments, 120 s cap per run), 3 repeats each (proposer seeds 0, 1, 2), two
# repeats at a time on the two cores; then `autoresearch compare`. Resumable: run again to go on.
# Run as: bash results/run_compare_rendezvous.sh > results/logs/compare_rendezvous.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
for proposer in random tpe gp; do
  group="results/compare-rendezvous/rdv-$proposer"
  autoresearch loop --family rendezvous --proposer "$proposer" --space random-range --seed 0 \
    --repeats 3 --workers 2 --max-runs 12 --max-iters 12 --plateau-window 1000 --max-failures 12 \
    --timeout-per-run 120 --campaign "$group" --plain
done
autoresearch compare results/compare-rendezvous/rdv-random results/compare-rendezvous/rdv-tpe \
  results/compare-rendezvous/rdv-gp --out results/compare-rendezvous/rendezvous
