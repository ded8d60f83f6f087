"""A proposer backed by Claude through the Anthropic Messages API.

One request per turn, with exactly the two tools and one tool use allowed, laid out for prompt
caching (:mod:`autoresearch.proposers.prompting`): ``cache_control`` breakpoints on the stable prefix and on
the last history block. Transport faults raise :class:`TransientAPIError` for the orchestrator to
retry (the SDK's own retries are off); authentication and spend-limit errors raise
:class:`FatalAPIError`; any other API error, a refusal, a truncated reply or a malformed call is an
invalid proposal.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import Any

import anthropic
import httpx2

from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, Usage
from autoresearch.proposers.capabilities import capabilities
from autoresearch.proposers.pricing import Price, checked_counts, cost_usd, load_prices, max_charge
from autoresearch.proposers.prompting import SYSTEM_PROMPT, render_prompt
from autoresearch.proposers.retry import sdk_error
from autoresearch.proposers.tools import anthropic_tools, parse_tool_call, safe_text

DEFAULT_MODEL = "claude-sonnet-5-5"
DEFAULT_MAX_TOKENS = 8192
DEFAULT_EFFORT = "low"  # thinking dominates the output cost at the API's default (high) effort
DEFAULT_READ_TIMEOUT_S = 600.0
# A gap between calls longer than this outlives a 5-minute cache entry: write 1-hour entries instead.
LONG_GAP_S = 240.0
# The SDK refuses a non-streamed request whose max_tokens promises more than 10 minutes of output.
MAX_NONSTREAMING_TOKENS = 21_000
CHARS_PER_TOKEN = 3.0  # conservative (English JSON is ~3.5-4), for the projected cost


def http_timeout(read_s: float) -> httpx2.Timeout:
    """Connect fast; wait ``read_s`` for the next bytes of a reply (a non-streamed reply sends them
    when it is done, so read_s must exceed the slowest legitimate reply)."""
    return httpx2.Timeout(connect=10.0, read=read_s, write=60.0, pool=60.0)


class AnthropicProposer(Proposer):
    name = "anthropic"

    def __init__(
        self,
        registry: dict[str, Any],
        *,
        model: str | None = None,
        client: anthropic.Anthropic | None = None,
        prices: Mapping[str, Price] | None = None,
        max_tokens: int = DEFAULT_MAX_TOKENS,
        timeout: float = DEFAULT_READ_TIMEOUT_S,
        effort: str | None = DEFAULT_EFFORT,
        thinking: str | None = None,
        force_tool_choice: bool | None = None,
        cache_ttl: str = "auto",
        max_retries: int = 0,
    ) -> None:
        """``effort`` (low .. max) is sent to models that take it (the capability table);
        ``thinking`` "adaptive" or "disabled" is sent only when given. ``cache_ttl`` is "5m", "1h",
        "off" or "auto" (1h once calls are more than LONG_GAP_S apart). ``client`` replaces the
        default ``anthropic.Anthropic(max_retries=0, timeout=http_timeout(timeout))``."""
        self.model = model or DEFAULT_MODEL
        self.caps = capabilities(self.model)
        self.client = client or anthropic.Anthropic(max_retries=max_retries, timeout=http_timeout(timeout))
        self.registry = registry
        self.prices = load_prices() if prices is None else prices
        self.tools = anthropic_tools(registry)
        self.max_tokens = min(max_tokens, self.caps.max_output, MAX_NONSTREAMING_TOKENS)
        forced = self.caps.forced_tool if force_tool_choice is None else force_tool_choice
        self.tool_choice = {"type": "any" if forced else "auto", "disable_parallel_tool_use": True}
        self.extra: dict[str, Any] = {}
        if effort is not None and self.caps.effort:
            self.extra["output_config"] = {"effort": effort}
        if thinking is not None:
            self.extra["thinking"] = {"type": thinking}
        if cache_ttl not in ("auto", "5m", "1h", "off"):
            raise ValueError(f"cache_ttl must be auto, 5m, 1h or off, got {cache_ttl!r}")
        self.cache_ttl = cache_ttl
        self._last_call: float | None = None
        self._ttl = "5m"

    def _cache_control(self) -> dict[str, str] | None:
        if self.cache_ttl == "off":
            return None
        ttl = self._ttl if self.cache_ttl == "auto" else self.cache_ttl
        return {"type": "ephemeral", "ttl": ttl}

    def request(self, context: ProposerContext) -> dict[str, Any]:
        """The Messages API request body for one turn."""
        prompt = render_prompt(context)
        cache = self._cache_control()
        content = [{"type": "text", "text": text} for text in (prompt.stable, *prompt.history, prompt.tail)]
        if cache is not None:
            content[0]["cache_control"] = cache
            if len(content) > 2:
                content[-2]["cache_control"] = cache
        return {
            "model": self.model,
            "max_tokens": self.max_tokens,
            "system": SYSTEM_PROMPT,
            "messages": [{"role": "user", "content": content}],
            "tools": self.tools,
            "tool_choice": self.tool_choice,
            **self.extra,
        }

    def projected_cost(self, context: ProposerContext) -> float:
        """An upper bound on the next call: every input token uncached, max_tokens of output."""
        chars = len(str(self.request(context)))
        return cost_usd(self.model, round(chars / CHARS_PER_TOKEN), self.max_tokens, self.prices)

    def propose(self, context: ProposerContext) -> Proposal:
        now = time.monotonic()
        if self._last_call is not None and now - self._last_call > LONG_GAP_S:
            self._ttl = "1h"
        self._last_call = now
        try:
            reply = self.client.messages.create(**self.request(context))
        except anthropic.APIError as err:
            return sdk_error(err, anthropic)
        usage = self._usage(reply.usage)
        if reply.stop_reason == "refusal":
            details = reply.stop_details
            category = getattr(details, "category", None)
            explanation = safe_text(str(getattr(details, "explanation", None) or ""))[:300]
            return Proposal(
                kind="invalid",
                usage=usage,
                error=f"the model refused (category: {category or 'none given'})"
                + (f": {explanation}" if explanation else ""),
                notes={"refusal": {"category": category, "explanation": explanation or None}},
            )
        calls = [block for block in reply.content if block.type == "tool_use"]
        if reply.stop_reason == "max_tokens":
            where = "inside its tool call" if calls else "before its tool call"
            return Proposal(
                kind="invalid",
                usage=usage,
                error=f"the reply was cut off at max_tokens={self.max_tokens} {where} (raise --max-tokens "
                f"or lower --effort)",
                notes={"truncated": True},
            )
        if len(calls) != 1:
            text = " ".join(block.text for block in reply.content if block.type == "text")
            error = f"expected exactly one tool call, got {len(calls)} (stop_reason={reply.stop_reason})"
            if text.strip():
                error += f"; text: {safe_text(' '.join(text.split())[:300])}"
            return Proposal(kind="invalid", usage=usage, error=error)
        return dataclasses.replace(parse_tool_call(calls[0].name, calls[0].input, self.registry), usage=usage)

    def _usage(self, u: Any) -> Usage:
        """Usage and cost from the reply's usage block; untrusted counts cost the maximum."""
        created = getattr(u, "cache_creation", None)
        details = getattr(u, "output_tokens_details", None)
        counts, problem = checked_counts(
            {
                "input_tokens": getattr(u, "input_tokens", None),
                "output_tokens": getattr(u, "output_tokens", None),
                "cache_read_input_tokens": getattr(u, "cache_read_input_tokens", None),
                "cache_creation_input_tokens": getattr(u, "cache_creation_input_tokens", None),
                "ephemeral_1h_input_tokens": getattr(created, "ephemeral_1h_input_tokens", None),
                "thinking_tokens": getattr(details, "thinking_tokens", None),
            }
        )
        if problem is not None:
            return Usage(cost_usd=max_charge(self.model, self.prices, self.max_tokens), problem=problem)
        written = counts["cache_creation_input_tokens"]
        written_1h = min(counts["ephemeral_1h_input_tokens"], written)
        read = counts["cache_read_input_tokens"]
        cost = cost_usd(
            self.model,
            counts["input_tokens"],
            counts["output_tokens"],
            self.prices,
            cache_read_tokens=read,
            cache_write_tokens=written - written_1h,
            cache_write_1h_tokens=written_1h,
        )
        return Usage(
            counts["input_tokens"] + read + written,
            counts["output_tokens"],
            cost,
            cache_read_tokens=read,
            cache_write_tokens=written,
            reasoning_tokens=counts["thinking_tokens"],
        )
