#!/usr/bin/env bash
# Issue 13: random, TPE and GP compared like with like on rendezvous: the same space (random-range),
# the same budget (BUDGET experiments, 120 s cap per run, no early stopping), 3 repeats each
# (proposer seeds 0, 1, 2); then `autoresearch compare`. The repeats run two at a time on the two
# cores, each on its own (a repeat is a campaign of its own); the groups were first run at 12
# experiments and then grown to BUDGET by resuming every repeat with the larger caps, so their first
# 12 experiments are the earlier comparison's. Resumable: run it again.
# Run as: bash results/run_compare_rendezvous.sh > results/logs/compare_rendezvous.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
BUDGET=${BUDGET:-40}
ROOT=results/compare-rendezvous
caps=(--max-iters "$BUDGET" --max-runs "$BUDGET")
for arm in random tpe gp; do
  [ -f "$ROOT/rdv-$arm/repeats.json" ] || autoresearch loop --family rendezvous --proposer "$arm" \
    --space random-range --seed 0 --repeats 3 --workers 2 "${caps[@]}" --plateau-window 1000 \
    --max-failures 12 --timeout-per-run 120 --campaign "$ROOT/rdv-$arm" --plain
done
# every repeat, arms interleaved, two at a time
for i in 00 01 02; do for arm in random tpe gp; do echo "$ROOT/rdv-$arm/repeat-$i"; done; done |
  xargs -P 2 -I{} autoresearch loop --resume --campaign {} "${caps[@]}" --plain
# record the caps in each group's repeats.json (every repeat is finished: nothing runs)
for arm in random tpe gp; do autoresearch loop --resume --campaign "$ROOT/rdv-$arm" "${caps[@]}" --plain; done
autoresearch compare "$ROOT/rdv-random" "$ROOT/rdv-tpe" "$ROOT/rdv-gp" --out "$ROOT/rendezvous"
