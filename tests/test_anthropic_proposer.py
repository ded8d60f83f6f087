"""AnthropicProposer against the real anthropic SDK, with the network faked at the HTTP layer."""

from __future__ import annotations

import math
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
    user_text,
)

from autoresearch.proposers.anthropic_api import DEFAULT_MODEL, LONG_GAP_S, AnthropicProposer
from autoresearch.proposers.base import FatalAPIError, TransientAPIError
from autoresearch.proposers.pricing import FALLBACK_PRICE, Price
from autoresearch.proposers.tools import PROPOSE, STOP

pytestmark = pytest.mark.needs("llm")


def _proposer(server: FakeServer, **kwargs) -> AnthropicProposer:
    return AnthropicProposer(REGISTRY, client=anthropic_client(server), **kwargs)


def test_default_model_is_a_sonnet_the_sdk_knows():
    from anthropic.types.model_param import ModelParam

    assert "sonnet" in DEFAULT_MODEL and DEFAULT_MODEL in ModelParam.__args__[0].__args__


def test_default_client_leaves_retries_to_the_orchestrator_and_waits_on_reads():
    proposer = AnthropicProposer(REGISTRY, timeout=123.0)
    assert proposer.client.max_retries == 0
    assert proposer.client.timeout.read == 123.0 and proposer.client.timeout.connect == 10.0


def test_request_carries_two_tools_one_forced_call_and_a_cacheable_context():
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
    assert "exactly one tool" in body["system"]

    (message,) = body["messages"]
    text = user_text(body)
    positions = [text.index(m) for m in SECTIONS]
    assert positions == sorted(positions)
    assert "last run timed out" in text[positions[5] : positions[6]]
    # breakpoints: the stable prefix and the last history block; the volatile tail comes after both
    blocks = message["content"]
    marked = [i for i, block in enumerate(blocks) if "cache_control" in block]
    assert marked == [0, len(blocks) - 2]
    assert blocks[0]["cache_control"] == {"type": "ephemeral", "ttl": "5m"}
    assert blocks[0]["text"].startswith("## Program") and "Budget" not in blocks[0]["text"]
    assert blocks[-1]["text"].startswith("\n## Runs in flight") and "last run timed out" in blocks[-1]["text"]


def test_ttl_turns_to_one_hour_when_calls_are_far_apart():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)))
    proposer = _proposer(server)
    proposer.propose(make_context())
    proposer._last_call = time.monotonic() - LONG_GAP_S - 1  # as if the last run took minutes
    proposer.propose(make_context())
    ttls = [
        b["cache_control"]["ttl"] for b in server.body()["messages"][0]["content"] if "cache_control" in b
    ]
    assert ttls == ["1h", "1h"]
    _proposer(server, cache_ttl="off").propose(make_context())
    assert not any("cache_control" in b for b in server.body()["messages"][0]["content"])


def test_capability_table_decides_forcing_effort_and_the_output_cap():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)))
    _proposer(server, max_tokens=10**6).propose(make_context())
    body = server.body()
    assert body["model"] == DEFAULT_MODEL
    assert body["tool_choice"] == {"type": "auto", "disable_parallel_tool_use": True}
    assert body["output_config"] == {"effort": "low"} and "thinking" not in body
    assert body["max_tokens"] == 21_000  # the most the SDK sends without streaming

    _proposer(server, force_tool_choice=True, thinking="disabled", effort="medium").propose(make_context())
    body = server.body()
    assert body["tool_choice"]["type"] == "any" and body["thinking"] == {"type": "disabled"}
    assert body["output_config"] == {"effort": "medium"}

    # an unknown model: no forcing (it might 400), no effort field (it might not take one)
    with pytest.warns(UserWarning, match="no price for model 'claude-fable-5-2'"):
        _proposer(server, model="claude-fable-5-2").propose(make_context())
    assert server.body()["tool_choice"]["type"] == "auto" and "output_config" not in server.body()


def test_blind_request_holds_neither_target_nor_baseline():
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT)))
    _proposer(server).propose(make_context(blind=True))
    raw = server.requests[0].content.decode()
    assert str(TARGET) not in raw and str(BASELINE_METRIC) not in raw
    assert "program_blind.md" in raw


def test_stop_is_parsed_with_its_annotation():
    server = FakeServer(messages_reply({"type": "text", "text": "Closing."}, tool_use(STOP, STOP_INPUT)))
    proposal = _proposer(server).propose(make_context())
    assert proposal.kind == "stop" and proposal.annotation == STOP_INPUT


def test_cost_prices_cache_reads_and_writes_at_their_rates():
    server = FakeServer(
        messages_reply(
            tool_use(PROPOSE, PROPOSAL_INPUT),
            input_tokens=100,
            output_tokens=500,
            cache_read_input_tokens=5000,
            cache_creation_input_tokens=0,
            output_tokens_details={"thinking_tokens": 300},
        )
    )
    usage = _proposer(server).propose(make_context()).usage
    assert (usage.input_tokens, usage.cache_read_tokens, usage.output_tokens) == (5100, 5000, 500)
    assert usage.reasoning_tokens == 300
    assert usage.cost_usd == pytest.approx((100 * 2.0 + 5000 * 0.2 + 500 * 10.0) / 1e6)  # $0.0062

    server = FakeServer(
        messages_reply(
            tool_use(PROPOSE, PROPOSAL_INPUT),
            input_tokens=10,
            output_tokens=0,
            cache_creation_input_tokens=3000,
            cache_creation={"ephemeral_5m_input_tokens": 1000, "ephemeral_1h_input_tokens": 2000},
        )
    )
    usage = _proposer(server, prices={DEFAULT_MODEL: Price(1.0, 1.0)}).propose(make_context()).usage
    assert usage.cache_write_tokens == 3000
    assert usage.cost_usd == pytest.approx((10 * 1.0 + 1000 * 1.25 + 2000 * 2.0) / 1e6)


