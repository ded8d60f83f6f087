"""The statistics of ``autoresearch compare`` against hand-computed cases and scipy."""

import math

import numpy as np
import pytest
from scipy import stats

from autoresearch.compare import stats as compare

INF = math.inf


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_iqm_is_the_mean_of_the_middle_half():
    assert compare.iqm(np.arange(1, 9)) == 4.5  # [3, 4, 5, 6]
    assert compare.iqm(np.arange(1, 11)) == 5.5  # int(10/4) = 2 cut from each end: [3..8]
    assert compare.iqm(np.array([100.0, 1, 2, 3, 4, 5, 6, -100])) == 3.5  # the tails do not matter
    assert compare.iqm(np.array([5.0, 5, 2, INF])) == 5.0  # a repeat with no feasible run is trimmed first


def test_best_so_far_counts_only_feasible_runs_and_holds_the_final_best():
    metrics = [3.0, math.nan, 2.0, 1.0, 0.5]
    feasible = [True, False, False, True, True]  # a failed run, an infeasible 2.0
    assert compare.best_so_far(metrics, feasible, -1, 7).tolist() == [3, 3, 3, 1, 0.5, 0.5, 0.5]
    assert compare.best_so_far(metrics, feasible, +1, 3).tolist() == [3, 3, 3]
    assert compare.best_so_far([1.0], [False], -1, 2).tolist() == [INF, INF]  # worst for a minimized metric
    assert compare.best_so_far([1.0], [False], +1, 2).tolist() == [-INF, -INF]
    assert compare.best_so_far([], [], -1, 2).tolist() == [INF, INF]


def test_best_at_wall_clock_times():
    curve = compare.best_so_far([3.0, 1.0], [True, True], -1, 2)
    grid = np.array([0.0, 1.0, 1.5, 2.0, 9.0])
    assert compare.best_at_times(curve, [1.0, 2.0], grid, -1).tolist() == [INF, 3, 3, 1, 1]
    assert compare.best_at_times(np.array([]), [], grid[:2], +1).tolist() == [-INF, -INF]  # nothing ran


@pytest.mark.parametrize(
    ("x", "y", "direction", "expected"),
    [
        ([1, 2, 3], [0], +1, 1.0),
        ([1, 2, 3], [0], -1, 0.0),
        ([1, 2, 3], [2, 2], +1, 0.5),  # 2 wins, 2 ties, 2 losses of 6 pairs
        ([1, 1], [1, 2], +1, 0.25),  # pairs: tie, loss, tie, loss
        ([1, 1], [1, 2], -1, 0.75),  # pairs: tie, win, tie, win
        ([INF], [5], -1, 0.0),  # no feasible run loses to any feasible one
        ([INF, 1], [INF], -1, 0.75),  # and ties with another such repeat
        ([3, 1, 2], [2.5, 0.5], -1, 2 / 6),  # only 1 and 2 beat 2.5
    ],
)
def test_probability_of_improvement_by_hand(x, y, direction, expected):
    assert compare.probability_of_improvement(x, y, direction) == pytest.approx(expected)
    assert compare.probability_of_improvement(y, x, direction) == pytest.approx(1 - expected)


def test_improvement_interval_is_a_stratified_bootstrap():
    low, high = compare.improvement_interval([1, 2, 3], [10, 11, 12], -1, rng())
    assert (low, high) == (1.0, 1.0)  # every resample of each arm keeps the arms apart
    low, high = compare.improvement_interval([1, 2, 3, 4], [2, 3, 4, 5], +1, rng())
    assert 0 <= low < compare.probability_of_improvement([1, 2, 3, 4], [2, 3, 4, 5], +1) < high <= 1
    # An arm of one repeat is held fixed; the other still varies. Two single repeats: no interval.
    low, high = compare.improvement_interval([5], [1, 2, 3, 9], +1, rng())
    assert 0 < low <= 0.75 <= high == 1.0
    assert all(math.isnan(v) for v in compare.improvement_interval([5], [1], +1, rng()))


