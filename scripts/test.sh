#!/usr/bin/env bash
# The test command: set-up, lint, format check, then the test suite. Extra args go to pytest, e.g.
#   bash scripts/test.sh -m "not slow"   # the fast tier: no real training runs, no Ray (CI runs all)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
EXTRAS="${EXTRAS:-all,dev}" source "$root/scripts/bootstrap.sh"
cd "$root"
echo "[test] ruff check"; ruff check .
echo "[test] ruff format --check"; ruff format --check .
echo "[test] pytest"
# One test process per core (pytest-xdist; the tests that start Ray share one worker, see
# tests/conftest.py), each single-threaded so that BLAS/torch do not oversubscribe the cores. Every
# extra is installed, so a test that needs one fails rather than skips (tests/conftest.py).
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MPLBACKEND=Agg CWH_REQUIRE_EXTRAS=1
exec python -m pytest -q -n "${TEST_WORKERS:-2}" --dist loadgroup "$@"
