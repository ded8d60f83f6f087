"""A key-free TPE arm: Optuna's TPESampler over the family's search space, ask/tell in memory.

Each turn a fresh in-memory study is filled with every outcome told so far and asked once,
with the sampler seeded by (seed, number of outcomes, attempt). The proposal is therefore a
pure function of the seed and the history: a resumed campaign, which tells the history again,
asks exactly what an uninterrupted one would have.

Outcomes: a successful feasible run is a COMPLETE trial with its metric; a successful but
infeasible run is a COMPLETE trial with its metric and a violated constraint, which Optuna's TPE
ranks below every feasible trial (penalised, yet its location still informs the model); a
failed or timed-out run is told as an infeasible trial at the worst metric seen so far (SMAC's
"crash cost"), so TPE learns to avoid regions that diverge or overrun the per-run time limit;
before any run has succeeded there is no worst metric and it is a FAIL trial, which TPE ignores.
Without the crash cost, a search space with slow corners keeps TPE in its random start-up phase
(FAIL trials do not count towards it) and spends the budget on timeouts. TPE searches the full
declared bounds unless ``space="random-range"`` (autoresearch.space.SPACES).

Constraints: when the family's runs report graded constraints (``constraints_field``, Optuna's
convention: a value <= 0 is satisfied), those are the trial's constraints, so that before any
run is feasible TPE ranks infeasible runs by how far they miss and the GP arm models the
probability of feasibility. With a 0/1 constraint every infeasible run ties: Optuna's TPE then
keeps the earliest runs as its "good" group and the GP's feasibility model is flat, so both arms
search blind until a draw happens to be feasible. A failed run takes the worst value seen of
each constraint (1.0 each while every run has met them all); runs without graded constraints
(older records) make every trial 0/1 again.
"""

from __future__ import annotations

import hashlib
import random
from collections.abc import Sequence
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from autoresearch.direction import Direction
from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, RunOutcome
from autoresearch.proposers.optuna_space import distributions, from_params, switchable, to_params
from autoresearch.proposers.random_search import MAX_DRAWS, full_config_proposal, seen_configs
from autoresearch.space import SearchSpace, canonical_key

MAX_ASKS = 20  # re-asks with a new seed when TPE suggests a configuration already run


def _derived_seed(*parts: Any) -> int:
    digest = hashlib.sha256(":".join(map(str, parts)).encode()).digest()
    return int.from_bytes(digest[:4], "big")


