"""The credibility layer's statistics (paper Sec. 3.4), one pure function per equation.

Every claim is denominated in the family's measured seed noise ``sigma``. ``sign`` is the
family's sigma_dir: +1 when the metric is maximized, -1 when it is minimized, so that an
oriented difference ``sign * (a - b)`` is positive when ``a`` is better than ``b``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from autoresearch.verdicts import reaches_target

# Eq. loodecision labels; "escalate" is the intermediate state of the one-seed probe.
KEEP = "keep"
KEEP_BORDERLINE = "keep-borderline"
DROP = "drop"
DROP_DAGGER = "drop-dagger"
ESCALATE = "escalate"
DROPPED = (DROP, DROP_DAGGER)


@dataclass(frozen=True)
class NoiseFloor:
    """Eq. noisefloor: the baseline's sample mean and Bessel-corrected sd over K seeds."""

    mean: float
    std: float
    k: int


def mean_sd(values: Sequence[float]) -> tuple[float, float | None]:
    """The sample mean and the Bessel-corrected sd (None for one value) of finite values. Where the
    plain sums overflow although the values are finite (1e160 apart squares to infinity) they are
    computed again on the values scaled by their largest magnitude; otherwise the plain result
    stands, to the last bit. ValueError when a statistic itself lies beyond a float (values near
    1.8e308 of both signs): it is refused, never written."""
    x = np.asarray(values, dtype=float)
    if not np.isfinite(x).all():
        raise ValueError(f"statistics of non-finite values: {list(values)!r}")

    def plain(x: np.ndarray) -> tuple[float, float | None]:
        with np.errstate(over="ignore", invalid="ignore"):
            return float(x.mean()), float(x.std(ddof=1)) if len(x) >= 2 else None

    def finite(mean: float, sd: float | None) -> bool:
        return math.isfinite(mean) and (sd is None or math.isfinite(sd))

    mean, sd = plain(x)
    if finite(mean, sd):
        return mean, sd
    scale = float(np.max(np.abs(x)))
    mean, sd = plain(x / scale)
    mean, sd = mean * scale, None if sd is None else sd * scale
    if not finite(mean, sd):
        raise ValueError(
            f"the mean or the spread of {len(x)} values up to {scale:.3g} in magnitude is too large for a "
            "float: rescale the metric"
        )
    return mean, sd


def noise_floor(values: Sequence[float]) -> NoiseFloor:
    """Eq. noisefloor. K >= 2 is enforced: one seed has no spread to measure."""
    k = len(values)
    if k < 2:
        raise ValueError(f"seed noise needs K >= 2 seeds (got K={k}): one run has no spread to measure")
    mean, sd = mean_sd(values)
    return NoiseFloor(mean=mean, std=sd, k=k)


def _require_noise(sigma: float) -> None:
    # A zero (or missing) sigma would make every margin infinite or undefined.
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(
            f"seed noise sigma must be a positive number (got {sigma!r}); "
            "measure it with `autoresearch noise` over K >= 2 seeds"
        )


def parity_guard(best_train_loss: float | None, source_train_loss: float | None) -> bool:
    """The train-loss parity guard: a reseed is valid unless its best training loss exceeds twice
    its source run's (a seed throttled by resource contention must not pollute mu_R).

    Without both losses, or with a non-positive source loss (where "twice" stops meaning worse),
    the guard cannot judge and keeps the reseed.
    """
    if best_train_loss is None or source_train_loss is None or source_train_loss <= 0:
        return True
    return best_train_loss <= 2 * source_train_loss


@dataclass(frozen=True)
class Gate:
    """Eq. reseedgate over the valid reseeds S_R."""

    mu_r: float
    sigma_r: float | None  # None when fewer than two valid reseeds
    n: int
    margin: float  # m = sigma_dir (mu_R - mu_0) / sigma
    all_feasible: bool
    passed: bool
    reason: str


def reseed_gate(
    values: Sequence[float], feasible: Sequence[bool], mu0: float, sigma: float, sign: int
) -> Gate:
    """Eq. reseedgate: accept iff m >= 2 and the configuration is feasible on every reseed.

    Our one addition: at least two valid reseeds, since sigma_R is reported with mu_R and one
    reseed would be the single-seed claim the gate exists to replace.
    """
    _require_noise(sigma)
    if len(values) != len(feasible):
        raise ValueError("reseed_gate: one feasibility flag per reseed value is required")
    n = len(values)
    if n == 0:
        raise ValueError("reseed_gate: no valid reseeds")
    mu_r, sigma_r = mean_sd(values)
    margin = sign * (mu_r - mu0) / sigma
    all_feasible = all(feasible)
    failures = []
    if n < 2:
        failures.append(f"only {n} valid reseed (need >= 2)")
    if sign * (mu_r - mu0) < 2 * sigma:  # the equation's own form: no rounding through m
        failures.append(f"margin m = {margin:.2f} < 2")
    if not all_feasible:
        failures.append(f"infeasible on {sum(not f for f in feasible)} of {n} reseeds")
    return Gate(mu_r, sigma_r, n, margin, all_feasible, not failures, "; ".join(failures) or "PASS")


@dataclass(frozen=True)
class Difference:
    """The oriented mean difference sigma_dir (mu_R - mu_0) with its Welch confidence interval."""

    diff: float
    low: float
    high: float
    confidence: float


