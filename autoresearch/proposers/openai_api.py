"""A proposer backed by the OpenAI Chat Completions API, or any server that speaks it (vLLM, Ollama).

One request per turn with the two function tools, ``tool_choice="required"`` and no parallel calls.
Retries and failure handling follow the Anthropic proposer: the SDK retries transient failures
(``max_retries``); an API error that survives them becomes an invalid proposal.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

import openai

from autoresearch.pricing import Price, cost_usd, load_prices
from autoresearch.prompting import SYSTEM_PROMPT, render_context
from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, Usage
from autoresearch.proposers.tools import openai_tools, parse_tool_call

# The newest GPT whose Chat Completions endpoint takes function tools without a reasoning_effort
# setting; gpt-5.5 and later refuse tools there unless reasoning_effort="none".
DEFAULT_MODEL = "gpt-5.4"


def _error_text(err: openai.APIError) -> str:
    return " ".join(str(err).split())[:500]


class OpenAIProposer(Proposer):
    name = "openai"

    def __init__(
        self,
        registry: dict[str, Any],
        *,
        model: str | None = None,
        base_url: str | None = None,
        client: openai.OpenAI | None = None,
        prices: Mapping[str, Price] | None = None,
        max_retries: int = 4,
        timeout: float = 120.0,
        reasoning_effort: str | None = None,
    ) -> None:
        """``base_url`` points at an OpenAI-compatible server; there the API key may be a dummy, so
        OPENAI_API_KEY is used when set and "not-needed" otherwise. With an injected ``client``,
        ``base_url`` (when given) still applies; max_retries and timeout do not.

        ``reasoning_effort`` is sent only when given (local servers may reject the field); pass "none"
        to use gpt-5.5, gpt-5.6 or gpt-6 models with tools on Chat Completions.
        """
        if client is None:
            api_key = os.environ.get("OPENAI_API_KEY") or ("not-needed" if base_url else None)
            client = openai.OpenAI(
                api_key=api_key, base_url=base_url, max_retries=max_retries, timeout=timeout
            )
        elif base_url is not None:
            client = client.with_options(base_url=base_url)
        self.model = model or DEFAULT_MODEL
        self.client = client
        self.registry = registry
        self.prices = load_prices() if prices is None else prices
        self.tools = openai_tools(registry)
        self.extra = {} if reasoning_effort is None else {"reasoning_effort": reasoning_effort}

    def propose(self, context: ProposerContext) -> Proposal:
        try:
            reply = self.client.chat.completions.create(
                model=self.model,
                messages=[
                    {"role": "system", "content": SYSTEM_PROMPT},
                    {"role": "user", "content": render_context(context)},
                ],
                tools=self.tools,
                tool_choice="required",
                parallel_tool_calls=False,
                **self.extra,
            )
        except openai.APIError as err:
            return Proposal(kind="invalid", error=f"api error: {_error_text(err)}")

        u = reply.usage
        input_tokens, output_tokens = (u.prompt_tokens, u.completion_tokens) if u else (0, 0)
        usage = Usage(
            input_tokens, output_tokens, cost_usd(self.model, input_tokens, output_tokens, self.prices)
        )

        if not reply.choices:
            return Proposal(kind="invalid", usage=usage, error="the reply has no choices")
        choice = reply.choices[0]
        calls = [call for call in choice.message.tool_calls or [] if call.type == "function"]
        if len(calls) != 1:
            error = f"expected exactly one tool call, got {len(calls)} (finish_reason={choice.finish_reason})"
            if choice.message.content and choice.message.content.strip():
                error += f"; text: {' '.join(choice.message.content.split())[:300]}"
            return Proposal(kind="invalid", usage=usage, error=error)
        call = calls[0].function
        return dataclasses.replace(parse_tool_call(call.name, call.arguments, self.registry), usage=usage)
