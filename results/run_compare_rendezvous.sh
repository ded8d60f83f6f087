#!/usr/bin/env bash
# Issue 13: random, TPE and GP compared like with like on rendezvous: the same space (random-range),
# the same budget (12 experiments, 120 s cap per run), 3 repeats each (proposer seeds 0, 1, 2), two
# repeats at a time on the two cores (a group grows with --resume --repeats N, so the third repeat of
# one arm runs beside the first of the next); then `autoresearch compare`. Resumable: run it again.
# Run as: bash results/run_compare_rendezvous.sh > results/logs/compare_rendezvous.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
group() {  # group <proposer> <repeats> <workers>
  local dir="results/compare-rendezvous/rdv-$1"
  if [ -f "$dir/repeats.json" ]; then
    autoresearch loop --resume --campaign "$dir" --repeats "$2" --workers "$3" --plain
  else
    autoresearch loop --family rendezvous --proposer "$1" --space random-range --seed 0 --repeats "$2" \
      --workers "$3" --max-runs 12 --max-iters 12 --plateau-window 1000 --max-failures 12 \
      --timeout-per-run 120 --campaign "$dir" --plain
  fi
}
group random 3 2
group tpe 2 2
group tpe 3 1 & group gp 1 1 & wait
group gp 3 2
autoresearch compare results/compare-rendezvous/rdv-random results/compare-rendezvous/rdv-tpe \
  results/compare-rendezvous/rdv-gp --out results/compare-rendezvous/rendezvous
