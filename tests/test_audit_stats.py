"""Each credibility equation (paper Sec. 3.4) against hand-computed cases."""

from __future__ import annotations

import math

import pytest
from scipy import stats as sps

from autoresearch.audit import stats
from autoresearch.audit.seeds import fresh_seeds

MIN, MAX = -1, +1  # sigma_dir of a minimized / maximized metric


def test_noise_floor_is_mean_and_bessel_sd():
    nf = stats.noise_floor([1.0, 2.0, 3.0, 4.0])
    assert nf.k == 4 and nf.mean == 2.5
    assert nf.std == pytest.approx(math.sqrt(5.0 / 3.0))  # (2.25+0.25+0.25+2.25)/3


@pytest.mark.parametrize("values", [[], [3.0]])
def test_noise_floor_enforces_k_at_least_two(values):
    with pytest.raises(ValueError, match="K >= 2"):
        stats.noise_floor(values)


def test_reseed_gate_boundary_passes_at_exactly_two_sigma():
    # minimize: mu0 = 10, sigma = 1, mu_R = 8 -> sigma_dir (mu_R - mu0) = 2 = 2 sigma.
    gate = stats.reseed_gate([7.5, 8.0, 8.5], [True] * 3, mu0=10.0, sigma=1.0, sign=MIN)
    assert gate.passed and gate.margin == 2.0 and gate.mu_r == 8.0 and gate.sigma_r == 0.5 and gate.n == 3


def test_reseed_gate_fails_on_margin_feasibility_and_too_few_reseeds():
    short = stats.reseed_gate([8.5, 8.1], [True, True], mu0=10.0, sigma=1.0, sign=MIN)
    assert not short.passed and short.margin == pytest.approx(1.7) and "m = 1.70 < 2" in short.reason
    unsafe = stats.reseed_gate([5.0, 5.0, 5.0], [True, False, True], mu0=10.0, sigma=1.0, sign=MIN)
    assert unsafe.margin == 5.0 and not unsafe.passed and "infeasible on 1 of 3" in unsafe.reason
    single = stats.reseed_gate([5.0], [True], mu0=10.0, sigma=1.0, sign=MIN)
    assert not single.passed and single.sigma_r is None and "need >= 2" in single.reason


def test_reseed_gate_is_oriented_for_maximized_metrics():
    gate = stats.reseed_gate([0.9, 0.9], [True, True], mu0=0.5, sigma=0.1, sign=MAX)
    assert gate.passed and gate.margin == pytest.approx(4.0)
    worse = stats.reseed_gate([0.1, 0.1], [True, True], mu0=0.5, sigma=0.1, sign=MAX)
    assert not worse.passed and worse.margin == pytest.approx(-4.0)


def test_zero_noise_is_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="sigma must be a positive number"):
        stats.reseed_gate([1.0, 1.0], [True, True], mu0=2.0, sigma=0.0, sign=MIN)


@pytest.mark.parametrize("sign", [MIN, MAX])
def test_welch_ci_matches_scipy_ttest_ind(sign):
    reseeds = [0.101, 0.095, 0.110, 0.099, 0.104]
    noise = [4.1, 3.8, 4.3, 4.0, 3.7, 4.2, 4.4]
    r, n = sps.describe(reseeds), sps.describe(noise)
    d = stats.mean_difference_ci(r.mean, math.sqrt(r.variance), 5, n.mean, math.sqrt(n.variance), 7, sign)
    ci = sps.ttest_ind(reseeds, noise, equal_var=False).confidence_interval(0.95)
    low, high = sorted((sign * ci.low, sign * ci.high))
    assert d.diff == pytest.approx(sign * (r.mean - n.mean))
    assert (d.low, d.high) == (pytest.approx(low), pytest.approx(high))


def test_welch_ci_needs_two_values_per_side():
    with pytest.raises(ValueError, match=">= 2 values per side"):
        stats.mean_difference_ci(1.0, 0.0, 1, 2.0, 0.1, 10, MIN)


def test_reproducibility_bound_prefers_the_tight_candidate():
    # Paper's docking promotion: an erratic 0.61 +- 0.24 loses to a tight 0.50 +- 0.02.
    erratic = stats.reproducibility_bound(0.61, 0.24, 10, MIN)
    tight = stats.reproducibility_bound(0.50, 0.02, 10, MIN)
    assert tight > erratic
    # ... and a tight, slightly worse mean beats a lucky, erratic better one.
    assert stats.reproducibility_bound(0.101, 0.007, 10, MIN) > stats.reproducibility_bound(
        0.095, 0.05, 10, MIN
    )


def test_paired_loo_delta_is_the_mean_change_at_the_same_seeds():
    # Reverting costs 0.1 at seed a and 0.3 at seed b (minimized): -0.2, whatever each seed's level.
    assert stats.paired_loo_delta([1.1, 5.3], [1.0, 5.0], MIN) == pytest.approx(-0.2)
    assert stats.paired_loo_delta([1.1], [1.0], MAX) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="one full-configuration value per reverted probe"):
        stats.paired_loo_delta([1.0, 2.0], [1.0], MIN)


