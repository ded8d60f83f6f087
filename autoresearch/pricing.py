"""LLM prices in USD per million tokens, for the campaign's spend cap and its report.

Prices change; the defaults below are list prices for standard (non-batch, uncached, short-context)
requests as published in November 2026. Override or extend them with a JSON object
``{"model-id": {"input": USD_per_Mtok, "output": USD_per_Mtok}, ...}``, given as a file path to
:func:`load_prices` or in the environment variable ``AUTORESEARCH_PRICES`` (a file path, or the JSON
object itself). Entries in the override replace or add to the defaults.

A model with no price (a local vLLM or Ollama model, or a new id) costs 0: this is not an error,
because local models are free, but it is announced once per model with a ``UserWarning``, since the
spend cap cannot protect a campaign whose cost it cannot see.
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

ENV_VAR = "AUTORESEARCH_PRICES"


@dataclass(frozen=True)
class Price:
    """USD per million input and output tokens."""

    input: float
    output: float


DEFAULT_PRICES: dict[str, Price] = {
    # Anthropic: platform.claude.com model pages.
    "claude-fable-5-1": Price(10.0, 50.0),
    "claude-fable-5": Price(10.0, 50.0),
    "claude-opus-5-5": Price(4.0, 20.0),
    "claude-opus-5": Price(5.0, 25.0),
    "claude-opus-4-8": Price(5.0, 25.0),
    "claude-opus-4-7": Price(5.0, 25.0),
    "claude-opus-4-6": Price(5.0, 25.0),
    "claude-opus-4-5": Price(5.0, 25.0),
    "claude-sonnet-5-5": Price(2.0, 10.0),
    "claude-sonnet-5": Price(2.0, 10.0),
    "claude-sonnet-4-6": Price(3.0, 15.0),
    "claude-sonnet-4-5": Price(3.0, 15.0),
    "claude-haiku-5-5": Price(0.10, 0.50),  # prompts up to 100k tokens; 5x above that
    "claude-haiku-4-5": Price(1.0, 5.0),
    # OpenAI: developers.openai.com pricing as reported at release; rates above 272k input tokens are higher.
    "gpt-6.2-astra": Price(8.0, 40.0),
    "gpt-6-astra": Price(10.0, 50.0),
    "gpt-6.2-sol": Price(2.0, 10.0),
    "gpt-6.1-sol": Price(2.0, 10.0),
    "gpt-6-sol": Price(2.0, 10.0),
    "gpt-6-luna": Price(0.10, 0.50),
    "gpt-5.6-sol": Price(4.0, 20.0),
    "gpt-5.6-terra": Price(2.0, 12.0),
    "gpt-5.6-luna": Price(0.20, 1.20),
    "gpt-5.5": Price(5.0, 30.0),
    "gpt-5.4": Price(2.50, 15.0),
    "gpt-4.1": Price(2.0, 8.0),
    "gpt-4o": Price(2.50, 10.0),
    "gpt-4o-mini": Price(0.15, 0.60),
}

# Dated snapshots share their alias's price: claude-sonnet-4-5-20250929, gpt-5.5-2026-04-23.
_SNAPSHOT_SUFFIX = re.compile(r"-(\d{8}|\d{4}-\d{2}-\d{2})$")
_warned: set[str] = set()


def _parse_table(text: str, source: str) -> dict[str, Price]:
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"price table {source} is not valid JSON: {err}") from None
    if not isinstance(raw, dict):
        raise ValueError(f"price table {source} must be a JSON object of model id -> prices")
    table = {}
    for model, entry in raw.items():
        values = [entry.get(k) if isinstance(entry, dict) else None for k in ("input", "output")]
        if not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
            for v in values
        ):
            raise ValueError(
                f'price table {source}: {model!r} must be {{"input": USD, "output": USD}} per million '
                f"tokens, non-negative numbers; got {entry!r}"
            )
        table[model] = Price(float(values[0]), float(values[1]))
    return table


def load_prices(path: str | os.PathLike[str] | None = None) -> dict[str, Price]:
    """The default table updated by the JSON file at ``path``, or else by ``$AUTORESEARCH_PRICES``."""
    prices = dict(DEFAULT_PRICES)
    if path is not None:
        prices.update(_parse_table(Path(path).read_text(), str(path)))
    elif value := os.environ.get(ENV_VAR, "").strip():
        if value.startswith("{"):
            prices.update(_parse_table(value, f"${ENV_VAR}"))
        else:
            prices.update(_parse_table(Path(value).read_text(), f"{value} (from ${ENV_VAR})"))
    return prices


def price_of(model: str, prices: Mapping[str, Price] | None = None) -> Price | None:
    """The price of ``model`` (or of its alias, for a dated snapshot), None when unknown."""
    table = load_prices() if prices is None else prices
    return table.get(model) or table.get(_SNAPSHOT_SUFFIX.sub("", model))


def cost_usd(
    model: str, input_tokens: int, output_tokens: int, prices: Mapping[str, Price] | None = None
) -> float:
    """USD for one call; 0 (with a one-time warning) for a model with no price."""
    price = price_of(model, prices)
    if price is None:
        if model not in _warned:
            _warned.add(model)
            warnings.warn(
                f"no price for model {model!r}: its calls count as $0 and the spend cap cannot limit them; "
                f"set {ENV_VAR} to price it",
                UserWarning,
                stacklevel=2,
            )
        return 0.0
    return (input_tokens * price.input + output_tokens * price.output) / 1e6
