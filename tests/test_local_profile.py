"""The local profile against fake vLLM and Ollama servers (real openai SDK, faked HTTP)."""

from __future__ import annotations

import json

import httpx2
import pytest
from llm_support import PROPOSAL_INPUT, REGISTRY, FakeServer, chat_reply, make_context, openai_client

from autoresearch.proposers.openai_api import OpenAIProposer
from autoresearch.proposers.tools import LOCAL_UNSUPPORTED, PROPOSE

pytestmark = pytest.mark.needs("llm")


def _keywords(value, found=None):
    found = set() if found is None else found
    if isinstance(value, dict):
        for key, item in value.items():
            found.add(key)
            _keywords(item, found)
    elif isinstance(value, list):
        for item in value:
            _keywords(item, found)
    return found


def vllm(request: httpx2.Request) -> httpx2.Response:
    """Like a vLLM guided-decoding back-end that knows no uniqueItems/minProperties."""
    body = json.loads(request.content)
    unsupported = _keywords([t["function"]["parameters"] for t in body["tools"]]) & {
        "uniqueItems",
        "minProperties",
    }
    if unsupported:
        return httpx2.Response(
            400,
            json={"object": "error", "message": f"unsupported keywords {sorted(unsupported)}", "code": 400},
        )
    return chat_reply(tool_calls=[(PROPOSE, json.dumps(PROPOSAL_INPUT))], model=body["model"])


def ollama_prose(text: str, prompt_tokens: int = 9000):
    """Like Ollama: ignores tool_choice and answers in prose; counts only the prompt it kept."""

    def reply(request: httpx2.Request) -> httpx2.Response:
        return chat_reply(content=text, finish_reason="stop", model="qwen3:32b", prompt_tokens=prompt_tokens)

    return reply


def _local(server: FakeServer, **kwargs) -> OpenAIProposer:
    return OpenAIProposer(
        REGISTRY,
        client=openai_client(server),
        base_url="http://127.0.0.1:8000/v1",
        model="Qwen/Qwen3-32B",
        **kwargs,
    )


def test_vllm_gets_a_schema_it_accepts_and_an_output_cap():
    server = FakeServer(vllm)
    proposal = _local(server, max_tokens=2048, reasoning_effort="low").propose(make_context())
    assert proposal.kind == "propose" and proposal.usage.cost_usd == 0.0
    body = server.body()
    assert not _keywords(body["tools"]) & set(LOCAL_UNSUPPORTED)
    assert body["max_tokens"] == 2048 and "max_completion_tokens" not in body
    assert "reasoning_effort" not in body
    # the schema still names every parameter (a property is kept even if named like a keyword)
    assert list(body["tools"][0]["function"]["parameters"]["properties"]["overrides"]["properties"]) == list(
        REGISTRY["search_space"]
    )


def test_the_cloud_schema_is_what_vllm_would_refuse():
    server = FakeServer(vllm)
    proposal = _local(server, profile="cloud").propose(make_context())
    assert proposal.kind == "invalid" and "unsupported keywords" in proposal.error


def test_ollama_prose_with_a_json_tool_call_is_accepted():
    call = json.dumps({"name": PROPOSE, "arguments": PROPOSAL_INPUT})
    server = FakeServer(ollama_prose(f"Here is my proposal:\n```json\n{call}\n```"))
    proposal = _local(server).propose(make_context())
    assert proposal.kind == "propose" and proposal.overrides == {"N_DEMOS": 128}
    assert proposal.notes["tool_call_in_prose"] is True


def test_ollama_plain_prose_is_invalid_and_a_cut_prompt_is_noted():
    server = FakeServer(ollama_prose("I would increase the data, maybe.", prompt_tokens=512))
    proposal = _local(server).propose(make_context())
    assert proposal.kind == "invalid" and "got 0" in proposal.error and "increase the data" in proposal.error
    assert "num_ctx" in proposal.notes["context_truncated"] and "512" in proposal.notes["context_truncated"]


def test_profile_is_checked():
    with pytest.raises(ValueError, match="profile must be one of"):
        OpenAIProposer(REGISTRY, client=openai_client(FakeServer()), profile="edge")
