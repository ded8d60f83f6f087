"""The key-free random-search arm (paper Eq. randsearch): iid draws from the per-axis laws."""

from __future__ import annotations

import random
from typing import Any

from autoresearch.proposers.base import Proposal, Proposer, ProposerContext
from autoresearch.space import SearchSpace, canonical_key

MAX_DRAWS = 1000


def seen_configs(context: ProposerContext) -> set[str]:
    """Configurations run or running: a key-free proposer proposes neither again."""
    return {canonical_key(item["config"]) for item in (*context.history, *context.running)}


def full_config_proposal(
    space: SearchSpace, config: dict[str, Any], context: ProposerContext, hypothesis: str
) -> Proposal:
    """A proposal of a whole configuration, annotated with the axes it moves off the current values."""
    changed = [k for k in config if config[k] != context.current_values.get(k)]
    return Proposal(
        kind="propose",
        overrides=config,
        annotation={"hypothesis": hypothesis, "axes": sorted(space.axes_of(changed))},
    )


CAMPAIGN_STREAM = "random-search"  # a `loop --proposer random` campaign's draws
ARM_STREAM = "audit-random-arm"  # the audit's random arm: never a campaign's draws at the same seed


class RandomProposer(Proposer):
    """Samples a full configuration each turn, skipping configurations already run.

    Iteration ``i`` draws from its own stream seeded by (``stream``, seed, i), so a resumed campaign
    draws exactly what an uninterrupted one would have, and the audit's random arm (its own
    ``stream``) never repeats the draws of a random campaign run at the same seed.
    """

    name = "random"

    def __init__(
        self,
        registry: dict[str, Any],
        seed: int = 0,
        space: str = "random-range",
        stream: str = CAMPAIGN_STREAM,
    ):
        self.space = SearchSpace.from_json(registry["search_space"], tuple(registry["axes"])).searched(space)
        self.seed, self.stream = seed, stream

    def propose(self, context: ProposerContext) -> Proposal:
        rng = random.Random(f"{self.stream}:{self.seed}:{context.iteration}")
        seen = seen_configs(context)
        for _ in range(MAX_DRAWS):
            config = self.space.sample(rng)
            if canonical_key(config) not in seen:
                return full_config_proposal(self.space, config, context, "random sample (Eq. randsearch)")
        return Proposal(kind="invalid", error=f"no unseen configuration in {MAX_DRAWS} random draws")
