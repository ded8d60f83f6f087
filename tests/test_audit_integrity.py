"""Issue 38, items 4 and 5: what the audit writes stays valid. Statistics of large finite metrics
are computed without overflow, or refused before anything is written (family.json and ledger.json
never hold Infinity); and a campaign whose proposals.jsonl repeats a record is refused by the audit,
as report and --resume refuse it, before any step runs or promotes."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from audit_support import ScriptedProposer, copy_family, run_campaign
from loop_helpers import TOY_FAMILY, copy_toy, snapshot

from autoresearch import ledger
from autoresearch.audit.stats import mean_sd, noise_floor, reseed_gate
from autoresearch.journal import JournalError, read_json

CLI = [sys.executable, "-m", "autoresearch"]


def _metric_of_seed(tmp_path, expression: str):
    """The toy family whose loss is ``expression`` of the run's seed."""
    toy = copy_toy(tmp_path)
    train = toy / "train.py"
    train.write_text(
        train.read_text().replace('        "loss": loss + noise,', f'        "loss": {expression},', 1)
    )
    return toy


def test_statistics_of_large_finite_values_do_not_overflow():
    values = [1e160 * (1 + seed) for seed in range(1, 4)]
    with np.errstate(over="ignore"):
        assert np.std(values, ddof=1) == math.inf  # what the plain formula gives
    floor = noise_floor(values)
    assert math.isclose(floor.mean, 3e160) and math.isclose(floor.std, 1e160)
    assert mean_sd([1.7e308, 1.7e308]) == (1.7e308, 0.0)
    gate = reseed_gate([1e160, 3e160], [True, True], mu0=5e160, sigma=1e160, sign=-1)
    assert math.isclose(gate.mu_r, 2e160) and math.isclose(gate.sigma_r, math.sqrt(2) * 1e160)
    with pytest.raises(ValueError, match="too large for a float"):
        mean_sd([1.7e308, -1.7e308, 1.7e308])


def test_noise_of_a_metric_near_the_float_limit_is_measured_or_refused_never_written_infinite(tmp_path):
    toy = _metric_of_seed(tmp_path / "a", "1e160 * (1 + seed)")
    done = subprocess.run([*CLI, "noise", "--family", str(toy), "--seeds", "3", "--out", str(tmp_path / "n")])
    assert done.returncode == 0
    noise = read_json(toy / "ledger.json")["seed_noise"]
    assert math.isclose(noise["std"], 1e160) and math.isclose(noise["mean"], 3e160)
    assert "Infinity" not in (toy / "ledger.json").read_text()
    assert subprocess.run([*CLI, "check", "--family", str(toy)], capture_output=True).returncode == 0

    toy = _metric_of_seed(tmp_path / "b", "1.7e308 * (-1) ** seed")
    before = snapshot(toy)
    cmd = [*CLI, "noise", "--family", str(toy), "--seeds", "3", "--out", str(tmp_path / "m")]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    (error,) = [line for line in done.stderr.splitlines() if "error:" in line]
    assert "too large for a float" in error and "Traceback" not in done.stderr
    assert snapshot(toy) == before  # nothing written: the family still loads


def test_the_ledger_refuses_a_non_finite_number_before_writing_either_file(tmp_path):
    family = copy_family(TOY_FAMILY, tmp_path / "toy")
    before = snapshot(family.path)

    def infinite_best(registry, old):
        registry["best"] = {"config": family.baseline_config, "metric": math.inf}
        return old.promoted({"config": family.baseline_config, "metric": math.inf}), None

    with pytest.raises(JournalError, match="not finite"):
        ledger.update(family.path, infinite_best)
    after = snapshot(family.path)
    assert after.pop("family.json.lock") == b"" and after == before


def test_the_audit_refuses_a_campaign_with_a_repeated_record(tmp_path):
    family = copy_family(TOY_FAMILY, tmp_path / "toy")
    campaign = run_campaign(family, tmp_path / "c", ScriptedProposer([{"EPOCHS": 20}, {"EPOCHS": 25}]), 3)
    proposals = campaign / "proposals.jsonl"
    lines = proposals.read_bytes().splitlines(keepends=True)
    proposals.write_bytes(b"".join([*lines[:2], lines[1], *lines[2:]]))  # a copied line
    before = snapshot(family.path)
    commands = (["audit", "--noise-seeds", "2", "--seeds", "2", "--campaign"], ["random", "--budget-from"])
    for command in commands:
        done = subprocess.run([*CLI, *command, str(campaign)], capture_output=True, text=True)
        assert done.returncode == 2, done.stderr
        assert "proposals.jsonl:3: iteration 2 again" in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
    assert snapshot(family.path) == before  # nothing measured, nothing promoted
    assert not (campaign / "audit.json").exists()
