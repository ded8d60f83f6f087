#!/usr/bin/env bash
# Issue 14: the sharper leave-one-out rules beside the paper's on a committed hand recipe. The
# paired rules share one seed plan, so the second reuses the first's runs (only its own extra
# escalations run). Each rule's result is kept under its own audit.json key.
# Run as: bash results/run_pruning.sh rendezvous > results/logs/rendezvous_pruning.txt 2>&1
set -euo pipefail
family="${1:?usage: run_pruning.sh docking|rendezvous}"
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg
campaign="results/$family/hand"
autoresearch prune --campaign "$campaign" --paired --noise-at candidate --workers "${WORKERS:-1}"
autoresearch prune --campaign "$campaign" --paired --workers "${WORKERS:-1}"
autoresearch report --campaign "$campaign" --arm "results/$family/tpe" --arm "results/$family/tpe-random"
