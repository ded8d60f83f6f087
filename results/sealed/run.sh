#!/usr/bin/env bash
# Issue 23, item 5: every committed promoted recipe re-measured on the sealed test split.
# Seed noise of both families at the committed noise seeds (1-10), then each recipe retrained at
# the seeds its audit reseeded it at, scored on both splits from one training. Resumable.
#   bash results/sealed/run.sh > results/logs/sealed_remeasure.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg
python=${PYTHON:-.venv/bin/python}
for family in rendezvous docking; do
  "$python" "families/$family/prepare.py" --warm-cache
  "$python" -m autoresearch noise --family "$family" --seeds 10 --workers 2 --out "results/sealed/$family/noise"
done
"$python" results/sealed/remeasure.py