class TPEProposer(Proposer):
    name = "tpe"

    def __init__(
        self,
        registry: dict[str, Any],
        seed: int = 0,
        n_startup_trials: int = 10,
        space: str = "bounds",
        prior: Sequence[RunOutcome] = (),
        off_at_zero: bool = False,
    ):
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.family_space = SearchSpace.from_json(registry["search_space"], tuple(registry["axes"]))
        self.space = self.family_space.searched(space)
        self.direction = Direction.of(registry["direction"])
        self.seed = seed
        self.n_startup_trials = n_startup_trials
        # loop --off-at-zero: a real range starting at 0 gets an off switch (optuna_space)
        self.switched = switchable(self.space) if off_at_zero else ()
        self.distributions = distributions(self.space, off_at_zero)
        self.outcomes: list[RunOutcome] = []
        for outcome in prior:  # a warm start: earlier campaigns' runs, told before this campaign's
            self.tell(outcome)

    def tell(self, outcome: RunOutcome) -> None:
        self.outcomes.append(outcome._replace(config=self.family_space.validate_full(outcome.config)))

    def _constraints_of_failures(self) -> dict[str, float] | None:
        """The graded constraints a failed run is told (the worst of each seen), or None when the
        successful runs do not all report the same graded constraints."""
        graded = [o.constraints for o in self.outcomes if o.metric is not None]
        if not graded or any(c is None or c.keys() != graded[0].keys() for c in graded):
            return None
        worst = {name: max(c[name] for c in graded) for name in graded[0]}
        # A failure is infeasible: while every run has met every constraint, it is told 1.0 each.
        return worst if any(v > 0 for v in worst.values()) else dict.fromkeys(worst, 1.0)

    @property
    def trials(self) -> list[FrozenTrial]:
        """The outcomes inside the searched space as Optuna trials, failures at the current crash cost.

        An outcome outside it (a baseline or enqueued run beyond a narrowed range) cannot be an
        Optuna trial of these distributions; it still sets the crash cost."""
        metrics = [o.metric for o in self.outcomes if o.metric is not None]
        crash_cost = self.direction.worst(metrics) if metrics else None
        crash_constraints = self._constraints_of_failures()
        trials = []
        for outcome in self.outcomes:
            if not self.space.contains(outcome.config):
                continue
            # What the run cost, and whether its time budget cut it: seen by anyone reading the study.
            attrs = {"seconds": outcome.seconds, "budget_exhausted": outcome.budget_exhausted}
            if outcome.curve:  # stopped early: Optuna's TPE ranks a pruned trial by how far it got
                trials.append(
                    optuna.trial.create_trial(
                        state=TrialState.PRUNED,
                        params=to_params(outcome.config, self.switched),
                        distributions=self.distributions,
                        intermediate_values=outcome.curve,
                        user_attrs=attrs,
                    )
                )
                continue
            if outcome.metric is None and crash_cost is None:
                trials.append(
                    optuna.trial.create_trial(
                        state=TrialState.FAIL,
                        params=to_params(outcome.config, self.switched),
                        distributions=self.distributions,
                        user_attrs=attrs,
                    )
                )
                continue
            if crash_constraints is None:
                constraints = {"feasible": 0.0 if outcome.metric is not None and outcome.feasible else 1.0}
            else:
                constraints = crash_constraints if outcome.metric is None else outcome.constraints
            trials.append(
                optuna.trial.create_trial(
                    value=crash_cost if outcome.metric is None else outcome.metric,
                    params=to_params(outcome.config, self.switched),
                    distributions=self.distributions,
                    constraints=constraints,
                    user_attrs=attrs,
                )
            )
        return trials

    def _ask(
        self, trials: list[FrozenTrial], attempt: int, running: Sequence[FrozenTrial] = ()
    ) -> dict[str, Any]:
        sampler = optuna.samplers.TPESampler(
            seed=_derived_seed("tpe", self.seed, len(trials), attempt),
            n_startup_trials=self.n_startup_trials,
            constant_liar=True,  # runs in flight are pending trials: TPE is steered away from them
        )
        study = optuna.create_study(direction=self.direction.study, sampler=sampler)
        study.add_trials([*trials, *running])
        return self.config_of(study.ask(self.distributions))

    def config_of(self, trial: optuna.trial.BaseTrial) -> dict[str, Any]:
        """The validated config an asked trial stands for (a switched-off parameter is 0)."""
        return self.space.validate_full(from_params(trial.params, self.switched))

    def propose(self, context: ProposerContext) -> Proposal:
        seen = seen_configs(context)
        trials = self.trials
        # Runs in flight are pending trials (those outside a narrowed space cannot be Optuna trials).
        configs = (self.family_space.validate_full(item["config"]) for item in context.running)
        running = [
            optuna.trial.create_trial(
                state=TrialState.RUNNING,
                params=to_params(config, self.switched),
                distributions=self.distributions,
            )
            for config in configs
            if self.space.contains(config)
        ]
        for attempt in range(MAX_ASKS):
            config = self._ask(trials, attempt, running)
            if canonical_key(config) not in seen:
                hypothesis = f"{self.name.upper()} suggestion after {len(trials)} observations"
                return full_config_proposal(self.space, config, context, hypothesis)
        # TPE keeps landing on known points (a small discrete space): fall back to an unseen random draw.
        rng = random.Random(_derived_seed("tpe-fallback", self.seed, len(self.outcomes)))
        for _ in range(MAX_DRAWS):
            config = self.space.sample(rng)
            if canonical_key(config) not in seen:
                hypothesis = "random draw: TPE suggested only configurations already run"
                return full_config_proposal(self.space, config, context, hypothesis)
        return Proposal(kind="invalid", error="no unseen configuration found by TPE or random draws")