@pytest.mark.parametrize(
    "usage",
    [
        {"input_tokens": -5_000_000},
        {"input_tokens": math.nan},
        {"output_tokens": True},
        {"cache_read_input_tokens": -1},
        {"input_tokens": 10**12},
    ],
)
def test_untrusted_usage_is_charged_the_maximum_and_recorded(usage):
    server = FakeServer(messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT), **usage))
    proposal = _proposer(server, max_tokens=1000).propose(make_context())
    assert proposal.kind == "propose"
    # a full 200k context at the dearest input rate plus max_tokens of output: far above a real call
    assert proposal.usage.cost_usd == pytest.approx((200_000 * 4.0 + 1000 * 10.0) / 1e6)
    assert proposal.usage.problem and "not a token count" in proposal.usage.problem


def test_unknown_model_is_charged_the_fallback_with_a_warning():
    server = FakeServer(
        messages_reply(tool_use(PROPOSE, PROPOSAL_INPUT), input_tokens=1000, output_tokens=100)
    )
    with pytest.warns(UserWarning, match="claude-mythos-9"):
        usage = _proposer(server, model="claude-mythos-9").propose(make_context()).usage
    assert usage.cost_usd == pytest.approx((1000 * FALLBACK_PRICE.input + 100 * FALLBACK_PRICE.output) / 1e6)


def test_transport_faults_are_raised_for_the_orchestrator_to_retry():
    server = FakeServer(anthropic_error(529, "overloaded_error", "Overloaded"))
    with pytest.raises(TransientAPIError, match=r"529.*Overloaded"):
        _proposer(server).propose(make_context())
    assert len(server.requests) == 1  # the SDK did not retry on its own

    limited = httpx2.Response(
        429,
        json={"type": "error", "error": {"type": "rate_limit_error", "message": "Slow down"}},
        headers={"retry-after": "30"},
    )
    with pytest.raises(TransientAPIError) as caught:
        _proposer(FakeServer(limited)).propose(make_context())
    assert caught.value.retry_after == 30.0

    def hang(request: httpx2.Request) -> httpx2.Response:
        raise httpx2.ReadTimeout("timed out", request=request)

    with pytest.raises(TransientAPIError, match=r"(?i)timed out"):
        _proposer(FakeServer(hang)).propose(make_context())


@pytest.mark.parametrize(
    ("status", "kind", "message", "fatal"),
    [
        (401, "authentication_error", "invalid x-api-key", "auth"),
        (403, "permission_error", "not allowed", "auth"),
        (402, "billing_error", "payment required", "spend_limit"),
        (400, "invalid_request_error", "Your credit balance is too low to access the API", "spend_limit"),
        (429, "rate_limit_error", "You have reached your specified API usage limits", "spend_limit"),
    ],
)
def test_key_and_spend_errors_are_fatal(status, kind, message, fatal):
    server = FakeServer(anthropic_error(status, kind, message))
    with pytest.raises(FatalAPIError) as caught:
        _proposer(server).propose(make_context())
    assert caught.value.kind == fatal and str(status) in str(caught.value)


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


def test_refusal_is_recorded_with_its_category():
    server = FakeServer(
        messages_reply(
            stop_reason="refusal",
            stop_details={"type": "refusal", "category": "frontier_llm", "explanation": "Restricted use."},
        )
    )
    proposal = _proposer(server).propose(make_context())
    assert (
        proposal.kind == "invalid" and "refused (category: frontier_llm): Restricted use." in proposal.error
    )
    assert proposal.notes["refusal"] == {"category": "frontier_llm", "explanation": "Restricted use."}


def test_a_tool_call_cut_off_at_max_tokens_is_reported_as_truncated():
    cut = tool_use(PROPOSE, {"hypothesis": "More demonstrations"})
    proposal = _proposer(FakeServer(messages_reply(cut, stop_reason="max_tokens")), max_tokens=1024).propose(
        make_context()
    )
    assert proposal.kind == "invalid" and proposal.notes == {"truncated": True}
    assert "cut off at max_tokens=1024 inside its tool call" in proposal.error

    thinking = {"type": "thinking", "thinking": "", "signature": "sig"}
    proposal = _proposer(FakeServer(messages_reply(thinking, stop_reason="max_tokens"))).propose(
        make_context()
    )
    assert "before its tool call" in proposal.error and "raise --max-tokens" in proposal.error


def test_escape_sequences_in_model_text_are_made_visible():
    hostile = PROPOSAL_INPUT | {"hypothesis": "More data\x1b]0;pwned\x07 \x1b[2J now"}
    proposal = _proposer(FakeServer(messages_reply(tool_use(PROPOSE, hostile)))).propose(make_context())
    assert proposal.kind == "propose"
    assert proposal.annotation["hypothesis"] == "More data\\x1b]0;pwned\\x07 \\x1b[2J now"

    prose = messages_reply({"type": "text", "text": "no\x1b[31m call\x9b"}, stop_reason="end_turn")
    proposal = _proposer(FakeServer(prose)).propose(make_context())
    assert "\x1b" not in proposal.error and "\x9b" not in proposal.error and "\\x1b[31m" in proposal.error


def test_a_runaway_field_is_an_invalid_proposal():
    huge = PROPOSAL_INPUT | {"hypothesis": "x" * 1_000_000}
    proposal = _proposer(FakeServer(messages_reply(tool_use(PROPOSE, huge)))).propose(make_context())
    assert (
        proposal.kind == "invalid"
        and "'hypothesis' is 1000000 characters long; the limit is 2000" in proposal.error
    )
    assert len(proposal.error) < 300


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
