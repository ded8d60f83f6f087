"""Issue 28, item 5: the third family, families/docking-constrained, follows the family contract.

Its data are the docking family's sizes (1,536 constrained expert solves, tens of minutes to build),
so the end-to-end evidence is the committed campaign (results/docking-constrained); these tests
hold the contract and the family's scoring on real flights without building any data.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from autoresearch.family import Family, family_problems
from cwh_envs.datasets import start_pool

ROOT = Path(__file__).resolve().parents[1]
FAMILY = ROOT / "families" / "docking-constrained"


def test_the_family_passes_the_contract_check():
    assert family_problems(FAMILY) == []
    family = Family.load(FAMILY)
    assert family.name == "docking-constrained" and family.has_test_split
    assert family.baseline_config["RECOVERY_AUGMENT_FRAC"] == 0.0  # the docking family's editable block


@pytest.mark.needs("families")
def test_prepare_check_names_the_missing_sets_and_builds_nothing(tmp_path):
    cache = tmp_path / "cache"
    env = {**os.environ, "CWH_ENVS_CACHE": str(cache), "OMP_NUM_THREADS": "1"}
    cold = subprocess.run(
        [sys.executable, "prepare.py", "--check"],
        cwd=FAMILY,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert cold.returncode != 0
    named = ("training pool", "recovery pool", "search split", "test split", "missing")
    assert all(part in cold.stderr for part in named)
    assert not cache.exists() or not any(cache.iterdir())


@pytest.fixture(scope="module")
def train():
    spec = importlib.util.spec_from_file_location("train_constrained_under_test", FAMILY / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.needs("families")
def test_the_score_counts_every_constraint_and_the_gate_covers_them(train):
    pool = start_pool("docking", 6, train.PROBLEM)
    config = {name: getattr(train, name) for name in train.CONFIG_NAMES}
    torch_policy = train.build_policy(config)  # an untrained network: it drifts, and breaks things
    flight = train.fly(torch_policy, pool.starts, pool.goals, train.safety_filter(config))
    metrics = train.docking_metrics(flight, flight.thrust)
    rates = metrics["violation_rates"]
    expected = (
        flight.terminal_distance.mean()
        + train.VIOLATION_WEIGHT
        * (flight.violation_rate + flight.speed_violation_rate + flight.cone_violation_rate).mean()
    )
    assert metrics[train.METRIC] == pytest.approx(expected, rel=1e-12)
    assert rates["keep_out"] == 0.0  # the filter keeps it first
    assert metrics["constraints"]["speed_violation_rate"] == rates["speed"]
    assert metrics["constraints"]["cone_violation_rate"] == rates["cone"]
    assert not metrics["strict_feasible"] and metrics["effort_ratio"] == pytest.approx(1.0)
    dispersed = train.dispersed_metrics(
        train.fly(torch_policy, pool.starts, pool.goals, train.safety_filter(config), train.DISPERSIONS),
        train.DISPERSIONS,
    )
    assert dispersed["dispersions"] == train.DISPERSIONS
    assert dispersed["mean_terminal_distance"] != metrics["mean_terminal_distance"]
    assert np.isfinite(dispersed["violation_rate"])
    # Per constraint: the starts breaking it as the score counts them, and how deep it went.
    assert set(dispersed["breaking_starts"]) == set(dispersed["deepest"]) == {"keep_out", "speed", "cone"}
    assert dispersed["violating_starts"] >= max(dispersed["breaking_starts"].values())
    assert all((dispersed["deepest"][k] > 0) >= (n > 0) for k, n in dispersed["breaking_starts"].items())


@pytest.mark.needs("families")
def test_the_robust_filter_lever_flies_the_robust_filter_and_the_protocol_limits_the_dispersed_share(train):
    from autoresearch.family import Family

    config = {name: getattr(train, name) for name in train.CONFIG_NAMES}
    assert train.safety_filter(config) == {"cbf_margin": train.PROBLEM.margin}
    assert train.safety_filter({**config, "RUNTIME_CBF_FILTER": False}) == {}
    robust = train.safety_filter({**config, "ROBUST_FILTER_K": 3.0})
    assert robust["cbf_bounds"].k_sigma == 3.0 and robust["cbf_bounds"].nav_position == 0.05
    pool = start_pool("docking", 3, train.PROBLEM)
    policy = train.build_policy({**config, "POLICY_FORM": "route"})  # the routed law: a zero correction
    flight = train.fly(policy, pool.starts, pool.goals, robust, train.DISPERSIONS)
    assert flight.cbf_margin_scale is not None  # the robust filter flew
    with pytest.raises(SystemExit, match="ROBUST_FILTER_K"):
        train.check_config({**config, "ROBUST_FILTER_K": -1.0})
    family = Family.load(FAMILY).under_protocol("robust")
    assert family.limits == {"dispersed_violating_share": 0.001}
    assert family.is_feasible({"strict_feasible": True, "dispersed_violating_share": 0.0})
    assert not family.is_feasible({"strict_feasible": True, "dispersed_violating_share": 1 / 128})
    # robust-fuel: issue 58's learned target as the gate, each clause able to fail the run alone.
    target = Family.load(FAMILY).under_protocol("robust-fuel")
    meets = {
        "strict_feasible": True,
        "dispersed_violating_share": 0.0,
        "dispersed_failure_share": 0.0,
        "dispersed_3sigma_failure_share": 1 / 128,
        "effort_ratio": 2.4,
    }
    assert target.is_feasible(meets)
    for field, miss in (
        ("dispersed_violating_share", 1 / 128),
        ("dispersed_failure_share", 1 / 128),
        ("dispersed_3sigma_failure_share", 2 / 128),
        ("effort_ratio", 2.6),
    ):
        assert not target.is_feasible({**meets, field: miss}), field
