"""AnthropicProposer against the real anthropic SDK, with the network faked at the HTTP layer."""

from __future__ import annotations

import time

import httpx2
import pytest
from llm_support import (
    BASELINE_METRIC,
    PROPOSAL_INPUT,
    REGISTRY,
    SECTIONS,
    STOP_INPUT,
    TARGET,
    FakeServer,
    anthropic_client,
    anthropic_error,
    make_context,
    messages_reply,
    tool_use,
)

from autoresearch.pricing import Price
from autoresearch.proposers.anthropic_api import DEFAULT_MODEL, AnthropicProposer
from autoresearch.proposers.tools import PROPOSE, STOP


def _proposer(server: FakeServer, **kwargs) -> AnthropicProposer:
    max_retries = kwargs.pop("max_retries", 2)
    return AnthropicProposer(REGISTRY, client=anthropic_client(server, max_retries=max_retries), **kwargs)


def test_default_model_is_a_sonnet_the_sdk_knows():
    from anthropic.types.model_param import ModelParam

    assert "sonnet" in DEFAULT_MODEL and DEFAULT_MODEL in ModelParam.__args__[0].__args__


def test_request_carries_two_tools_one_forced_call_and_the_context():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT), model="claude-sonnet-4-6"))
    proposal = _proposer(server, model="claude-sonnet-4-6").propose(
        make_context(warnings=("last run timed out",))
    )
    assert proposal.kind == "propose" and proposal.overrides == {"N_DEMOS": 128}

    (request,) = server.requests
    assert request.url.path == "/v1/messages"
    body = server.body()
    assert body["model"] == "claude-sonnet-4-6"
    assert body["tool_choice"] == {"type": "any", "disable_parallel_tool_use": True}
    assert [tool["name"] for tool in body["tools"]] == [PROPOSE, STOP]
    propose_schema = body["tools"][0]["input_schema"]
    assert propose_schema["properties"]["axes"]["items"]["enum"] == REGISTRY["axes"]
    assert list(propose_schema["properties"]["overrides"]["properties"]) == list(REGISTRY["search_space"])
    assert body["tools"][1]["input_schema"]["properties"]["axes_tested"]["items"]["enum"] == REGISTRY["axes"]
    assert "exactly one tool" in body["system"]

    (message,) = body["messages"]
    assert message["role"] == "user"
    text = message["content"]
    positions = [text.index(m) for m in SECTIONS]
    assert positions == sorted(positions)
    assert "last run timed out" in text[positions[0] : positions[1]]


def test_models_that_refuse_forcing_get_auto_with_one_tool_use():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)))
    _proposer(server).propose(make_context())
    assert server.body()["model"] == DEFAULT_MODEL
    assert server.body()["tool_choice"] == {"type": "auto", "disable_parallel_tool_use": True}

    _proposer(server, force_tool_choice=True).propose(make_context())
    assert server.body()["tool_choice"] == {"type": "any", "disable_parallel_tool_use": True}


def test_blind_request_holds_neither_target_nor_baseline():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)))
    # The proposer is built from the full registry; only the context is redacted.
    _proposer(server).propose(make_context(blind=True))
    raw = server.requests[0].content.decode()
    assert str(TARGET) not in raw and str(BASELINE_METRIC) not in raw
    assert "program_blind.md" in raw


def test_stop_is_parsed_with_its_annotation():
    server = FakeServer(messages_reply({"type": "text", "text": "Closing."}, tool_use(STOP, STOP_INPUT)))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "stop" and proposal.annotation == STOP_INPUT


def test_cost_comes_from_the_usage_block_and_the_price_table():
    server = FakeServer(
        messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT), input_tokens=12_000, output_tokens=800)
    )
    usage = _proposer(server).propose(make_context()).usage
    assert (usage.input_tokens, usage.output_tokens) == (12_000, 800)
    assert usage.cost_usd == pytest.approx((12_000 * 2.0 + 800 * 10.0) / 1e6)

    cheap = {DEFAULT_MODEL: Price(input=0.5, output=1.0)}
    usage = _proposer(server, prices=cheap).propose(make_context()).usage
    assert usage.cost_usd == pytest.approx((12_000 * 0.5 + 800 * 1.0) / 1e6)


def test_overloaded_then_success_is_retried_by_the_sdk():
    server = FakeServer(
        anthropic_error(529, "overloaded_error", "Overloaded"),
        messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)),
    )
    start = time.monotonic()
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "propose" and len(server.requests) == 2
    assert time.monotonic() - start < 2.0


def test_rate_limit_with_retry_after_ms_then_success():
    server = FakeServer(
        anthropic_error(429, "rate_limit_error", "Slow down"),
        messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)),
    )
    assert _proposer(server).propose(make_context()).kind == "propose"
    assert len(server.requests) == 2
    assert server.requests[1].headers["x-stainless-retry-count"] == "1"


def test_exhausted_retries_become_an_invalid_proposal():
    server = FakeServer(anthropic_error(529, "overloaded_error", "Overloaded"))
    proposal = _proposer(server, max_retries=2).propose(make_context())
    assert len(server.requests) == 3
    assert proposal.kind == "invalid"
    assert (
        proposal.error.startswith("api error: ")
        and "529" in proposal.error
        and "Overloaded" in proposal.error
    )


def test_timeout_becomes_an_invalid_proposal():
    def hang(request: httpx2.Request) -> httpx2.Response:
        raise httpx2.ReadTimeout("timed out", request=request)

    proposal = _proposer(FakeServer(hang), max_retries=0).propose(make_context())
    assert proposal.kind == "invalid" and "timed out" in proposal.error.lower()


def test_bad_request_is_not_retried_and_becomes_invalid():
    server = FakeServer(anthropic_error(400, "invalid_request_error", "tool_choice is not supported"))
    proposal = _proposer(server).propose(make_context())
    assert len(server.requests) == 1
    assert proposal.kind == "invalid" and "tool_choice is not supported" in proposal.error


def test_reply_without_a_tool_call_is_invalid():
    server = FakeServer(
        messages_reply({"type": "text", "text": "I think we should wait."}, stop_reason="end_turn")
    )
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "invalid"
    assert "got 0" in proposal.error and "end_turn" in proposal.error and "wait" in proposal.error
    assert proposal.usage.output_tokens == 200


def test_truncated_reply_says_to_raise_max_tokens():
    thinking = {"type": "thinking", "thinking": "", "signature": "sig"}
    server = FakeServer(messages_reply(thinking, stop_reason="max_tokens"))
    proposal = _proposer(server, max_tokens=1024).propose(make_context())
    assert proposal.kind == "invalid" and "raise max_tokens" in proposal.error
    assert server.body()["max_tokens"] == 1024


@pytest.mark.parametrize(
    "tool_input",
    [
        {k: v for k, v in PROPOSAL_INPUT.items() if k != "hypothesis"},
        PROPOSAL_INPUT | {"overrides": ["N_DEMOS", 128]},
        PROPOSAL_INPUT | {"axes": ["luck"]},
        PROPOSAL_INPUT | {"axes": []},
    ],
)
def test_malformed_tool_input_is_invalid_and_still_costed(tool_input):
    server = FakeServer(messages_reply(tool_use(PROPOSE, tool_input)))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "invalid" and proposal.error.startswith(f"malformed {PROPOSE} call")
    assert proposal.usage.cost_usd > 0
