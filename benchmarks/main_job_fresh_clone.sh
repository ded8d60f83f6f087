#!/usr/bin/env bash
# The main job's wall time on a fresh clone, once installed: clone HEAD into a temporary directory,
# install there (scripts/bootstrap.sh, a fresh .venv), then run scripts/main.sh and keep its output
# in results/logs/main_job_fresh_clone.txt (machine paths stripped), which benchmarks/run_all.py reads.
# Run as: bash benchmarks/main_job_fresh_clone.sh
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
clone="$(mktemp -d)/cwh-autoresearch"
trap 'rm -rf "$(dirname "$clone")"' EXIT
git clone -q "$repo" "$clone"
install_start=$SECONDS
(cd "$clone" && source scripts/bootstrap.sh)
install_s=$((SECONDS - install_start))
log="$repo/results/logs/main_job_fresh_clone.txt"
{
  echo "[fresh clone] commit $(git -C "$clone" rev-parse --short HEAD), $(nproc) CPUs," \
    "$(date -u '+%Y-%m-%d %H:%M UTC'), install: $install_s s"
  bash "$clone/scripts/main.sh" 2>&1
} | sed "s#$clone/##g; s#$clone#.#g; s#$HOME#~#g" | tee "$log"
