"""The leave-one-out rules on a simulated family with known effects (autoresearch/audit/
rules_simulation.py: Gaussian seed noise, the audit's own decision functions, no training).
Each assertion has a margin of several standard errors at n = 1000 simulated audits."""

from __future__ import annotations

import pytest

from autoresearch.audit.rules_simulation import Scenario, rates, table

N = 1000
SHARED = Scenario("seed shares 90 % of the variance", 0.9, 1.0)
NOT_SHARED = Scenario("seed shares nothing", 0.0, 1.0)
NOISY_BASELINE = Scenario("baseline 50x noisier", 0.5, 50.0)


def test_pairing_keeps_fewer_hitchhikers_when_the_seed_is_shared():
    paper = rates(SHARED, paired=False, noise_at="baseline", n=N)
    paired = rates(SHARED, paired=True, noise_at="baseline", n=N)
    assert paired["hitch_kept"] < paper["hitch_kept"] - 0.15  # ~8 % against ~32 %
    assert paired["both_hitch_kept"] < paper["both_hitch_kept"] / 5  # no one seed keeps them all
    assert paired["load"] == paper["load"] == 0.0


def test_pairing_spreads_the_bad_seed_at_half_shared_variance():
    half = Scenario("seed shares half the variance", 0.5, 1.0)
    paper = rates(half, paired=False, noise_at="baseline", n=N)
    paired = rates(half, paired=True, noise_at="baseline", n=N)
    assert paired["both_hitch_kept"] < paper["both_hitch_kept"] - 0.04  # ~10 % against ~18 %


def test_pairing_costs_when_the_seed_shares_nothing():
    """A paired difference then has twice a run's variance: the paired rule keeps more
    hitchhikers, so its advantage is the shared part of the seed, not the pairing as such."""
    paper = rates(NOT_SHARED, paired=False, noise_at="baseline", n=N)
    paired = rates(NOT_SHARED, paired=True, noise_at="baseline", n=N)
    assert paired["hitch_kept"] > paper["hitch_kept"] + 0.04


def test_the_baseline_unit_drops_everything_when_the_baseline_is_much_noisier():
    for paired in (False, True):
        at_baseline = rates(NOISY_BASELINE, paired=paired, noise_at="baseline", n=N)
        at_candidate = rates(NOISY_BASELINE, paired=paired, noise_at="candidate", n=N)
        assert at_baseline["load"] == 1.0 and at_baseline["hitch_kept"] == 0.0
        assert at_candidate["load"] < 0.02 and at_candidate["hitch_kept"] > 0.2


@pytest.mark.parametrize("paired", [False, True])
def test_the_candidate_unit_changes_nothing_when_the_noise_is_the_same(paired):
    same = Scenario("same noise", 0.5, 1.0)
    a = rates(same, paired=paired, noise_at="baseline", n=N)
    b = rates(same, paired=paired, noise_at="candidate", n=N)
    assert abs(a["hitch_kept"] - b["hitch_kept"]) < 0.06 and abs(a["border"] - b["border"]) < 0.06


def test_the_simulation_is_seeded():
    assert rates(SHARED, True, "candidate", n=50, seed=3) == rates(SHARED, True, "candidate", n=50, seed=3)
    assert table(n=5).count("\n") == 2 + 4 * 4 - 1
