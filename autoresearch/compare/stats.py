"""Statistics for scoring an arm over many campaigns (``autoresearch compare``), as pure functions.

An arm is N independent campaigns (repeats) of one proposer. Each repeat gives a best-so-far curve over
its experiments; stacked, an arm's curves are an (N, B) matrix for a budget of B experiments. The
aggregates follow Agarwal et al. (2021, "Deep RL at the edge of the statistical precipice", the rliable
library): median and interquartile mean (IQM) across repeats with 95 % percentile-bootstrap intervals that
resample repeats within each arm (the stratified bootstrap, via ``scipy.stats.bootstrap``), and the
probability of improvement P(X > Y) = U / (n m) from the Mann-Whitney U statistic, ties counting 1/2.

Values stay in raw metric units; ``direction`` is sigma_dir (+1: larger is better, -1: smaller is), so
``direction * (a - b) > 0`` means a is better. A repeat that has no feasible run yet has the best-so-far
:func:`worst` (an infinity on the bad side): it ranks below every feasible value and never reaches a target.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 5000
Statistic = Callable[..., np.ndarray]


def worst(direction: int) -> float:
    """The best-so-far of a repeat with no feasible run: worse than any value."""
    return -direction * math.inf


def best_so_far(
    metrics: Sequence[float], feasible: Sequence[bool], direction: int, budget: int
) -> np.ndarray:
    """Best feasible metric after each of the first ``budget`` experiments (NaN metric: a failed run).

    A campaign that ended before ``budget`` experiments keeps its final best: the budget it left unused
    cannot change what it found.
    """
    m = np.asarray(metrics, dtype=float)[:budget]
    ok = np.asarray(feasible, dtype=bool)[:budget] & np.isfinite(m)
    oriented = np.full(budget, -math.inf)
    if len(m):
        oriented[: len(m)] = np.maximum.accumulate(np.where(ok, direction * m, -math.inf))
        oriented[len(m) :] = oriented[len(m) - 1]
    return direction * oriented


def best_at_times(curve: np.ndarray, times: Sequence[float], grid: np.ndarray, direction: int) -> np.ndarray:
    """The best-so-far ``curve`` (one value per experiment, finished at ``times``) at each time of ``grid``."""
    if not len(times):
        return np.full(len(grid), worst(direction))
    index = np.searchsorted(np.maximum.accumulate(np.asarray(times, dtype=float)), grid, side="right") - 1
    return np.where(index >= 0, np.asarray(curve)[np.clip(index, 0, None)], worst(direction))


def iqm(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50 % (``int(n/4)`` values cut from each end, as rliable)."""
    return stats.trim_mean(x, 0.25, axis=axis)


