"""A proposer backed by the OpenAI Chat Completions API, or any server that speaks it (vLLM, Ollama).

One request per turn with the two function tools, ``tool_choice="required"`` and no parallel calls.
The prompt is laid out for the automatic prefix caches of OpenAI and vLLM (stable parts first), and
``cached_tokens`` are billed at the cache-read rate. Errors follow the Anthropic proposer: transport
faults raise :class:`TransientAPIError` for the orchestrator to retry, authentication and spend-limit
errors :class:`FatalAPIError`, anything else is an invalid proposal.

The **local profile** (``profile="local"``, the default with ``base_url``) serves vLLM and Ollama:
tool schemas without the keywords their guided decoding rejects, ``max_tokens`` instead of
``max_completion_tokens``, no ``reasoning_effort``, a tool call written as JSON in prose accepted
(both servers may ignore ``tool_choice``), a note when the server counted far fewer prompt tokens
than were sent (Ollama silently truncates past its context), and a price of 0 unless the table or
an override prices the model.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from collections.abc import Mapping
from typing import Any

import openai

from autoresearch.proposers.anthropic_api import (
    CHARS_PER_TOKEN,
    DEFAULT_MAX_TOKENS,
    DEFAULT_READ_TIMEOUT_S,
    http_timeout,
)
from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, Usage
from autoresearch.proposers.capabilities import capabilities
from autoresearch.proposers.pricing import Price, checked_counts, cost_usd, load_prices, max_charge, price_of
from autoresearch.proposers.prompting import SYSTEM_PROMPT, render_context
from autoresearch.proposers.retry import sdk_error
from autoresearch.proposers.tools import PROPOSE, STOP, openai_tools, parse_tool_call, safe_text

# The newest GPT whose Chat Completions endpoint takes function tools without a reasoning_effort
# setting; gpt-5.5 and later refuse tools there unless reasoning_effort="none".
DEFAULT_MODEL = "gpt-5.4"
PROFILES = ("auto", "cloud", "local")
# A server reporting fewer prompt tokens than this share of our estimate has cut the prompt.
TRUNCATION_RATIO = 0.5
LOCAL_CONTEXT_TOKENS = 32_768  # what the docs ask a local server to give the model
_JSON_OBJECT = re.compile(r"\{.*\}", re.DOTALL)


def _prose_call(text: str) -> tuple[str, Any] | None:
    """A tool call a local model wrote as JSON in its text: {"name": ..., "arguments": {...}}."""
    match = _JSON_OBJECT.search(text)
    if not match:
        return None
    try:
        data = json.loads(match.group())
    except json.JSONDecodeError:
        return None
    if isinstance(data, dict) and data.get("name") in (PROPOSE, STOP):
        return data["name"], data.get("arguments", data.get("parameters"))
    return None


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
        max_tokens: int = DEFAULT_MAX_TOKENS,
        timeout: float = DEFAULT_READ_TIMEOUT_S,
        reasoning_effort: str | None = None,
        profile: str = "auto",
        max_retries: int = 0,
    ) -> None:
        """``base_url`` points at an OpenAI-compatible server; there the API key may be a dummy, so
        OPENAI_API_KEY is used when set and "not-needed" otherwise. With an injected ``client``,
        ``base_url`` (when given) still applies; max_retries and timeout do not.

        ``reasoning_effort`` is sent only when given, and never to a local server; pass "none" to
        use gpt-5.5, gpt-5.6 or gpt-6 models with tools on Chat Completions.
        """
        if profile not in PROFILES:
            raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {profile!r}")
        self.local = profile == "local" or (profile == "auto" and base_url is not None)
        if client is None:
            api_key = os.environ.get("OPENAI_API_KEY") or ("not-needed" if base_url else None)
            client = openai.OpenAI(
                api_key=api_key, base_url=base_url, max_retries=max_retries, timeout=http_timeout(timeout)
            )
        elif base_url is not None:
            client = client.with_options(base_url=base_url)
        self.model = model or DEFAULT_MODEL
        self.client = client
        self.registry = registry
        self.prices = dict(load_prices() if prices is None else prices)
        if self.local and price_of(self.model, self.prices) is None:
            self.prices[self.model] = Price(0.0, 0.0)  # a model served locally costs no money
        self.tools = openai_tools(registry, local=self.local)
        self.max_tokens = max_tokens if self.local else min(max_tokens, capabilities(self.model).max_output)
        cap = "max_tokens" if self.local else "max_completion_tokens"
        self.extra: dict[str, Any] = {cap: self.max_tokens}
        if reasoning_effort is not None and not self.local:
            self.extra["reasoning_effort"] = reasoning_effort

    def request(self, context: ProposerContext) -> dict[str, Any]:
        """The Chat Completions request body for one turn."""
        return {
            "model": self.model,
            "messages": [
                {"role": "system", "content": SYSTEM_PROMPT},
                {"role": "user", "content": render_context(context)},
            ],
            "tools": self.tools,
            "tool_choice": "required",
            "parallel_tool_calls": False,
            **self.extra,
        }

    def projected_cost(self, context: ProposerContext) -> float:
        """An upper bound on the next call: every input token uncached, max_tokens of output."""
        chars = len(str(self.request(context)))
        return cost_usd(self.model, round(chars / CHARS_PER_TOKEN), self.max_tokens, self.prices)

    def propose(self, context: ProposerContext) -> Proposal:
        body = self.request(context)
        try:
            reply = self.client.chat.completions.create(**body)
        except openai.APIError as err:
            return sdk_error(err, openai, with_code=True)
        usage = self._usage(reply.usage)
        notes: dict[str, Any] = {}
        sent_chars = len(json.dumps(body["messages"])) + len(json.dumps(body["tools"]))
        if (
            self.local
            and usage.problem is None
            and 0 < usage.input_tokens < TRUNCATION_RATIO * sent_chars / 4
        ):
            notes["context_truncated"] = (
                f"the server counted {usage.input_tokens} prompt tokens for about {sent_chars // 4}: it "
                f"probably cut the prompt; give the model a context of {LOCAL_CONTEXT_TOKENS} tokens "
                f"(Ollama: num_ctx)"
            )
        if not reply.choices:
            return Proposal(kind="invalid", usage=usage, error="the reply has no choices", notes=notes)
        choice = reply.choices[0]
        calls = [call for call in choice.message.tool_calls or [] if call.type == "function"]
        text = choice.message.content or ""
        if choice.finish_reason == "length":
            where = "inside its tool call" if calls else "before its tool call"
            notes["truncated"] = True
            return Proposal(
                kind="invalid",
                usage=usage,
                error=f"the reply was cut off at max_tokens={self.max_tokens} {where} (raise --max-tokens)",
                notes=notes,
            )
        if not calls and self.local and (prose := _prose_call(text)) is not None:
            notes["tool_call_in_prose"] = True
            return dataclasses.replace(parse_tool_call(*prose, self.registry), usage=usage, notes=notes)
        if getattr(choice.message, "refusal", None):
            refusal = safe_text(" ".join(choice.message.refusal.split())[:300])
            notes["refusal"] = {"category": None, "explanation": refusal}
            return Proposal(kind="invalid", usage=usage, error=f"the model refused: {refusal}", notes=notes)
        if len(calls) != 1:
            error = f"expected exactly one tool call, got {len(calls)} (finish_reason={choice.finish_reason})"
            if text.strip():
                error += f"; text: {safe_text(' '.join(text.split())[:300])}"
            return Proposal(kind="invalid", usage=usage, error=error, notes=notes)
        call = calls[0].function
        proposal = parse_tool_call(call.name, call.arguments, self.registry)
        return dataclasses.replace(proposal, usage=usage, notes=notes)

    def _usage(self, u: Any) -> Usage:
        """Usage and cost from the reply's usage block; untrusted counts cost the maximum."""
        if u is None:
            return Usage(
                cost_usd=max_charge(self.model, self.prices, self.max_tokens), problem="no usage block"
            )
        prompt_details = getattr(u, "prompt_tokens_details", None)
        completion_details = getattr(u, "completion_tokens_details", None)
        counts, problem = checked_counts(
            {
                "prompt_tokens": getattr(u, "prompt_tokens", None),
                "completion_tokens": getattr(u, "completion_tokens", None),
                "cached_tokens": getattr(prompt_details, "cached_tokens", None),
                "reasoning_tokens": getattr(completion_details, "reasoning_tokens", None),
            }
        )
        if problem is None and counts["cached_tokens"] > counts["prompt_tokens"]:
            problem = f"usage.cached_tokens={counts['cached_tokens']} exceeds prompt_tokens={counts['prompt_tokens']}"
        if problem is not None:
            return Usage(cost_usd=max_charge(self.model, self.prices, self.max_tokens), problem=problem)
        prompt, cached = counts["prompt_tokens"], counts["cached_tokens"]
        cost = cost_usd(
            self.model, prompt - cached, counts["completion_tokens"], self.prices, cache_read_tokens=cached
        )
        return Usage(
            prompt,
            counts["completion_tokens"],
            cost,
            cache_read_tokens=cached,
            reasoning_tokens=counts["reasoning_tokens"],
        )
