#!/usr/bin/env bash
# After the comparison: does picking among more candidates, on the search split only, close the gap
# that a one-seed pick leaves? The fourth arm's three campaigns (as they ended; copied, so the
# committed comparison is untouched) are verified again with verify's default --top 3 and the pick
# made on the reseeded search split (--gate-split search: gate and promotion on search, the sealed
# test split only measured). The top candidate's ten reseeds are reused from the comparison's
# verification (same seeds 11-20); the other two run. Then top3.py tables each candidate and the pick.
#   bash results/keyfree-search/top3.sh >> results/logs/keyfree_top3.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
ROOT=${ROOT:-results/keyfree-search}
for r in 00 01 02; do
  src="$ROOT/tpe-hyperband-off/repeat-$r" dst="$ROOT/top3-search/repeat-$r"
  if [ ! -d "$dst" ]; then
    mkdir -p "$dst/audit"
    cp "$src"/{campaign.json,family.json,proposals.jsonl,runs.jsonl,audit.json} "$dst/"
    cp -r "$src/audit/verify" "$dst/audit/"
  fi
  autoresearch verify --campaign "$dst" --top 3 --seeds 10 --gate-split search --workers 2
done
python results/keyfree-search/top3.py "$ROOT"