def median(x: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.median(x, axis=axis)


def interval(
    samples: Sequence[np.ndarray],
    statistic: Statistic,
    rng: np.random.Generator,
    n_resamples: int = RESAMPLES,
) -> tuple[np.ndarray, np.ndarray]:
    """The 95 % percentile-bootstrap interval of ``statistic(*samples, axis=0)``.

    Each sample (an arm's repeats, a stratum) is resampled on its own along axis 0, whole rows at a time
    (a repeat's whole curve). A sample of one repeat is held fixed, which is all resampling it could do;
    with no sample of two or more the interval is undefined (NaN).
    """
    samples = [np.asarray(s, dtype=float) for s in samples]
    varying = [i for i, s in enumerate(samples) if len(s) >= 2]
    shape = np.shape(statistic(*samples, axis=0))
    if not varying:
        return np.full(shape, np.nan), np.full(shape, np.nan)

    def resampled(*drawn: np.ndarray, axis: int) -> np.ndarray:
        full = list(samples)
        for i, d in zip(varying, drawn, strict=True):
            full[i] = d
        # scipy moves the resampled axis last; a fixed sample must broadcast against it.
        full = [f if i in varying else np.moveaxis(f, 0, -1)[..., None, :] for i, f in enumerate(full)]
        return statistic(*full, axis=axis)

    result = stats.bootstrap(
        [samples[i] for i in varying],
        resampled,
        n_resamples=n_resamples,
        vectorized=True,
        axis=0,
        confidence_level=CONFIDENCE,
        method="percentile",
        rng=rng,
    )
    return result.confidence_interval.low, result.confidence_interval.high


def location_band(
    matrix: np.ndarray, statistic: Statistic, rng: np.random.Generator, n_resamples: int = RESAMPLES
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point, low, high) of a location statistic (median, IQM) of each column of ``matrix`` (repeats x budgets).

    scipy's bootstrap cannot take infinities, so a repeat with no feasible run enters it as a finite
    stand-in far beyond every finite value; any bound the stand-in reaches is mapped back to infinity.
    Sound for statistics that are means of order statistics (median, IQM), which is all this is used for.
    """
    matrix = np.asarray(matrix, dtype=float)
    point = statistic(matrix, axis=0)
    finite = matrix[np.isfinite(matrix)]
    lo, hi = (finite.min(), finite.max()) if finite.size else (0.0, 0.0)
    margin = hi - lo + 1.0
    far = 1e9 * margin  # moves any statistic that averages in a stand-in by >> margin
    stand_in = np.where(matrix == math.inf, hi + far, np.where(matrix == -math.inf, lo - far, matrix))
    low, high = interval([stand_in], statistic, rng, n_resamples)

    def restore(bound: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):  # NaN: no interval
            return np.where(bound > hi + margin, math.inf, np.where(bound < lo - margin, -math.inf, bound))

    return point, restore(low), restore(high)


def probability_of_improvement(
    x: Sequence[float], y: Sequence[float], direction: int, axis: int = 0
) -> float:
    """P(X > Y): the probability that a repeat of arm X ends better than a repeat of arm Y.

    rliable's definition, U / (n m) with the Mann-Whitney U of X against Y, i.e. the fraction of pairs
    (x_i, y_j) with x_i better, ties counting 1/2. "Better" is oriented by ``direction``.
    """
    x, y = direction * np.asarray(x, dtype=float), direction * np.asarray(y, dtype=float)
    u = stats.mannwhitneyu(x, y, axis=axis, method="asymptotic").statistic
    return u / (x.shape[axis] * y.shape[axis])


def improvement_interval(
    x: Sequence[float],
    y: Sequence[float],
    direction: int,
    rng: np.random.Generator,
    n_resamples: int = RESAMPLES,
) -> tuple[float, float]:
    """95 % stratified-bootstrap interval of :func:`probability_of_improvement` (each arm resampled alone)."""

    def statistic(a: np.ndarray, b: np.ndarray, axis: int) -> np.ndarray:
        return probability_of_improvement(a, b, direction, axis=axis)

    low, high = interval([np.asarray(x, float), np.asarray(y, float)], statistic, rng, n_resamples)
    return float(low), float(high)


def reached(values: np.ndarray, target: float, direction: int) -> np.ndarray:
    """Elementwise: the value has reached the target (never, for a repeat with no feasible run)."""
    with np.errstate(invalid="ignore"):
        return direction * (np.asarray(values, dtype=float) - target) >= 0


def experiments_to_target(matrix: np.ndarray, target: float, direction: int) -> list[int | None]:
    """Per repeat, the number of experiments after which its best first reached the target; None if never."""
    hits = reached(matrix, target, direction)
    return [int(np.argmax(row)) + 1 if row.any() else None for row in hits]


def median_experiments_to_target(hits: Sequence[int | None]) -> float:
    """Median of :func:`experiments_to_target`, a repeat that never reached the target counting as infinite
    (right-censored at the budget); infinite when at least half never reached it."""
    return float(np.median([math.inf if h is None else h for h in hits]))


def fraction_reaching(
    finals: Sequence[float], target: float, direction: int
) -> tuple[int, int, float, float]:
    """(k, n, low, high): k of n repeats ended at or beyond the target, with the 95 % Wilson interval."""
    k, n = int(reached(finals, target, direction).sum()), len(finals)
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    return k, n, float(ci.low), float(ci.high)


def profile(finals: Sequence[float], thresholds: np.ndarray, direction: int) -> np.ndarray:
    """Indicator matrix (repeats x thresholds) of a performance profile: the repeat's final best is at or
    beyond each threshold (<= it for a minimized metric); its column means are the profile."""
    finals = np.asarray(finals, dtype=float)[:, None]
    with np.errstate(invalid="ignore"):
        return (direction * (finals - np.asarray(thresholds)[None, :]) >= 0).astype(float)


def noise_units(value: np.ndarray | float, reference: float, sigma: float, direction: int) -> np.ndarray:
    """direction (value - reference) / sigma: how many units of seed noise ``value`` is better than the
    reference (the baseline's mean), as the audit's m."""
    return direction * (np.asarray(value, dtype=float) - reference) / sigma


def summarize_arm(
    matrix: np.ndarray,
    direction: int,
    target: float | None,
    rng: np.random.Generator,
    n_resamples: int = RESAMPLES,
) -> dict[str, Any]:
    """One arm's numbers from its best-so-far matrix (repeats x budgets): median and IQM with their 95 %
    bands at every budget, the final bests (last column), and, with a target, the fraction of repeats
    reaching it and the experiments each needed."""
    summary: dict[str, Any] = {"n": len(matrix), "finals": matrix[:, -1]}
    for name, statistic in (("median", median), ("iqm", iqm)):
        summary[name] = dict(
            zip(("point", "low", "high"), location_band(matrix, statistic, rng, n_resamples), strict=True)
        )
    if target is not None:
        hits = experiments_to_target(matrix, target, direction)
        summary["reach"] = fraction_reaching(matrix[:, -1], target, direction)
        summary["to_target"] = hits
        summary["median_to_target"] = median_experiments_to_target(hits)
    return summary


def improvement_table(
    finals: dict[str, np.ndarray], direction: int, rng: np.random.Generator, n_resamples: int = RESAMPLES
) -> dict[tuple[str, str], tuple[float, float, float]]:
    """P(X > Y) with its 95 % interval for every ordered pair of arms (X, Y), from their final bests.
    Each unordered pair is bootstrapped once: P(Y > X) = 1 - P(X > Y), and so are its bounds."""
    table = {}
    names = list(finals)
    for i, x in enumerate(names):
        for y in names[i + 1 :]:
            p = float(probability_of_improvement(finals[x], finals[y], direction))
            low, high = improvement_interval(finals[x], finals[y], direction, rng, n_resamples)
            table[x, y] = (p, low, high)
            table[y, x] = (1 - p, 1 - high, 1 - low)
    return table