def mean_difference_ci(
    mean_r: float,
    sd_r: float,
    n_r: int,
    mean_0: float,
    sd_0: float,
    n_0: int,
    sign: int,
    confidence: float = 0.95,
) -> Difference:
    """Welch's CI for sigma_dir (mu_R - mu_0) from summary statistics.

    Identical to ``scipy.stats.ttest_ind(r, noise, equal_var=False).confidence_interval()``
    (tested), but computable from the (mean, std, k) that family.json stores for the noise.
    Positive means the reseeded configuration is better than the baseline.
    """
    if n_r < 2 or n_0 < 2:
        raise ValueError(f"Welch CI needs >= 2 values per side (got {n_r} reseeds, {n_0} noise seeds)")
    v_r, v_0 = sd_r**2 / n_r, sd_0**2 / n_0
    se = math.sqrt(v_r + v_0)
    diff = sign * (mean_r - mean_0)
    if se == 0:
        return Difference(diff, diff, diff, confidence)
    dof = (v_r + v_0) ** 2 / (v_r**2 / (n_r - 1) + v_0**2 / (n_0 - 1))
    half = float(stats.t.ppf(0.5 + confidence / 2, dof)) * se
    return Difference(diff, diff - half, diff + half, confidence)


def reproducibility_bound(mean: float, sd: float, n: int, sign: int, confidence: float = 0.95) -> float:
    """The pessimistic end of the two-sided CI of a reseeded mean, oriented (higher is better).

    The promotion rule ranks passing candidates by it: a slightly worse but tight mean beats a
    lucky, erratic one (the paper's width-512-over-640 and 256-over-128 promotions).
    """
    if n < 2:
        raise ValueError(f"a reproducibility bound needs >= 2 reseeds (got {n})")
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * sd / math.sqrt(n)
    return sign * mean - half


def loo_delta(values: Sequence[float], mu_r: float, sign: int) -> float:
    """Eq. loo: Delta_i = sigma_dir (f(theta_-i) - mu_R), f averaged over the probe seeds given."""
    return sign * (float(np.mean(values)) - mu_r)


def paired_loo_delta(reverted: Sequence[float], full: Sequence[float], sign: int) -> float:
    """The paired form of Eq. loo: sigma_dir (f(theta_-i; s) - f(theta; s)) averaged over the probe
    seeds s, the full configuration run at the same seeds (common random numbers), so the seed's
    own luck cancels instead of deciding; used with Eq. loodecision's thresholds unchanged."""
    if len(reverted) != len(full) or not reverted:
        raise ValueError("paired_loo_delta: one full-configuration value per reverted probe is required")
    return sign * float(np.mean(np.asarray(reverted, dtype=float) - np.asarray(full, dtype=float)))


def loo_decision(delta1: float, sigma: float, delta2: float | None = None) -> str:
    """Eq. loodecision with one-seed then two-seed escalation.

    Cases are checked in the order the equation writes them, which resolves its overlap and
    its gap explicitly:

    1. keep            Delta1 <= -sigma                 (one seed suffices: clearly load-bearing)
       escalate        otherwise, while Delta2 is unknown
    2. drop            |Delta2| < 0.5 sigma             (hitchhiker; wins the overlap with 3, so
                                                         0 < Delta2 < 0.5 sigma is a plain drop:
                                                         a sub-half-sigma gain is not a signal)
    3. drop-dagger     Delta2 >= 0.5 sigma              (reverting helps beyond noise: flagged)
    4. keep-borderline -sigma < Delta2 <= -0.5 sigma    (kept conservatively)
    5. keep            Delta2 <= -sigma                 (the equation's gap: load-bearing, seen
                                                         only at two seeds)
    """
    _require_noise(sigma)
    if delta1 <= -sigma:
        return KEEP
    if delta2 is None:
        return ESCALATE
    if abs(delta2) < 0.5 * sigma:
        return DROP
    if delta2 > 0:
        return DROP_DAGGER
    if delta2 > -sigma:
        return KEEP_BORDERLINE
    return KEEP


def prune_publish(
    passed_gate: bool, pruned_mean: float, full_mean: float, target: float | None, sign: int
) -> tuple[bool, bool]:
    """Eq. prunereverify: publish the pruned recipe iff its re-verification clears the same gate
    (margin and all-seeds feasibility: ``passed_gate``) and the target is retained.

    "Retained" means: if the full configuration's reseeded mean reached the target (Eq. stop's
    rho), the pruned recipe's must too; with no target, or one the full recipe missed, there is
    nothing to lose. Returns (publish, target_retained).
    """
    retained = not reaches_target(full_mean, target, sign) or reaches_target(pruned_mean, target, sign)
    return passed_gate and retained, retained


AGENT_WINS = "agent wins"
RANDOM_WINS = "random wins"
TIE = "tie"


def random_verdict(
    b_agent: float | None, b_random: float | None, sigma: float, sign: int
) -> tuple[str, float | None]:
    """Eq. verdict in noise units: (verdict, sigma_dir (b_agent - b_random) / sigma).

    The paper's "LLM wins" reads "agent wins" here (the campaign's proposer need not be an
    LLM). A side with no feasible run has no best: the other side wins categorically (the
    docking case, where random search never produced a feasible policy); neither: a tie.
    """
    _require_noise(sigma)
    if b_agent is None or b_random is None:
        if b_agent is None and b_random is None:
            return TIE, None
        return (RANDOM_WINS if b_agent is None else AGENT_WINS), None
    units = sign * (b_agent - b_random) / sigma
    if units > 2:
        return AGENT_WINS, units
    if units < -2:
        return RANDOM_WINS, units
    return TIE, units
