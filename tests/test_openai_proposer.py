"""OpenAIProposer against the real openai SDK, with the network faked at the HTTP layer."""

from __future__ import annotations

import json

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
)

from autoresearch.pricing import Price
from autoresearch.proposers.openai_api import DEFAULT_MODEL, OpenAIProposer
from autoresearch.proposers.tools import PROPOSE, STOP

PROPOSE_CALL = (PROPOSE, json.dumps(PROPOSAL_INPUT))


def _proposer(server: FakeServer, **kwargs) -> OpenAIProposer:
    max_retries = kwargs.pop("max_retries", 2)
    return OpenAIProposer(REGISTRY, client=openai_client(server, max_retries=max_retries), **kwargs)


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
    assert "reasoning_effort" not in body
    assert [t["function"]["name"] for t in body["tools"]] == [PROPOSE, STOP]
    parameters = body["tools"][0]["function"]["parameters"]
    assert parameters["properties"]["axes"]["items"]["enum"] == REGISTRY["axes"]
    assert list(parameters["properties"]["overrides"]["properties"]) == list(REGISTRY["search_space"])

    system, user = body["messages"]
    assert system["role"] == "system" and "exactly one tool" in system["content"]
    positions = [user["content"].index(m) for m in SECTIONS]
    assert positions == sorted(positions)


def test_reasoning_effort_is_sent_only_when_given():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL]))
    _proposer(server, model="gpt-6-sol", reasoning_effort="none").propose(make_context())
    assert server.body()["reasoning_effort"] == "none" and server.body()["model"] == "gpt-6-sol"


def test_base_url_sends_the_request_to_that_server():
    server = FakeServer(chat_reply(tool_calls=[PROPOSE_CALL], model="qwen3-32b"))
    proposer = _proposer(
        server, base_url="http://vllm.local:8000/v1", model="qwen3-32b", prices={"qwen3-32b": Price(0, 0)}
    )
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


def test_rate_limit_then_success_is_retried_by_the_sdk():
    limited = retry_soon(429, {"error": {"message": "Rate limit reached", "type": "requests", "code": None}})
    server = FakeServer(limited, chat_reply(tool_calls=[PROPOSE_CALL]))
    assert _proposer(server).propose(make_context()).kind == "propose"
    assert len(server.requests) == 2


def test_exhausted_retries_become_an_invalid_proposal():
    server = FakeServer(
        retry_soon(503, {"error": {"message": "Service unavailable", "type": "server_error"}})
    )
    proposal = _proposer(server, max_retries=1).propose(make_context())
    assert len(server.requests) == 2
    assert proposal.kind == "invalid" and proposal.error.startswith("api error: ") and "503" in proposal.error


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
