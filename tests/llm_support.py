"""Shared material for the LLM proposer tests: a registry, contexts, and fake HTTP servers.

The SDK clients are real; only the network is replaced, by an httpx2 MockTransport that answers with
real Messages API / Chat Completions JSON and records every request it sees.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import httpx2
from extras import needs_module

from autoresearch.loop.context import shown_registry
from autoresearch.proposers import prompting
from autoresearch.proposers.base import ProposerContext

# The context order both proposers render: stable parts first, the parts that change every turn last.
SECTIONS = (
    prompting.PROGRAM,
    prompting.REGISTRY,
    prompting.RANDOM_ARM,
    prompting.HISTORY,
    prompting.RUNNING,
    prompting.WARNINGS,
    prompting.BEST,
    prompting.CURRENT,
)

# Distinctive numbers, so the blind-mode test can search the whole request for them.
TARGET = 0.7123
BASELINE_METRIC = 6.6047

REGISTRY: dict[str, Any] = {
    "name": "docking",
    "metric": "score",
    "direction": "minimize",
    "target": TARGET,
    "feasibility_field": "strict_feasible",
    "default_seed": 0,
    "axes": ["data", "optimizer", "architecture", "training_budget", "regularization", "safety"],
    "search_space": {
        "N_DEMOS": {"type": "categorical", "choices": [32, 64, 128, 256], "axis": "data"},
        "EPOCHS": {"type": "int", "low": 10, "high": 120, "axis": "training_budget"},
        "LEARNING_RATE": {"type": "log-real", "low": 1e-4, "high": 5e-3, "axis": "optimizer"},
        "WEIGHT_DECAY": {"type": "real", "low": 0.0, "high": 1e-3, "axis": "optimizer"},
        "DROPOUT": {
            "type": "real",
            "low": 0.0,
            "high": 0.5,
            "high_exclusive": True,
            "axis": "regularization",
        },
        "ACTIVATION": {"type": "categorical", "choices": ["tanh", "relu", "gelu"], "axis": "architecture"},
        "RUNTIME_CBF_FILTER": {"type": "bool", "axis": "safety"},
    },
    "baseline": {
        "config": {
            "N_DEMOS": 64,
            "EPOCHS": 40,
            "LEARNING_RATE": 1e-3,
            "WEIGHT_DECAY": 0.0,
            "DROPOUT": 0.1,
            "ACTIVATION": "tanh",
            "RUNTIME_CBF_FILTER": False,
        },
        "metric": BASELINE_METRIC,
        "seed": 0,
    },
    "seed_noise": {"mean": 6.61, "std": 0.2, "k": 5, "seeds": [0, 1, 2, 3, 4], "metric": "score"},
    "best": None,
}

PROPOSAL_INPUT: dict[str, Any] = {
    "hypothesis": "More demonstrations reduce compounding error.",
    "overrides": {"N_DEMOS": 128},
    "axes": ["data"],
    "expected_mechanism": "Better state coverage near the docking port.",
    "comparison_to_best": "Doubles the data of the best run; expect a lower score.",
    "failure_prediction": {"metric": 6.0, "direction": "above"},
}

STOP_INPUT: dict[str, Any] = {
    "status": "exhausted",
    "conclusion": "Six runs over four axes; no move beat the best by more than the seed noise.",
    "axes_tested": ["data", "optimizer", "architecture", "regularization"],
}


def make_context(*, blind: bool = False, warnings: tuple[str, ...] = ()) -> ProposerContext:
    config = dict(REGISTRY["baseline"]["config"])
    if blind:
        registry = shown_registry(REGISTRY, blind=True)  # the loop's own redaction
        program = "Dock the chaser. Minimize score. Parameters and bounds are in the registry."
        history = (
            {"config": config | {"EPOCHS": 60}, "score": 5.9},
            {"config": config | {"N_DEMOS": 32}, "score": 7.25},
        )
        summary = None
    else:
        registry = REGISTRY
        program = f"Dock the chaser. Baseline score {BASELINE_METRIC}; target {TARGET}."
        history = ({"run_id": "r1", "config": config | {"EPOCHS": 60}, "score": 5.9, "seed": 0},)
        summary = "random arm: 8 runs, best score 5.4"
    return ProposerContext(
        iteration=len(history) + 1,
        warnings=warnings,
        program=program,
        registry=registry,
        random_arm_summary=summary,
        history=history,
        current_values=config,
        blind=blind,
    )


class FakeServer:
    """Answers requests in turn from ``replies`` (the last one repeats) and records them."""

    def __init__(self, *replies: httpx2.Response | Callable[[httpx2.Request], httpx2.Response]) -> None:
        self.replies = list(replies)
        self.requests: list[httpx2.Request] = []

    def __call__(self, request: httpx2.Request) -> httpx2.Response:
        self.requests.append(request)
        reply = self.replies[min(len(self.requests), len(self.replies)) - 1]
        return reply(request) if callable(reply) else reply

    def body(self, i: int = -1) -> dict[str, Any]:
        return json.loads(self.requests[i].content)

    def http_client(self) -> httpx2.Client:
        return httpx2.Client(transport=httpx2.MockTransport(self))


def anthropic_client(server: FakeServer, *, max_retries: int = 0):
    """A real Anthropic client whose HTTP goes to ``server`` (the test skips without the [llm] extra)."""
    anthropic = needs_module("anthropic", "llm")
    return anthropic.Anthropic(api_key="test-key", max_retries=max_retries, http_client=server.http_client())


def openai_client(server: FakeServer, *, max_retries: int = 0):
    """A real OpenAI client whose HTTP goes to ``server`` (the test skips without the [llm] extra)."""
    openai = needs_module("openai", "llm")
    return openai.OpenAI(api_key="test-key", max_retries=max_retries, http_client=server.http_client())


def retry_soon(status: int, body: dict[str, Any]) -> httpx2.Response:
    """An error the SDK retries after 1 ms (the retry-after-ms header), so tests never sleep."""
    return httpx2.Response(status, json=body, headers={"retry-after-ms": "1"})


def anthropic_error(status: int, kind: str, message: str) -> httpx2.Response:
    return retry_soon(status, {"type": "error", "error": {"type": kind, "message": message}})


def messages_reply(
    *blocks: dict[str, Any],
    model: str = "claude-sonnet-5-5",
    stop_reason: str = "tool_use",
    input_tokens: Any = 1000,
    output_tokens: Any = 200,
    stop_details: dict[str, Any] | None = None,
    **usage: Any,
) -> httpx2.Response:
    """A Messages API reply; ``usage`` adds fields such as cache_read_input_tokens."""
    body = {
        "id": "msg_01",
        "type": "message",
        "role": "assistant",
        "model": model,
        "content": list(blocks),
        "stop_reason": stop_reason,
        "stop_sequence": None,
        "usage": {"input_tokens": input_tokens, "output_tokens": output_tokens, **usage},
    }
    if stop_details is not None:
        body["stop_details"] = stop_details
    # json.dumps writes NaN as the bare token NaN, as a broken server might
    return httpx2.Response(200, content=json.dumps(body), headers={"content-type": "application/json"})


def tool_use(name: str, tool_input: Any) -> dict[str, Any]:
    return {"type": "tool_use", "id": "toolu_01", "name": name, "input": tool_input}


def chat_reply(
    *,
    tool_calls: list[tuple[str, str]] = (),
    content: str | None = None,
    finish_reason: str = "tool_calls",
    model: str = "gpt-5.4",
    prompt_tokens: Any = 1000,
    completion_tokens: Any = 200,
    cached_tokens: Any = None,
    reasoning_tokens: Any = None,
) -> httpx2.Response:
    """A Chat Completions reply; ``tool_calls`` are (name, JSON arguments) pairs."""
    message: dict[str, Any] = {"role": "assistant", "content": content}
    if tool_calls:
        message["tool_calls"] = [
            {"id": f"call_{i}", "type": "function", "function": {"name": name, "arguments": arguments}}
            for i, (name, arguments) in enumerate(tool_calls)
        ]
    usage: dict[str, Any] = {"prompt_tokens": prompt_tokens, "completion_tokens": completion_tokens}
    if cached_tokens is not None:
        usage["prompt_tokens_details"] = {"cached_tokens": cached_tokens}
    if reasoning_tokens is not None:
        usage["completion_tokens_details"] = {"reasoning_tokens": reasoning_tokens}
    body = {
        "id": "chatcmpl-1",
        "object": "chat.completion",
        "created": 1_790_000_000,
        "model": model,
        "choices": [{"index": 0, "message": message, "finish_reason": finish_reason, "logprobs": None}],
        "usage": usage,
    }
    return httpx2.Response(200, content=json.dumps(body), headers={"content-type": "application/json"})


def user_text(body: dict[str, Any]) -> str:
    """The user message of a request body, its content blocks joined."""
    content = body["messages"][-1]["content"]
    return content if isinstance(content, str) else "".join(block["text"] for block in content)
