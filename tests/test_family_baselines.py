"""A second machine's numbers: each family's baseline, trained here at seed 1 on the shipped splits,
scores its committed sealed-split metric (the family's seed noise in ledger.json) within BASELINE_RTOL.

The splits are the same bits everywhere (tests/test_shipped_splits.py); what may differ between
machines is float rounding in the expert's trajectories and in training (BLAS kernels, torch
builds). Measured at seed 1 on the sealed split, rendezvous: 5.213133060 (the noise of 2026-12-05,
committed before this test), 5.21313 (another machine), 5.213132887 (re-measured here, in
ledger.json); docking: 9.980739260, 9.98073 and 9.980730854. The largest difference is 8.4e-7 relative.
BASELINE_RTOL is 1e-4, a hundred times the largest of those differences, and far below the
baseline's seed noise (about 10 %), so a changed split, problem or training recipe fails it.

Constrained docking is not run here: the expert's trajectories for its 1024 sealed starts take about
40 minutes to solve on CI's two cores (its starts are checked by tests/test_shipped_splits.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BASELINE_RTOL = 1e-4
SEED = 1


@pytest.mark.slow
@pytest.mark.needs("families")
@pytest.mark.parametrize("name", ["rendezvous", "docking"])
def test_the_baseline_at_seed_1_scores_its_committed_sealed_split_metric(name, tmp_path):
    family = ROOT / "families" / name
    registry = json.loads((family / "family.json").read_text())
    noise = json.loads((family / "ledger.json").read_text())["seed_noise"]
    committed = noise["test"]["values"][noise["seeds"].index(SEED)]
    assert noise["split_ids"] == registry["split_ids"]  # measured on the splits the family pins
    result = subprocess.run(
        [
            *(sys.executable, "train.py", "--seed", str(SEED), "--eval-split", "test"),
            *("--runs-log", str(tmp_path / "runs.jsonl"), "--out", str(tmp_path / "out")),
        ],
        cwd=family,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    (line,) = [x for x in result.stdout.splitlines() if x.startswith("FINAL_METRIC: ")]
    record = json.loads(line.removeprefix("FINAL_METRIC: "))
    assert record["split_ids"] == registry["split_ids"]
    assert record["splits"]["test"][registry["metric"]] == pytest.approx(committed, rel=BASELINE_RTOL)
