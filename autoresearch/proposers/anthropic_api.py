"""A proposer backed by Claude through the Anthropic Messages API.

One request per turn, with exactly the two tools and one tool use allowed. Transient failures
(429, 5xx, 529 overloaded, timeouts, dropped connections) are retried with backoff by the SDK itself
(``max_retries``); once retries are spent, or on any other API error, the turn becomes an invalid
proposal, which the orchestrator counts against its consecutive-failure cap, so no single outage ends
a campaign. Configuration errors (no credentials) still raise: they will not heal by retrying.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import anthropic

from autoresearch.pricing import Price, cost_usd, load_prices
from autoresearch.prompting import SYSTEM_PROMPT, render_context
from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, Usage
from autoresearch.proposers.tools import anthropic_tools, parse_tool_call

DEFAULT_MODEL = "claude-sonnet-5-5"

# Models whose API answers a forced tool choice ("any" or a named tool) with a 400: on these the tool
# choice is "auto" and a reply without a tool call becomes an invalid proposal. Dated snapshots match
# by prefix.
NO_FORCED_TOOL_CHOICE = ("claude-sonnet-5-5", "claude-opus-5-5", "claude-fable-5-1")


def _error_text(err: anthropic.APIError) -> str:
    return " ".join(str(err).split())[:500]


class AnthropicProposer(Proposer):
    name = "anthropic"

    def __init__(
        self,
        registry: dict[str, Any],
        *,
        model: str | None = None,
        client: anthropic.Anthropic | None = None,
        prices: Mapping[str, Price] | None = None,
        max_tokens: int = 8192,
        max_retries: int = 4,
        timeout: float = 120.0,
        force_tool_choice: bool | None = None,
    ) -> None:
        """``client`` defaults to one reading ANTHROPIC_API_KEY (max_retries and timeout apply to it only).

        ``force_tool_choice`` None picks by model: forced ("any") unless the model is in
        NO_FORCED_TOOL_CHOICE. ``max_tokens`` bounds thinking and the tool call together.
        """
        self.model = model or DEFAULT_MODEL
        self.client = client or anthropic.Anthropic(max_retries=max_retries, timeout=timeout)
        self.registry = registry
        self.prices = load_prices() if prices is None else prices
        self.max_tokens = max_tokens
        self.tools = anthropic_tools(registry)
        if force_tool_choice is None:
            force_tool_choice = not self.model.startswith(NO_FORCED_TOOL_CHOICE)
        self.tool_choice = {"type": "any" if force_tool_choice else "auto", "disable_parallel_tool_use": True}

    def propose(self, context: ProposerContext) -> Proposal:
        try:
            reply = self.client.messages.create(
                model=self.model,
                max_tokens=self.max_tokens,
                system=SYSTEM_PROMPT,
                messages=[{"role": "user", "content": render_context(context)}],
                tools=self.tools,
                tool_choice=self.tool_choice,
            )
        except anthropic.APIError as err:
            return Proposal(kind="invalid", error=f"api error: {_error_text(err)}")

        # Prompt caching is not requested, so the cache counts are normally absent; if present they are
        # input tokens too, priced at the input rate.
        u = reply.usage
        input_tokens = (
            u.input_tokens + (u.cache_creation_input_tokens or 0) + (u.cache_read_input_tokens or 0)
        )
        usage = Usage(
            input_tokens, u.output_tokens, cost_usd(self.model, input_tokens, u.output_tokens, self.prices)
        )

        calls = [block for block in reply.content if block.type == "tool_use"]
        if len(calls) != 1:
            text = " ".join(block.text for block in reply.content if block.type == "text")
            hint = " (raise max_tokens)" if reply.stop_reason == "max_tokens" else ""
            error = (
                f"expected exactly one tool call, got {len(calls)} (stop_reason={reply.stop_reason}{hint})"
            )
            if text.strip():
                error += f"; text: {' '.join(text.split())[:300]}"
            return Proposal(kind="invalid", usage=usage, error=error)
        return dataclasses.replace(parse_tool_call(calls[0].name, calls[0].input, self.registry), usage=usage)