def test_location_band_is_scipys_percentile_bootstrap_over_repeats():
    matrix = rng(1).normal(size=(12, 4))
    point, low, high = compare.location_band(matrix, compare.iqm, rng(7), n_resamples=999)
    expected = stats.bootstrap(
        (matrix,), compare.iqm, n_resamples=999, axis=0, method="percentile", rng=rng(7)
    ).confidence_interval
    np.testing.assert_allclose(point, compare.iqm(matrix))
    np.testing.assert_allclose(low, expected.low)
    np.testing.assert_allclose(high, expected.high)


def test_location_band_with_repeats_without_a_feasible_run():
    matrix = np.array([[INF, 5.0], [INF, 3.0], [INF, INF], [INF, 2.0]])
    point, low, high = compare.location_band(matrix, compare.median, rng(), n_resamples=999)
    assert point.tolist() == [INF, 4.0]
    assert low[0] == high[0] == INF  # nobody feasible yet: no finite bound
    assert 2.0 <= low[1] <= 4.0 and high[1] == INF  # a resample can hold mostly the infeasible repeat
    single = compare.location_band(np.array([[1.0, 2.0]]), compare.iqm, rng())
    assert np.isnan(single[1]).all() and np.isnan(single[2]).all()


def test_experiments_to_target_with_censoring():
    matrix = np.array([[5.0, 3, 1], [5, 5, 5], [2, 2, 2]])
    hits = compare.experiments_to_target(matrix, 2.0, -1)
    assert hits == [3, None, 1]
    assert compare.median_experiments_to_target(hits) == 3  # [1, 3, never]
    assert compare.median_experiments_to_target([3, None, None]) == INF  # reported as ">budget"
    assert compare.median_experiments_to_target([2, 4]) == 3
    assert compare.experiments_to_target(np.array([[-INF, 1.0, 7.0]]), 7.0, +1) == [3]  # maximized


def test_fraction_reaching_the_target_with_a_wilson_interval():
    k, n, low, high = compare.fraction_reaching(np.array([0.01, 0.2, INF, 0.05]), 0.05, -1)
    assert (k, n) == (2, 4)
    ci = stats.binomtest(2, 4).proportion_ci(method="wilson")
    assert (low, high) == pytest.approx((ci.low, ci.high))


def test_profile_and_noise_units_are_oriented():
    finals = np.array([0.1, 0.3, INF])
    assert compare.profile(finals, np.array([0.2, 0.3]), -1).mean(axis=0).tolist() == pytest.approx(
        [1 / 3, 2 / 3]
    )
    assert compare.profile(finals[:2], np.array([0.2]), +1).mean(axis=0).tolist() == [0.5]
    assert compare.noise_units(0.8, 1.0, 0.1, -1) == pytest.approx(2.0)  # lower loss: better
    assert compare.noise_units(0.8, 1.0, 0.1, +1) == pytest.approx(-2.0)


def test_improvement_table_is_consistent_both_ways():
    finals = {"a": np.array([1.0, 2, 3]), "b": np.array([2.0, 3, 4]), "c": np.array([INF, INF])}
    table = compare.improvement_table(finals, -1, rng(), n_resamples=500)
    p, low, high = table["a", "b"]
    assert p == pytest.approx(compare.probability_of_improvement(finals["a"], finals["b"], -1))
    assert table["b", "a"] == pytest.approx((1 - p, 1 - high, 1 - low))
    assert table["a", "c"] == (1.0, 1.0, 1.0)


def test_stratified_bootstrap_interval_covers_the_true_iqm():
    """40 simulated arms of 30 repeats from Exp(1); the 95% interval should hold the population IQM."""
    q1, q3 = -math.log(0.75), math.log(4.0)
    true_iqm = ((q1 + 1) * math.exp(-q1) - (q3 + 1) * math.exp(-q3)) / 0.5  # E[X | q1 < X < q3]
    gen, covered = rng(2024), 0
    for _ in range(40):
        sample = gen.exponential(size=(30, 1))
        _, low, high = compare.location_band(sample, compare.iqm, gen, n_resamples=1000)
        covered += bool(low[0] <= true_iqm <= high[0])
    assert covered >= 34, covered  # >= 85%
