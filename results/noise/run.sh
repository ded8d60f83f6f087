#!/usr/bin/env bash
# The three families' seed noise measured again on their train.py as it is now. The committed noise
# (results/sealed/*/noise-512, results/docking-constrained/gp/audit/noise) was measured before the
# issue-37 and lever changes to train.py (the budget-paced schedule, the fine-tuning and DAgger
# knobs, off at the baseline), so its pins no longer matched and every `autoresearch audit` of a
# fresh clone measured it again (the main job with 3 seeds, over the family's 10). K = 10 seeds
# (1-10, as before), 2 workers, both splits from one training. Resumable.
#   bash results/noise/run.sh > results/logs/noise_remeasure.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg
python=${PYTHON:-.venv/bin/python}
for family in rendezvous docking docking-constrained; do
  "$python" "families/$family/prepare.py" --warm-cache
  "$python" -m autoresearch noise --family "$family" --seeds 10 --workers 2 --out "results/noise/$family"
done
