#!/usr/bin/env bash
# Issue 12: the committed 40-experiment rendezvous TPE campaign (results/rendezvous/tpe: bounds space,
# seed 0, 150 s cap, run beside its random arm so two runs shared the two cores) again with
# --early-stop asha and 2 workers (two runs on the two cores, as then). Compare with:
#   python results/early_stop/summarize.py results/rendezvous/tpe results/early_stop/rdv-tpe-asha
# Run as: bash results/early_stop/run_tpe40.sh > results/logs/early_stop_tpe40.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
campaign=results/early_stop/rdv-tpe-asha
resume=()
[ -f "$campaign/campaign.json" ] && resume=(--resume)
autoresearch loop --family rendezvous --proposer tpe --space bounds --seed 0 --max-iters 40 \
  --plateau-window 1000 --max-failures 12 --timeout-per-run 150 --early-stop asha --workers 2 \
  --campaign "$campaign" --plain "${resume[@]}"
