# The agent-levers probes' shared machinery, sourced by their run.sh: each arm's patched train.py
# ($root/<arm>.py) trained at each seed under AUTORESEARCH_TIME_BUDGET, two runs at a time (one per
# core), into $root/<arm>-s<seed> (a run whose policy is there is not run again), then one line per
# run with the FINAL_METRIC fields named in FIELDS.
# Set before probe_runs: root, FAMILY (its directory under families/), BUDGET, FIELDS, SEEDS, ARMS.

probe_one() {  # arm seed
  local run=$root/$1-s$2
  mkdir -p "$run"
  [ -f "$run/out/policy.pt" ] || (cd "families/$FAMILY" && AUTORESEARCH_TIME_BUDGET=$BUDGET \
    python "../../$root/$1.py" --seed "$2" --out "../../$run/out" --runs-log "../../$run/runs.jsonl" \
    > "../../$run/stdout.txt")
  echo "$1 seed $2: $(grep FINAL_METRIC "$run/stdout.txt" | python -c 'import json, os, sys
r = json.loads(sys.stdin.read().split(": ", 1)[1])
print(json.dumps({k: r.get(k) for k in os.environ["FIELDS"].split()}))')"
}

probe_runs() {
  export -f probe_one
  export root FAMILY BUDGET FIELDS
  for seed in $SEEDS; do for arm in $ARMS; do echo "$arm $seed"; done; done |
    xargs -P 2 -L 1 bash -c 'probe_one "$0" "$1"'
}
