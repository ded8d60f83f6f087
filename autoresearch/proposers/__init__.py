"""Proposer strategies, built by name. LLM back-ends are imported only when asked for."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from autoresearch.extras import require
from autoresearch.proposers.base import Proposer, RunOutcome

PROPOSERS = ("anthropic", "gp", "openai", "random", "tpe")
KEY_FREE = ("gp", "random", "tpe")
# The space a key-free proposer searches when none is chosen (autoresearch.space.SPACES): what
# each searched before the choice existed, so that old campaigns resume unchanged.
DEFAULT_SPACE = {"gp": "bounds", "random": "random-range", "tpe": "bounds"}


def make_proposer(
    name: str,
    registry: dict[str, Any],
    *,
    seed: int,
    model: str | None = None,
    base_url: str | None = None,
    prices: Any = None,
    space: str | None = None,
    off_at_zero: bool = False,
    prior: Sequence[RunOutcome] = (),
    **llm_options: Any,
) -> Proposer:
    """The proposer called ``name``; ``registry`` is family.json as shown to it.

    ``seed`` seeds the key-free proposers (an LLM's sampling cannot be seeded reliably);
    ``space`` is what a key-free proposer searches (default :data:`DEFAULT_SPACE`);
    ``off_at_zero`` gives the tpe and gp samplers an off switch for each real range starting at 0
    (autoresearch.proposers.optuna_space); ``prior`` are earlier campaigns' runs a TPE or GP sampler starts from (``loop --warm-start``);
    ``llm_options`` go to the LLM proposer's constructor (max_tokens, effort, profile, ...).
    """
    if prior and name not in ("tpe", "gp"):
        raise ValueError(f"earlier runs (--warm-start) are told to the tpe and gp samplers, not to {name!r}")
    if off_at_zero and name not in ("tpe", "gp"):
        raise ValueError(f"--off-at-zero applies to the tpe and gp samplers, not to {name!r}")
    if name in KEY_FREE and (model or base_url or llm_options):
        raise ValueError(f"--model, --base-url and the LLM flags apply to LLM proposers, not to {name!r}")
    if name not in KEY_FREE and space is not None:
        raise ValueError(
            f"--space applies to the key-free proposers ({', '.join(KEY_FREE)}), not to {name!r}"
        )
    if name in KEY_FREE:
        space = space or DEFAULT_SPACE[name]
    if name == "random":
        from autoresearch.proposers.random_search import RandomProposer

        return RandomProposer(registry, seed=seed, space=space)
    if name == "tpe":
        from autoresearch.proposers.tpe import TPEProposer

        return TPEProposer(registry, seed=seed, space=space, prior=prior, off_at_zero=off_at_zero)
    if name == "gp":
        require("torch", "gp", "--proposer gp (Optuna's GPSampler)")
        from autoresearch.proposers.gp import GPProposer

        return GPProposer(registry, seed=seed, space=space, prior=prior, off_at_zero=off_at_zero)
    if name == "anthropic":
        if base_url:
            raise ValueError("--base-url applies to the openai proposer only")
        require("anthropic", "llm", "--proposer anthropic")
        from autoresearch.proposers.anthropic_api import AnthropicProposer

        return AnthropicProposer(registry, model=model, prices=prices, **llm_options)
    if name == "openai":
        require("openai", "llm", "--proposer openai")
        from autoresearch.proposers.openai_api import OpenAIProposer

        return OpenAIProposer(registry, model=model, base_url=base_url, prices=prices, **llm_options)
    raise ValueError(f"unknown proposer {name!r}; choose one of {', '.join(PROPOSERS)}")
