"""Proposer strategies, built by name. LLM back-ends are imported only when asked for."""

from __future__ import annotations

from typing import Any

from autoresearch.proposers.base import Proposer

PROPOSERS = ("anthropic", "openai", "random", "tpe")
KEY_FREE = ("random", "tpe")


def make_proposer(
    name: str,
    registry: dict[str, Any],
    *,
    seed: int,
    model: str | None = None,
    base_url: str | None = None,
    prices: Any = None,
    **llm_options: Any,
) -> Proposer:
    """The proposer called ``name``; ``registry`` is family.json as shown to it.

    ``seed`` seeds the key-free proposers (an LLM's sampling cannot be seeded reliably);
    ``llm_options`` go to the LLM proposer's constructor (max_tokens, effort, profile, ...).
    """
    if name in KEY_FREE and (model or base_url or llm_options):
        raise ValueError(f"--model, --base-url and the LLM flags apply to LLM proposers, not to {name!r}")
    if name == "random":
        from autoresearch.proposers.random_search import RandomProposer

        return RandomProposer(registry, seed=seed)
    if name == "tpe":
        from autoresearch.proposers.tpe import TPEProposer

        return TPEProposer(registry, seed=seed)
    if name == "anthropic":
        if base_url:
            raise ValueError("--base-url applies to the openai proposer only")
        from autoresearch.proposers.anthropic_api import AnthropicProposer

        return AnthropicProposer(registry, model=model, prices=prices, **llm_options)
    if name == "openai":
        from autoresearch.proposers.openai_api import OpenAIProposer

        return OpenAIProposer(registry, model=model, base_url=base_url, prices=prices, **llm_options)
    raise ValueError(f"unknown proposer {name!r}; choose one of {', '.join(PROPOSERS)}")
