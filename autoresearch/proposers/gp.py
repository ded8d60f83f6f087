"""A key-free Gaussian-process arm: Optuna's GPSampler (log expected improvement, constrained when a
run is infeasible: by the family's graded constraints where it reports them, which GPSampler models
as a probability of feasibility), for budgets of tens of experiments over mixed spaces.

It keeps everything of the TPE arm (autoresearch.proposers.tpe) but the sampler: a fresh in-memory
study per turn filled with the outcomes told so far, failures at the crash cost, the sampler seeded
by (seed, number of outcomes, attempt), so that a resumed campaign asks what an uninterrupted one
would have. Experiments still running (``loop --workers K``) enter the study as RUNNING trials,
which GPSampler folds into a q-batch acquisition (qLogEI) instead of proposing next to them.
Kept rather than CMA-ES, which ignores RUNNING trials, samples categoricals independently and
needs the cmaes package; benchmarks/bench_keyfree_samplers.py found no sampler clearly ahead of
TPE at 30 trials on a synthetic objective (results/README.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import optuna
from optuna.trial import FrozenTrial

from autoresearch.proposers.base import RunOutcome
from autoresearch.proposers.tpe import TPEProposer, _derived_seed

N_STARTUP_TRIALS = 5  # random draws before the GP is fitted (the baseline counts as one)


class GPProposer(TPEProposer):
    name = "gp"

    def __init__(
        self,
        registry: dict[str, Any],
        seed: int = 0,
        n_startup_trials: int = N_STARTUP_TRIALS,
        space: str = "bounds",
        prior: Sequence[RunOutcome] = (),
        off_at_zero: bool = False,
    ):
        super().__init__(
            registry,
            seed=seed,
            n_startup_trials=n_startup_trials,
            space=space,
            prior=prior,
            off_at_zero=off_at_zero,
        )

    def _ask(
        self, trials: list[FrozenTrial], attempt: int, running: Sequence[FrozenTrial] = ()
    ) -> dict[str, Any]:
        seed = _derived_seed("gp", self.seed, len(trials), attempt)
        sampler = optuna.samplers.GPSampler(
            seed=seed,
            n_startup_trials=self.n_startup_trials,
            independent_sampler=optuna.samplers.RandomSampler(seed=seed),
            warn_independent_sampling=False,
        )
        study = optuna.create_study(direction=self.direction.study, sampler=sampler)
        study.add_trials([*trials, *running])
        return self.config_of(study.ask(self.distributions))
