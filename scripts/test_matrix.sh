#!/usr/bin/env bash
# The dependency surface's fast tier (below) on the oldest and newest Python the project claims, at
# both ends of its dependency ranges (.ci/run runs it beside scripts/test.sh):
#   py3.10-lowest: every direct dependency at its lowest declared version (uv --resolution lowest-direct)
#   py3.13-newest: every dependency at its newest release
# Both install [llm,dev] (the base, the LLM SDKs, the test tools): no torch, so the tests that need
# [families], [gp], [sb3], [onnx], [ray] or [dashboard] skip, naming the extra. The two run at once
# (each is mostly one process); each job's install and test times are printed.
# Each job runs the dependency surface: the test modules that exercise a dependency's own API (the
# envs and experts on gymnasium, numpy, scipy and proxsuite; the proposers on the SDKs and Optuna;
# the report on matplotlib; the install on pip). The rest of the fast tier (the loop, the audit, the
# process life: our own code over the standard library) runs once, in scripts/test.sh: the whole
# fast tier in both jobs beside it took CI past its 30 minutes. A new module that calls a
# dependency's API belongs in this list.
SURFACE=(
  envs dynamics experts cbf cbf_multi socp constrained_expert constraints rollout vector wrappers
  dispersions start_pool datasets controllers mpc sb3_adapter
  anthropic_proposer openai_proposer llm_loop llm_cli prompting pricing retry
  keyfree_proposers keyfree_space sampling space optuna_journal early_stop warm_start
  report render audit_stats compare_stats journal editable splits install readme shipped_splits
)
MODULES=()
for name in "${SURFACE[@]}"; do MODULES+=("tests/test_$name.py"); done
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
work="${MATRIX_DIR:-$root/.matrix}"
mkdir -p "$work"
if [ ! -x "$work/uv/bin/uv" ]; then
  python3 -m venv "$work/uv" && "$work/uv/bin/python" -m pip install -q uv
fi
uv="$work/uv/bin/uv"

find_python() {  # uv's own discovery, then pyenv's versions
  "$uv" python find --no-python-downloads "$1" 2>/dev/null && return
  local found
  found="$(ls -d "$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")"/versions/"$1".*/bin/python"$1" 2>/dev/null | tail -1)"
  [ -n "$found" ] && echo "$found" && return
  echo "[matrix] Python $1 not found (install it, e.g. with pyenv): the project claims it" >&2
  return 1
}

job() {  # job NAME PYTHON RESOLUTION
  local name="$1" venv="$work/$1" start=$SECONDS
  rm -rf "$venv"
  "$uv" venv -q --seed -p "$2" "$venv"  # --seed: pip in it, as the README's install lines need
  VIRTUAL_ENV="$venv" "$uv" pip install -q --resolution "$3" -e "$root[llm,dev]"
  local installed=$((SECONDS - start)) status=0
  (cd "$root" && OMP_NUM_THREADS=1 MPLBACKEND=Agg "$venv/bin/python" -m pytest -q -m "not slow" -p no:cacheprovider \
    "${MODULES[@]}") \
    > "$work/$name.log" 2>&1 || status=$?
  echo "[matrix] $name: $(tail -1 "$work/$name.log") (install ${installed} s, tests $((SECONDS - start - installed)) s)"
  [ "$status" -eq 0 ] || { tail -40 "$work/$name.log"; return "$status"; }
}

py310="$(find_python 3.10)"
py313="$(find_python 3.13)"
job py3.10-lowest "$py310" lowest-direct & lowest=$!
job py3.13-newest "$py313" highest & newest=$!
failed=0
wait "$lowest" || failed=1
wait "$newest" || failed=1
exit "$failed"
