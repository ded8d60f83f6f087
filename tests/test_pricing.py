"""Cost = tokens x the capability table's prices (cache rates included); the table can be
overridden; unknown models cost a conservative fallback, loudly; untrusted counts are refused."""

from __future__ import annotations

import json
import re
import uuid

import pytest

from autoresearch.proposers.capabilities import MODELS, capabilities
from autoresearch.proposers.pricing import (
    DEFAULT_PRICES,
    ENV_VAR,
    FALLBACK_PRICE,
    Price,
    checked_counts,
    cost_usd,
    load_prices,
    price_of,
)


@pytest.fixture(autouse=True)
def _no_env_override(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)


def test_cost_is_tokens_times_price_per_million():
    assert cost_usd("claude-sonnet-5-5", 1_000_000, 0) == pytest.approx(2.0)
    assert cost_usd("claude-sonnet-5-5", 1000, 200) == pytest.approx((1000 * 2.0 + 200 * 10.0) / 1e6)
    assert cost_usd("gpt-5.4", 2000, 500) == pytest.approx((2000 * 2.5 + 500 * 15.0) / 1e6)


def test_current_families_have_defaults():
    for model in (
        "claude-sonnet-5-5",
        "claude-opus-5-5",
        "claude-haiku-5-5",
        "gpt-5.4",
        "gpt-5.5",
        "gpt-6-sol",
    ):
        assert model in DEFAULT_PRICES


def test_dated_snapshots_take_the_alias_price():
    assert price_of("claude-sonnet-4-5-20250929") == DEFAULT_PRICES["claude-sonnet-4-5"]
    assert price_of("gpt-5.5-2026-04-23") == DEFAULT_PRICES["gpt-5.5"]


def test_cache_rates_follow_the_providers_multipliers():
    # 100 input + 5000 cache reads + 500 output on claude-sonnet-5-5 ($2/$10): reads at 0.1x
    assert cost_usd("claude-sonnet-5-5", 100, 500, cache_read_tokens=5000) == pytest.approx(0.0062)
    assert cost_usd("claude-sonnet-5-5", 0, 0, cache_write_tokens=10**6) == pytest.approx(2.5)  # 1.25x
    assert cost_usd("claude-sonnet-5-5", 0, 0, cache_write_1h_tokens=10**6) == pytest.approx(4.0)  # 2x
    assert cost_usd("gpt-5.4", 0, 0, cache_read_tokens=10**6) == pytest.approx(0.25)


def test_one_table_holds_prices_and_capabilities():
    assert set(DEFAULT_PRICES) == set(MODELS)
    assert capabilities("claude-sonnet-4-5-20250929") == MODELS["claude-sonnet-4-5"]
    assert not capabilities("claude-sonnet-5-5").forced_tool and capabilities("claude-sonnet-4-6").forced_tool
    assert capabilities("some-new-model").price is None and not capabilities("some-new-model").forced_tool


def test_unknown_model_costs_the_fallback_with_one_warning(recwarn):
    model = f"claude-fable-{uuid.uuid4().hex[:8]}"
    expected = (10_000 * FALLBACK_PRICE.input + 10_000 * FALLBACK_PRICE.output) / 1e6
    assert cost_usd(model, 10_000, 10_000) == pytest.approx(expected)
    assert cost_usd(model, 10_000, 10_000) == pytest.approx(expected)
    messages = [str(w.message) for w in recwarn.list if issubclass(w.category, UserWarning)]
    assert len(messages) == 1 and model in messages[0] and ENV_VAR in messages[0]
    assert all(
        FALLBACK_PRICE.input >= p.input and FALLBACK_PRICE.output >= p.output for p in DEFAULT_PRICES.values()
    )


def test_a_suffix_that_is_not_a_date_is_a_different_model():
    with pytest.warns(UserWarning, match="gpt-5.4-ultra"):
        assert price_of("gpt-5.4-ultra") is None and cost_usd("gpt-5.4-ultra", 1, 1) > 0


@pytest.mark.parametrize(
    ("counts", "problem"),
    [
        ({"input_tokens": -1}, "usage.input_tokens=-1"),
        ({"input_tokens": float("nan")}, "nan"),
        ({"input_tokens": float("inf")}, "inf"),
        ({"output_tokens": True}, "True"),
        ({"output_tokens": "12"}, "'12'"),
        ({"output_tokens": 2.5}, "2.5"),
        ({"output_tokens": 10**9}, "1000000000"),
    ],
)
def test_counts_that_are_not_token_counts_are_refused(counts, problem):
    clean, why = checked_counts(counts)
    assert clean == {} and problem in why


def test_valid_counts_pass_with_none_as_zero():
    assert checked_counts({"a": 5, "b": None, "c": 7.0}) == ({"a": 5, "b": 0, "c": 7}, None)


def test_file_override_replaces_and_adds(tmp_path):
    path = tmp_path / "prices.json"
    path.write_text(
        json.dumps(
            {
                "claude-sonnet-5-5": {"input": 1.0, "output": 4.0, "cache_read": 0.05},
                "qwen3": {"input": 0, "output": 0},
            }
        )
    )
    prices = load_prices(path)
    assert prices["claude-sonnet-5-5"] == Price(1.0, 4.0, cache_read=0.05)
    assert prices["qwen3"] == Price(0.0, 0.0)
    assert prices["gpt-5.4"] == DEFAULT_PRICES["gpt-5.4"]
    assert cost_usd("claude-sonnet-5-5", 1000, 1000, prices) == pytest.approx(5000 / 1e6)


def test_env_override_as_path_or_inline_json(tmp_path, monkeypatch):
    path = tmp_path / "prices.json"
    path.write_text(json.dumps({"gpt-5.4": {"input": 9, "output": 9}}))
    monkeypatch.setenv(ENV_VAR, str(path))
    assert load_prices()["gpt-5.4"] == Price(9.0, 9.0)
    monkeypatch.setenv(ENV_VAR, '{"gpt-5.4": {"input": 7, "output": 8}}')
    assert load_prices()["gpt-5.4"] == Price(7.0, 8.0)
    assert cost_usd("gpt-5.4", 1_000_000, 1_000_000) == pytest.approx(15.0)


@pytest.mark.parametrize(
    "table",
    [
        '{"m": {"input": 1}}',
        '{"m": {"input": -1, "output": 1}}',
        '{"m": [1, 2]}',
        "[1, 2]",
        "{not json",
        '{"m": {"input": 1, "output": 1, "cache_reed": 0}}',
    ],
)
def test_malformed_override_is_a_clear_error(table, tmp_path):
    path = tmp_path / "prices.json"
    path.write_text(table)
    with pytest.raises(ValueError, match=re.escape(f"price table {path}")):
        load_prices(path)
