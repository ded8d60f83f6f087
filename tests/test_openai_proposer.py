"""OpenAIProposer against the real openai SDK, with the network faked at the HTTP layer."""

from __future__ import annotations

import json
import math

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
    chat_reply,
    make_context,
    openai_client,
    retry_soon,
    user_text,
)

from autoresearch.proposers.base import FatalAPIError, TransientAPIError
from autoresearch.proposers.openai_api import DEFAULT_MODEL, OpenAIProposer
from autoresearch.proposers.pricing import Price
from autoresearch.proposers.tools import PROPOSE, STOP

pytestmark = pytest.mark.needs("llm")

PROPOSE_CALL = (PROPOSE, json.dumps(PROPOSAL_INPUT))


def _proposer(server: FakeServer, **kwargs) -> OpenAIProposer:
    return OpenAIProposer(REGISTRY, client=openai_client(server), **kwargs)


def test_default_model_is_a_gpt_the_sdk_knows():
    from openai.types.shared.chat_model import ChatModel

    assert DEFAULT_MODEL in ChatModel.__args__


def test_request_requires_one_call_of_the_two_functions():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL]))
    proposal = _proposer(server).propose(make_context(warnings=("duplicate configuration",)))
    assert proposal.kind == "propose" and proposal.overrides == {"N_DEMOS": 128}
    assert proposal.annotation["failure_prediction"] == {"metric": 6.0, "direction": "above"}

    (request,) = server.requests
    assert str(request.url) == "https://api.openai.com/v1/chat/completions"
    body = server.body()
    assert body["model"] == DEFAULT_MODEL
    assert body["tool_choice"] == "required" and body["parallel_tool_calls"] is False
    assert "reasoning_effort" not in body and body["max_completion_tokens"] == 8192
    assert [t["function"]["name"] for t in body["tools"]] == [PROPOSE, STOP]
    parameters = body["tools"][0]["function"]["parameters"]
    assert parameters["properties"]["axes"]["items"]["enum"] == REGISTRY["axes"]
    assert list(parameters["properties"]["overrides"]["properties"]) == list(REGISTRY["search_space"])

    system, _ = body["messages"]
    assert system["role"] == "system" and "exactly one tool" in system["content"]
    positions = [user_text(body).index(m) for m in SECTIONS]
    assert positions == sorted(positions)


def test_reasoning_effort_is_sent_only_when_given():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL]))
    _proposer(server, model="gpt-6-sol", reasoning_effort="none").propose(make_context())
    assert server.body()["reasoning_effort"] == "none" and server.body()["model"] == "gpt-6-sol"


def test_base_url_sends_the_request_to_that_server():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL], model="qwen3-32b"))
    proposer = _proposer(server, base_url="http://vllm.local:8000/v1", model="qwen3-32b")
    assert proposer.propose(make_context()).kind == "propose"
    url = server.requests[0].url
    assert (url.host, url.port, url.path) == ("vllm.local", 8000, "/v1/chat/completions")


def test_base_url_without_a_key_uses_a_dummy_one(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    proposer = OpenAIProposer(REGISTRY, base_url="http://localhost:11434/v1", model="llama3.3")
    assert proposer.client.api_key == "not-needed"
    assert str(proposer.client.base_url) == "http://localhost:11434/v1/"

    monkeypatch.setenv("OPENAI_API_KEY", "sk-real")
    assert OpenAIProposer(REGISTRY, base_url="http://localhost:11434/v1").client.api_key == "sk-real"


def test_blind_request_holds_neither_target_nor_baseline():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL]))
    _proposer(server).propose(make_context(blind=True))
    raw = server.requests[0].content.decode()
    assert str(TARGET) not in raw and str(BASELINE_METRIC) not in raw


def test_stop_is_parsed_with_its_annotation():
    server = FakeServer(chat_reply(tool_calls=[(STOP, json.dumps(STOP_INPUT))]))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "stop" and proposal.annotation == STOP_INPUT


