#!/usr/bin/env bash
# Graded constraints against 0/1 on docking: the GP arm over the bounds space, 3 repeats each
# (proposer seeds 0, 1, 2), up to 16 experiments, median early stopping, 480 s cap per run; the
# loop stops a repeat at the target (0.7, strict-feasible). "graded" is the family as committed;
# "binary" is a copy of it (runs/families/docking, regenerated here, not committed) without
# constraints_field, so the arm is told only whether a run was feasible. Two repeats at a time on
# the two cores; then `autoresearch compare`. Resumable: run it again.
# Run as: bash results/constraints-ab/run.sh > results/logs/constraints_ab.txt 2>&1
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
binary=runs/families/docking
rm -rf "$binary" && mkdir -p "$(dirname "$binary")"
cp -r families/docking "$binary" && rm -rf "$binary/out" "$binary/runs.jsonl"
python - "$binary/family.json" <<'PY'
import json, sys
registry = json.load(open(sys.argv[1]))
del registry["constraints_field"]
json.dump(registry, open(sys.argv[1], "w"), indent=2)
PY
group() {  # group <arm> <family> <repeats> <workers>
  local dir="results/constraints-ab/dock-gp-$1"
  if [ -f "$dir/repeats.json" ]; then
    autoresearch loop --resume --campaign "$dir" --repeats "$3" --workers "$4" --plain
  else
    autoresearch loop --family "$2" --proposer gp --space bounds --seed 0 --repeats "$3" --workers "$4" \
      --max-iters 16 --plateau-window 1000 --max-failures 16 --timeout-per-run 480 --early-stop median \
      --campaign "$dir" --plain
  fi
}
group graded families/docking 2 2
group graded families/docking 3 1 & group binary "$binary" 1 1 & wait
group binary "$binary" 3 2
autoresearch compare results/constraints-ab/dock-gp-graded results/constraints-ab/dock-gp-binary \
  --out results/constraints-ab/docking
