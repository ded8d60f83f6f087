#!/usr/bin/env bash
# Compute saved by --early-stop asha: the same random campaign on rendezvous (random-range space,
# seed 0, 10 iterations, 2 workers, 60 s cap per run) with and without early stopping.
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg
for stop in none asha; do
  rm -rf "runs/early-stop-$stop"
  autoresearch loop --family rendezvous --proposer random --space random-range --seed 0 \
    --max-iters 10 --workers 2 --timeout-per-run 60 --early-stop "$stop" --plain \
    --campaign "runs/early-stop-$stop"
done