def test_cost_comes_from_the_usage_block_and_the_price_table():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL], prompt_tokens=9000, completion_tokens=300))
    usage = _proposer(server).propose(make_context()).usage
    assert (usage.input_tokens, usage.output_tokens) == (9000, 300)
    assert usage.cost_usd == pytest.approx((9000 * 2.5 + 300 * 15.0) / 1e6)
    usage = _proposer(server, prices={DEFAULT_MODEL: Price(1.0, 2.0)}).propose(make_context()).usage
    assert usage.cost_usd == pytest.approx((9000 * 1.0 + 300 * 2.0) / 1e6)


def test_cached_and_reasoning_tokens_are_counted():
    server = FakeServer(
        chat_reply(
            tool_calls=[PROPOSE_CALL],
            prompt_tokens=9000,
            completion_tokens=300,
            cached_tokens=8000,
            reasoning_tokens=200,
        )
    )
    usage = _proposer(server).propose(make_context()).usage
    assert (usage.input_tokens, usage.cache_read_tokens, usage.reasoning_tokens) == (9000, 8000, 200)
    assert usage.cost_usd == pytest.approx((1000 * 2.5 + 8000 * 0.25 + 300 * 15.0) / 1e6)


@pytest.mark.parametrize(
    "usage",
    [
        {"prompt_tokens": -3_000_000},
        {"completion_tokens": math.nan},
        {"prompt_tokens": 10, "cached_tokens": 20},
        {"prompt_tokens": 1.5},
    ],
)
def test_untrusted_usage_is_charged_the_maximum(usage):
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL], **usage))
    proposal = _proposer(server, max_tokens=1000).propose(make_context())
    assert proposal.usage.cost_usd == pytest.approx((400_000 * 2.5 + 1000 * 15.0) / 1e6)
    assert proposal.usage.problem


def test_transport_faults_are_raised_and_key_errors_are_fatal():
    limited = retry_soon(429, {"error": {"message": "Rate limit reached", "type": "requests", "code": None}})
    with pytest.raises(TransientAPIError):
        _proposer(FakeServer(limited)).propose(make_context())
    unavailable = retry_soon(503, {"error": {"message": "Service unavailable", "type": "server_error"}})
    server = FakeServer(unavailable)
    with pytest.raises(TransientAPIError, match="503"):
        _proposer(server).propose(make_context())
    assert len(server.requests) == 1

    quota = httpx2.Response(
        429,
        json={
            "error": {
                "message": "You exceeded your current quota",
                "type": "insufficient_quota",
                "code": "insufficient_quota",
            }
        },
    )
    with pytest.raises(FatalAPIError) as caught:
        _proposer(FakeServer(quota)).propose(make_context())
    assert caught.value.kind == "spend_limit"
    bad_key = httpx2.Response(
        401, json={"error": {"message": "Incorrect API key", "code": "invalid_api_key"}}
    )
    with pytest.raises(FatalAPIError, match="credentials"):
        _proposer(FakeServer(bad_key)).propose(make_context())


def test_length_finish_inside_a_tool_call_is_reported_as_truncated():
    server = FakeServer(chat_reply(tool_calls=[(PROPOSE, '{"hypothesis": "More')], finish_reason="length"))
    proposal = _proposer(server, max_tokens=512).propose(make_context())
    assert proposal.kind == "invalid" and proposal.notes["truncated"] is True
    assert "cut off at max_tokens=512 inside its tool call" in proposal.error
    assert server.body()["max_completion_tokens"] == 512


def test_reply_without_a_tool_call_is_invalid():
    server = FakeServer(chat_reply(content="Let me think about it.", finish_reason="stop"))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "invalid"
    assert "got 0" in proposal.error and "finish_reason=stop" in proposal.error and "think" in proposal.error


def test_two_tool_calls_are_invalid():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL, PROPOSE_CALL]))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "invalid" and "got 2" in proposal.error


def test_arguments_that_are_not_json_are_invalid():
    server = FakeServer(chat_reply(tool_calls=[(PROPOSE, '{"hypothesis": "x", "overrides": ')]))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "invalid" and "not valid JSON" in proposal.error