def test_loo_delta_is_oriented_change_from_reverting():
    # minimize, mu_R = 1.0: reverting to 3.0 hurts -> Delta = -2 (load-bearing).
    assert stats.loo_delta([3.0], 1.0, MIN) == -2.0
    assert stats.loo_delta([0.5, 0.7], 1.0, MIN) == pytest.approx(0.4)  # two-seed mean


@pytest.mark.parametrize(
    ("delta1", "delta2", "expected"),
    [
        (-1.0, None, stats.KEEP),  # one seed suffices at exactly -sigma
        (-3.0, None, stats.KEEP),
        (-0.99, None, stats.ESCALATE),  # inconclusive: escalate to two seeds
        (0.8, None, stats.ESCALATE),
        (-0.5, 0.3, stats.DROP),  # hitchhiker
        (0.2, -0.49, stats.DROP),
        (0.2, 0.3, stats.DROP),  # the overlap: |D2| < 0.5 sigma and D2 > 0 -> plain drop
        (0.2, 0.5, stats.DROP_DAGGER),  # reverting helps by half a sigma or more: flagged
        (0.9, 2.0, stats.DROP_DAGGER),
        (-0.6, -0.5, stats.KEEP_BORDERLINE),  # borderline keep, upper edge included
        (-0.9, -0.75, stats.KEEP_BORDERLINE),
        (-0.8, -1.0, stats.KEEP),  # the gap: load-bearing, visible only at two seeds
        (0.0, -2.5, stats.KEEP),
    ],
)
def test_loo_decision_cases(delta1, delta2, expected):
    assert stats.loo_decision(delta1, 1.0, delta2) == expected


def test_loo_decision_scales_with_sigma():
    assert stats.loo_decision(-0.2, 0.2) == stats.KEEP
    assert stats.loo_decision(-0.1, 0.2, -0.1) == stats.KEEP_BORDERLINE


def test_prune_publish_requires_gate_and_retained_target():
    # minimize; the full recipe's reseeded mean is 1.0.
    assert stats.prune_publish(True, 2.0, 1.0, target=3.0, sign=MIN) == (True, True)
    # Clears the gate but loses the target the full recipe reached (the joint-group case).
    assert stats.prune_publish(True, 2.0, 1.0, target=1.5, sign=MIN) == (False, False)
    # The full recipe missed the target too: nothing to retain.
    assert stats.prune_publish(True, 2.0, 1.0, target=0.5, sign=MIN) == (True, True)
    assert stats.prune_publish(True, 2.0, 1.0, target=None, sign=MIN) == (True, True)
    # Fails the gate: never published, whatever the target.
    assert stats.prune_publish(False, 2.0, 1.0, target=None, sign=MIN) == (False, True)


@pytest.mark.parametrize(
    ("b_agent", "b_random", "expected", "units"),
    [
        (0.094, 0.635, stats.AGENT_WINS, 0.541 / 0.26),
        (1.0, 2.0, stats.AGENT_WINS, 1.0 / 0.26),
        (2.0, 1.9, stats.TIE, -0.1 / 0.26),
        (2.0, 1.0, stats.RANDOM_WINS, -1.0 / 0.26),
        (0.5, None, stats.AGENT_WINS, None),  # random never feasible: categorical
        (None, 0.5, stats.RANDOM_WINS, None),
        (None, None, stats.TIE, None),
    ],
)
def test_random_verdict_in_noise_units(b_agent, b_random, expected, units):
    verdict, got = stats.random_verdict(b_agent, b_random, sigma=0.26, sign=MIN)
    assert verdict == expected
    assert got == (None if units is None else pytest.approx(units))


def test_random_verdict_two_sigma_is_a_tie():
    assert stats.random_verdict(3.0, 1.0, sigma=1.0, sign=MAX) == (stats.TIE, 2.0)


def test_parity_guard_drops_a_reseed_above_twice_its_source_loss():
    assert stats.parity_guard(0.20, 0.10)  # exactly twice: still valid
    assert not stats.parity_guard(0.2001, 0.10)
    assert stats.parity_guard(0.05, 0.10)
    assert stats.parity_guard(None, 0.10) and stats.parity_guard(0.5, None)  # nothing to compare
    assert stats.parity_guard(5.0, -1.0)  # "twice" is meaningless for a non-positive loss


def test_fresh_seeds_are_disjoint_smallest_and_deterministic():
    used = {0, 1, 2, 5, 7}
    seeds = fresh_seeds(used, 4)
    assert seeds == [3, 4, 6, 8] and not used & set(seeds)
    assert fresh_seeds(used, 4) == seeds
    assert fresh_seeds([], 3) == [0, 1, 2]
    with pytest.raises(ValueError, match="n >= 1"):
        fresh_seeds(used, 0)
