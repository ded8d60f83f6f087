#!/usr/bin/env bash
# Issue 37, item 7: where the key-free agent lands against the hand recipe. Random search, TPE and the
# new arm (TPE proposing, Optuna's HyperbandPruner stopping, every run granted a training time budget
# and scored as it stands), REPEATS repeats each (proposer seeds 0, 1, ...), SECONDS_PER_CAMPAIGN of
# loop time per campaign on 2 workers, in the paper's space (--protocol paper) on rendezvous; the
# target is a report line, so every campaign uses its whole budget. Each campaign's single-seed best
# is then reseeded at SEEDS fresh seeds on the sealed test split (autoresearch verify, the runaway
# gate); `autoresearch compare` scores the arms over their repeats, and summarize.py writes
# summary.json (per arm and repeat: the campaign, the audited best's config and test_metric; the
# target check against the hand recipe, and the new arm against random with a bootstrap interval).
# The campaigns run one after another (each takes both cores), the arms interleaved, so a stopped
# run leaves a balanced comparison; run it again to resume (a campaign whose verification finished
# is skipped: resuming it would only add a session to its campaign.json).
#   bash results/keyfree-search/run.sh >> results/logs/keyfree_search.txt 2>&1
# A session too short for a whole repeat runs some arms of it, e.g.
#   REPEATS=2 ARMS="random tpe-hyperband" bash results/keyfree-search/run.sh >> ... 2>&1
# Note: verify promotes a passing best into families/rendezvous (family.json and ledger.json) when it
# is more reproducible than the family's best (the hand recipe): that is the audit's job; review it.
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MPLBACKEND=Agg PATH="$PWD/.venv/bin:$PATH"
ROOT=${ROOT:-results/keyfree-search}
SECONDS_PER_CAMPAIGN=${SECONDS_PER_CAMPAIGN:-2700}
REPEATS=${REPEATS:-3}
ARMS=${ARMS:-random tpe tpe-hyperband}  # a subset runs only those arms (the rest wait for a later resume)
SEEDS=${SEEDS:-10}
SPACE=${SPACE:-random-range}  # the space of the earlier key-free comparisons (issue 13)
TIMEOUT=${TIMEOUT:-120}       # random and TPE: a run's hard limit, as in those comparisons
BUDGET=${BUDGET:-120}         # the new arm: training seconds per run (its hard limit: + 60 s allowance)
common=(--family rendezvous --protocol paper --space "$SPACE" --max-seconds "$SECONDS_PER_CAMPAIGN"
  --max-iters 100000 --plateau-window 100000 --max-failures 100 --workers 2 --plain)
arm_flags() {
  case "$1" in
    random) echo "--proposer random --timeout-per-run $TIMEOUT" ;;
    tpe) echo "--proposer tpe --timeout-per-run $TIMEOUT" ;;
    tpe-hyperband) echo "--proposer tpe --early-stop hyperband --time-budget $BUDGET" ;;
    # the new arm again, with TPE's off switches for dropout and weight decay, on the family's
    # budget-paced schedule (a later session: random, TPE and the new arm above ran before both)
    tpe-hyperband-off) echo "--proposer tpe --early-stop hyperband --time-budget $BUDGET --off-at-zero" ;;
  esac
}
python families/rendezvous/prepare.py --warm-cache  # its data sets, once (a no-op when cached)
verified() {  # the campaign's audit.json holds a finished verification
  python -c 'import json, sys; sys.exit(json.load(open(sys.argv[1])).get("verify", {}).get("status") != "done")' \
    "$1/audit.json" 2>/dev/null
}
start=$SECONDS
for ((r = 0; r < REPEATS; r++)); do
  for arm in $ARMS; do
    dir="$ROOT/$arm/repeat-$(printf %02d "$r")"
    if verified "$dir"; then
      echo "[keyfree-search] $dir already verified"
      continue
    elif [ -f "$dir/campaign.json" ]; then
      autoresearch loop --resume --campaign "$dir" --plain
    else
      # shellcheck disable=SC2046
      autoresearch loop $(arm_flags "$arm") "${common[@]}" --seed "$r" --campaign "$dir"
    fi
    autoresearch verify --campaign "$dir" --top 1 --seeds "$SEEDS" --workers 2
    echo "[keyfree-search] $dir done at $((SECONDS - start)) s"
  done
done
arms_run=()
for arm in random tpe tpe-hyperband tpe-hyperband-off; do
  if [ -d "$ROOT/$arm" ]; then arms_run+=("$ROOT/$arm"); fi
done
autoresearch compare "${arms_run[@]}" --out "$ROOT/compare"
python results/keyfree-search/summarize.py "$ROOT"
echo "[keyfree-search] total wall time: $((SECONDS - start)) s"
