"""Single-seed judgements in units of noise (paper Eqs. perrun and plateau), and which run of a
campaign is its best.

``direction`` is sigma_dir: +1 when larger metric values are better, -1 when smaller are, so
``direction * (a - b) > 0`` exactly when ``a`` is better than ``b``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Protocol, TypeVar

from autoresearch.splits import Score

CONFIRMED, REGRESSED, WITHIN_NOISE = "confirmed", "regressed", "within noise"


def noise_threshold(reference: float, sigma: float | None) -> float:
    """The measured seed noise when there is one, else 5 % of the reference value (at least 1e-12)."""
    if sigma is not None:
        return sigma
    return max(0.05 * abs(reference), 1e-12)


class Ranked(Protocol):
    """A run as the ranking sees it (a campaign's Record)."""

    iteration: int
    metric: float
    feasible: bool | None


R = TypeVar("R", bound=Ranked)


def ranking(direction: int) -> Callable[[Ranked], tuple[float, int]]:
    """The order of runs, best first: by the metric in ``direction``, the earliest iteration on ties."""
    return lambda run: (-direction * run.metric, run.iteration)


def best_feasible(runs: Iterable[R | None], direction: int) -> R | None:
    """The best feasible run of ``runs`` (a campaign's single-seed best), the earliest on ties."""
    return min((r for r in runs if r is not None and r.feasible), key=ranking(direction), default=None)


def is_better(a: float, b: float | None, direction: int) -> bool:
    return b is None or direction * (a - b) > 0


def reaches_target(best: float | None, target: float | None, direction: int) -> bool:
    """rho_t: the running best has reached the target."""
    return best is not None and target is not None and direction * (best - target) >= 0


def verdict(metric: float, prior_best: float, direction: int, sigma: float | None) -> str:
    """Eq. perrun: confirmed / regressed / within noise relative to the prior best."""
    threshold = noise_threshold(prior_best, sigma)
    delta = direction * (metric - prior_best)
    if delta >= threshold:
        return CONFIRMED
    if delta <= -threshold:
        return REGRESSED
    return WITHIN_NOISE


def judged_against(seed_noise: dict | None, prior_best: float) -> dict:
    """The noise unit a run's Eq. perrun verdict was judged against, as its record names it: the
    measured seed noise (its sigma, K and when it was measured), or, with none measured yet, 5 % of
    the prior best (``measured_at`` null). A later verdict against newer noise may differ."""
    if seed_noise:
        return {
            "sigma": seed_noise["std"],
            "k": seed_noise.get("k"),
            "measured_at": seed_noise.get("measured_at"),
        }
    return {"sigma": noise_threshold(prior_best, None), "k": None, "measured_at": None}


def run_verdict(
    metric: float, *, feasible: bool, is_baseline: bool, prior_best: float | None, direction: int, sigma
) -> str:
    """The verdict recorded for a run that ran: baseline, infeasible, no prior best, or Eq. perrun."""
    if is_baseline:
        return "baseline"
    if not feasible:
        return "infeasible"
    if prior_best is None:
        return "no prior best"
    return verdict(metric, prior_best, direction, sigma)


def plateau(runs: Sequence[Score], direction: int, window: int, kappa: float, sigma: float | None) -> bool:
    """Eq. plateau over the scores of successful runs, oldest first.

    True when none of the last ``window`` runs beats the best feasible run before the window by
    ``kappa`` noise units. An infeasible run cannot beat anything. Without ``window`` runs and a
    feasible run before them the predicate is false.
    """
    if window < 1 or len(runs) <= window:
        return False
    before = [s.metric for s in runs[:-window] if s.feasible]
    if not before:
        return False
    b_pre = max(before, key=lambda m: direction * m)
    margin = kappa * noise_threshold(b_pre, sigma)
    return all(not s.feasible or direction * (s.metric - b_pre) < margin for s in runs[-window:])
