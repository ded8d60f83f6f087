"""The loop driving a real-SDK LLM proposer over a faked network: transport faults retried and not
counted, a bad key or spent account stops the campaign at once, the spend cap looks one call ahead,
untrusted usage is charged at the maximum, and model text never reaches the terminal raw."""

from __future__ import annotations

import io
import time

import httpx2
import pytest
from llm_support import FakeServer, anthropic_client, anthropic_error, messages_reply, tool_use
from loop_helpers import copy_toy

from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.loop.live import PlainView
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.anthropic_api import AnthropicProposer
from autoresearch.proposers.base import ProposerContext, projected_cost
from autoresearch.proposers.enqueued import EnqueuedProposer
from autoresearch.proposers.random_search import RandomProposer
from autoresearch.proposers.tools import PROPOSE

pytestmark = pytest.mark.needs("llm")


def _proposal(epochs: int, hypothesis: str = "More epochs lower the loss.") -> dict:
    return {
        "hypothesis": hypothesis,
        "overrides": {"EPOCHS": epochs},
        "axes": ["training_budget"],
        "expected_mechanism": "More optimisation steps.",
        "comparison_to_best": "Longer than the best run.",
        "failure_prediction": {"metric": 1.0, "direction": "above"},
    }


def _run(tmp_path, server: FakeServer, **budgets):
    toy = copy_toy(tmp_path)
    family = Family.load(toy)
    proposer = AnthropicProposer(family.registry, client=anthropic_client(server), model="claude-sonnet-4-6")
    stream = io.StringIO()
    budgets.setdefault("max_iters", 3)
    settings = LoopSettings(proposer_name="anthropic", budgets=Budgets(**budgets), timeout_per_run=60.0)
    outcome = Orchestrator(
        family, proposer, tmp_path / "c", settings, view=PlainView(family.metric, stream)
    ).run()
    return outcome, read_jsonl(tmp_path / "c" / "proposals.jsonl"), stream.getvalue()


def test_transport_faults_are_retried_recorded_and_not_failures(tmp_path):
    overloaded = anthropic_error(529, "overloaded_error", "Overloaded")  # retry-after-ms: 1
    server = FakeServer(
        overloaded, overloaded, overloaded, overloaded, messages_reply(tool_use(PROPOSE, _proposal(12)))
    )
    outcome, records, _ = _run(tmp_path, server, max_iters=2, max_failures=1)
    assert outcome.trigger == "max_iters" and records[1]["status"] == "ran"
    faults = records[1]["proposal"]["notes"]["transport_faults"]
    assert len(faults) == 4 and all("529" in f for f in faults)


def test_a_long_retry_after_ends_the_campaign_at_its_wall_clock_budget(tmp_path):
    limited = httpx2.Response(
        429,
        json={"type": "error", "error": {"type": "rate_limit_error", "message": "Slow down"}},
        headers={"retry-after": "3000"},
    )
    server = FakeServer(limited)
    start = time.monotonic()
    outcome, records, _ = _run(tmp_path, server, max_iters=10, max_seconds=600)
    assert time.monotonic() - start < 60 and len(server.requests) == 1
    assert outcome.trigger == "wall_clock" and "429" in outcome.reason
    assert [r["status"] for r in records] == ["ran", "stopped"]


def test_a_runaway_reply_is_refused_and_never_resent(tmp_path):
    huge = _proposal(12, hypothesis="x" * 1_000_000)
    server = FakeServer(
        messages_reply(tool_use(PROPOSE, huge)), messages_reply(tool_use(PROPOSE, _proposal(14)))
    )
    _, records, _ = _run(tmp_path, server, max_iters=3)
    assert records[1]["status"] == "invalid" and "the limit is 2000" in records[1]["reason"]
    assert len(server.requests[1].content) < 50_000 and records[2]["status"] == "ran"


def test_a_bad_key_stops_the_campaign_at_once(tmp_path):
    server = FakeServer(anthropic_error(401, "authentication_error", "invalid x-api-key"))
    outcome, records, _ = _run(tmp_path, server, max_iters=10)
    assert len(server.requests) == 1
    assert (outcome.status, outcome.trigger) == ("stopped", "api_auth")
    assert "invalid x-api-key" in outcome.reason and records[-1]["status"] == "stopped"
    assert [r["status"] for r in records] == ["ran", "stopped"]


def test_the_spend_cap_looks_one_call_ahead(tmp_path):
    server = FakeServer(messages_reply(tool_use(PROPOSE, _proposal(12))))
    # 8192 output tokens at $15/M alone are $0.12: the first call would pass a $0.05 cap
    outcome, records, _ = _run(tmp_path, server, max_cost_usd=0.05)
    assert server.requests == [] and outcome.trigger == "max_cost"
    assert "projected" in outcome.reason and records[-1]["cumulative_cost_usd"] == 0.0


def test_untrusted_usage_is_charged_at_the_maximum_and_recorded(tmp_path):
    server = FakeServer(messages_reply(tool_use(PROPOSE, _proposal(12)), input_tokens=-3_000_000_000))
    outcome, records, _ = _run(tmp_path, server, max_iters=6, max_cost_usd=2.0)
    charged = records[1]
    assert charged["cost_usd"] > 0.5 and "not a token count" in charged["proposal"]["usage"]["problem"]
    assert outcome.trigger == "max_cost"  # the spend cap still sees it


def test_escape_sequences_from_the_model_never_reach_the_terminal(tmp_path):
    hostile = "\x1b]0;owned\x07\x1b[2J"
    server = FakeServer(
        messages_reply({"type": "text", "text": f"no call {hostile}"}, stop_reason="end_turn"),
        messages_reply(tool_use(PROPOSE, _proposal(12, hypothesis=f"epochs {hostile}"))),
    )
    _, records, printed = _run(tmp_path, server, max_iters=3, max_failures=5)
    assert "\x1b" not in printed and "\x07" not in printed and "\\x1b]0;owned" in printed
    assert records[1]["status"] == "invalid" and records[2]["status"] == "ran"
    assert records[2]["proposal"]["annotation"]["hypothesis"] == "epochs \\x1b]0;owned\\x07\\x1b[2J"


def test_the_projection_sees_through_an_enqueued_wrapper(tmp_path):
    family = Family.load(copy_toy(tmp_path))
    llm = AnthropicProposer(family.registry, client=anthropic_client(FakeServer()))
    wrapped = EnqueuedProposer([{"EPOCHS": 12}], llm, family.space)
    context = ProposerContext(1, (), family.program, family.registry, None, (), family.baseline_config)
    assert (
        projected_cost(wrapped, context) == llm.projected_cost(context) > 0.08
    )  # 8192 output tokens at $10/M
    assert (
        projected_cost(EnqueuedProposer([], RandomProposer(family.registry, seed=0), family.space), context)
        == 0
    )
