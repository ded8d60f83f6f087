"""Configurations the user asks to run first, ahead of any proposer (Optuna's ``enqueue_trial``).

Use it to warm-start a search from known-good recipes, or to put a hand-found configuration into
a campaign so the audit can reseed and prune it like any other candidate. Each queued entry is a
partial {NAME: value} map applied to the family's baseline; it runs once (a configuration already
in the history is skipped, which also makes resuming exact), then the wrapped proposer takes over.
Every outcome is told to the wrapped proposer, so TPE learns from the queued runs too.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, RunOutcome
from autoresearch.proposers.random_search import full_config_proposal, seen_configs
from autoresearch.space import SearchSpace, ValidationError, canonical_key

HYPOTHESIS = "enqueued by the user (--enqueue), run ahead of the proposer"


def read_queue(path: str | Path) -> list[dict[str, Any]]:
    """The entries of an --enqueue file: one JSON object or a list of them."""
    try:
        entries = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:  # ValueError: bad JSON, or an integer of > 4300 digits
        raise ValueError(f"--enqueue {path}: {err}") from None
    except RecursionError:
        raise ValueError(f"--enqueue {path}: JSON nested too deeply") from None
    entries = [entries] if isinstance(entries, dict) else entries
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise ValueError(f"--enqueue {path}: expected a JSON object or a non-empty list of objects")
    return entries


def full_queue(space: SearchSpace, baseline: dict[str, Any], entries: list[dict[str, Any]]) -> list[dict]:
    """Each entry validated against the search space and completed from the baseline."""
    queue = []
    for number, entry in enumerate(entries, start=1):
        try:
            queue.append(space.validate_full({**baseline, **space.validate(entry)}))
        except ValidationError as err:
            raise ValueError(f"--enqueue entry {number}: {err}") from None
    return queue


class EnqueuedProposer(Proposer):
    """Proposes each queued configuration not yet in the history, then defers to ``inner``."""

    def __init__(self, queue: list[dict[str, Any]], inner: Proposer, space: SearchSpace):
        self.queue, self.inner, self.space = queue, inner, space
        self.name = inner.name

    def propose(self, context: ProposerContext) -> Proposal:
        seen = seen_configs(context)
        for config in self.queue:
            if canonical_key(config) not in seen:
                return full_config_proposal(self.space, config, context, HYPOTHESIS)
        return self.inner.propose(context)

    def tell(self, outcome: RunOutcome) -> None:
        self.inner.tell(outcome)
