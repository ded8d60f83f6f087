#!/usr/bin/env bash
# A probe of issue 35's routing point on plain docking: the docking family best (the residual recipe,
# DAGGER_ITERS=0) trained again with DAgger rounds, which fly the policy as deployed (the CBF filter on)
# and relabel the states it visits with the expert: the filter-held states of a start behind the
# keep-out sphere are what it would relabel. Each seed is scored on the search split and on the
# sealed test split (--eval-split test), then where_tail_sits.py flies the policies on the test split.
#   bash results/tails/dagger-probe/run.sh > results/logs/tails_dagger_probe.txt 2>&1
# ITERS and SEEDS override the defaults. Runs (weights, patched train.py) go under runs/ (not committed).
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
ITERS=${ITERS:-2}
SEEDS=${SEEDS:-"11 12"}
root=runs/dagger-probe/iters-$ITERS
mkdir -p "$root"
python - "$root/train.py" "$ITERS" <<'PY'
import json, sys
from pathlib import Path
from autoresearch.editable import patch
config = json.loads(Path("families/docking/family.json").read_text())["best"]["config"]
config["DAGGER_ITERS"] = int(sys.argv[2])
source = Path("families/docking/train.py").read_text()
Path(sys.argv[1]).write_text(patch(source, config))
print("config:", json.dumps(config))
PY
for seed in $SEEDS; do
  run=$root/s$seed
  mkdir -p "$run"
  [ -f "$run/out/policy.pt" ] || (cd families/docking && python "../../$root/train.py" --seed "$seed" \
    --eval-split test --out "../../$run/out" --runs-log "../../$run/runs.jsonl" > "../../$run/stdout.txt")
  grep FINAL_METRIC "$run/stdout.txt"
done
python results/tails/where_tail_sits.py "$root"/s*/
