"""The numbers of a comparison of arms over their repeats, before anything is written: each arm's
best so far over a common budget, its summary, the pairwise probabilities of improvement, and notes
on repeats that ended early or have not run."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from autoresearch.compare import stats as compare
from autoresearch.compare.inputs import CompareError, RepeatedArm, common_family, noise_reference
from autoresearch.direction import Direction

BUDGET_TRIGGERS = ("max_iters", "max_runs", "wall_clock", "max_cost")


@dataclass(frozen=True)
class Analysis:
    family: dict[str, Any]
    direction: int
    budget: int
    noise: dict[str, Any] | None
    arms: list[RepeatedArm]
    summaries: dict[str, dict[str, Any]]
    improvement: dict[tuple[str, str], tuple[float, float, float]]
    notes: list[str]


def analyse(
    arms: list[RepeatedArm],
    budget: int | None = None,
    sigma: float | None = None,
    seed: int = 0,
    n_resamples: int = compare.RESAMPLES,
) -> Analysis:
    family = common_family(arms)
    direction = Direction.of(family["direction"])
    longest = max(r.n for arm in arms for r in arm.repeats)
    if longest == 0:
        raise CompareError("no campaign has run an experiment yet")
    budget = min(budget or longest, longest)
    rng = np.random.default_rng(seed)
    matrices = {
        arm.name: np.array(
            [compare.best_so_far(r.metrics, r.feasible, direction, budget) for r in arm.repeats]
        )
        for arm in arms
    }
    summaries = {
        name: compare.summarize_arm(m, direction, family["target"], rng, n_resamples)
        for name, m in matrices.items()
    }
    finals = {name: s["finals"] for name, s in summaries.items()}
    notes = []
    for arm in arms:
        short = [r for r in arm.repeats if r.n < budget and r.ended in BUDGET_TRIGGERS]
        if short:
            notes.append(
                f"{arm.name}: {len(short)} repeat(s) ended by their own budget ({short[0].ended}) before "
                f"{budget} experiments and are held at their final best; pass --budget "
                f"{min(r.n for r in short)} to compare like for like."
            )
        if arm.unstarted:
            notes.append(
                f"{arm.name}: not started yet, left out: {', '.join(d.name for d in arm.unstarted)}."
            )
        unfinished = [r.dir.name for r in arm.repeats if r.ended is None]
        if unfinished:
            notes.append(
                f"{arm.name}: unfinished (running or interrupted), held at their last best: {', '.join(unfinished)}."
            )
    return Analysis(
        family,
        direction,
        budget,
        noise_reference(arms, sigma),
        arms,
        summaries,
        compare.improvement_table(finals, direction, rng, n_resamples),
        notes,
    )
