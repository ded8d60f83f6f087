#!/usr/bin/env bash
# Creates (or reuses) .venv and installs the project into it. Sourced by main.sh and test.sh.
# torch goes in first and on its own, so that the project's install keeps whatever torch is there.
# Which build pip picks is the index's choice: where the default index offers only CUDA builds for
# this platform (several GB), set TORCH_INDEX_URL to an index of CPU wheels, e.g.
#   TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu bash scripts/test.sh
# (off by default). Override the version with TORCH_SPEC, e.g. TORCH_SPEC="torch==2.5.1".
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${VENV:-$root/.venv}"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
  echo "[setup] creating virtual environment in $venv"
  "$python" -m venv "$venv"
fi
pip="$venv/bin/python -m pip"
# pip runs at its normal verbosity: on a fresh machine the two installs take minutes (torch alone is
# hundreds of MB), and its lines (Collecting, Downloading, Installing) are the progress to watch.
if ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
  echo "[setup] installing ${TORCH_SPEC:-torch==2.13.0} first${TORCH_INDEX_URL:+ from $TORCH_INDEX_URL}:" \
    "a download of hundreds of MB, a few minutes on a fresh machine; pip's progress follows"
  $pip install ${TORCH_INDEX_URL:+--index-url "$TORCH_INDEX_URL"} "${TORCH_SPEC:-torch==2.13.0}"
fi
stamp="$venv/.cwh-installed"
if [ ! -f "$stamp" ] || [ "$root/pyproject.toml" -nt "$stamp" ]; then
  echo "[setup] installing cwh-autoresearch and its dependencies (about a minute); pip's progress follows"
  $pip install -e "$root[${EXTRAS:-all,dev}]"
  touch "$stamp"
fi
echo "[setup] ready: $venv"
export PATH="$venv/bin:$PATH"
