"""``autoresearch loop``'s LLM flags and ``--dry-run`` (no key, no network, nothing written)."""

from __future__ import annotations

import json

import pytest
from loop_helpers import copy_toy

from autoresearch.campaign import CampaignMeta
from autoresearch.cli import main
from autoresearch.family import Family
from autoresearch.loop.session import DEFAULTS, build_loop


@pytest.fixture
def toy(tmp_path):
    return copy_toy(tmp_path)


def _body(out: str) -> dict:
    return json.loads(out.split("\n# dry run")[0])


@pytest.mark.needs("llm")
def test_dry_run_prints_the_first_request_and_the_cost_without_a_key(toy, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("ANTHROPIC_API_KEY", raising=False)
    campaign = tmp_path / "c"
    code = main(
        [
            "loop",
            "--family",
            str(toy),
            "--proposer",
            "anthropic",
            "--campaign",
            str(campaign),
            "--dry-run",
            "--max-iters",
            "30",
            "--effort",
            "medium",
            "--max-tokens",
            "4096",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0 and not campaign.exists()
    body = _body(out)
    assert body["model"] == "claude-sonnet-5-5" and body["max_tokens"] == 4096
    assert body["output_config"] == {"effort": "medium"}
    assert body["messages"][0]["content"][0]["cache_control"]["type"] == "ephemeral"
    assert "estimated cost of 30 iterations: $" in out and "with prompt caching" in out


@pytest.mark.needs("llm")
def test_dry_run_for_a_local_server(toy, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    code = main(
        [
            "loop",
            "--family",
            str(toy),
            "--proposer",
            "openai",
            "--base-url",
            "http://127.0.0.1:11434/v1",
            "--model",
            "qwen3:32b",
            "--campaign",
            str(tmp_path / "c"),
            "--dry-run",
        ]
    )
    out = capsys.readouterr().out
    body = _body(out)
    assert code == 0 and body["max_tokens"] == 8192 and "uniqueItems" not in json.dumps(body)
    assert "$0.00 with prompt caching" in out


@pytest.mark.needs("llm")
def test_llm_flags_reach_the_proposer_and_are_kept(toy, tmp_path, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    campaign = tmp_path / "c"
    settings = {**DEFAULTS, "reasoning_effort": "none", "max_tokens": 1000, "profile": "cloud"}
    _, proposer, _ = build_loop(CampaignMeta.new(Family.load(toy), "openai", settings))
    assert proposer.extra == {"max_completion_tokens": 1000, "reasoning_effort": "none"}
    assert not campaign.exists()


def test_a_flag_for_another_proposer_is_a_clear_error(toy, tmp_path, capsys):
    code = main(
        [
            "loop",
            "--family",
            str(toy),
            "--proposer",
            "tpe",
            "--effort",
            "low",
            "--campaign",
            str(tmp_path / "c"),
        ]
    )
    assert code == 2 and "--effort applies to the anthropic proposer" in capsys.readouterr().err


@pytest.mark.needs("llm")  # without the SDK, that is what the one line names
def test_an_anthropic_flag_for_the_openai_proposer_is_a_clear_error(toy, tmp_path, capsys):
    code = main(
        [
            "loop",
            "--family",
            str(toy),
            "--proposer",
            "openai",
            "--effort",
            "low",
            "--base-url",
            "http://x/v1",
            "--campaign",
            str(tmp_path / "d"),
        ]
    )
    assert code == 2 and "--effort applies to the anthropic proposer" in capsys.readouterr().err
