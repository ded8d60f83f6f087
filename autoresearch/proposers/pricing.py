"""LLM spend in USD, for the campaign's spend cap and its report.

The per-model prices live in the capability table (:mod:`autoresearch.proposers.capabilities`),
cache rates included. Override or extend them with a JSON object
``{"model-id": {"input": USD_per_Mtok, "output": USD_per_Mtok, "cache_read"?: ..., "cache_write"?: ...,
"cache_write_1h"?: ...}, ...}``, given as a file path to :func:`load_prices` or in the environment
variable ``AUTORESEARCH_PRICES`` (a file path, or the JSON object itself).

A model with no price is charged at :data:`FALLBACK_PRICE`, above every listed model, with a
one-time ``UserWarning``: a campaign whose spend is invisible would not be protected by the spend
cap. A local model is priced at 0 by the local profile (or by an override).

The server's usage counts are untrusted: :func:`checked_counts` accepts only non-negative integers;
anything else makes the call cost :func:`max_charge`, the most the call could have cost.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from autoresearch.proposers.capabilities import MODELS, Price, alias, capabilities

__all__ = ["DEFAULT_PRICES", "ENV_VAR", "FALLBACK_PRICE", "Price", "cost_usd", "load_prices", "price_of"]

ENV_VAR = "AUTORESEARCH_PRICES"
DEFAULT_PRICES: dict[str, Price] = {model: row.price for model, row in MODELS.items() if row.price}
# Above the dearest listed model (10/50), so an unpriced model trips the spend cap early, not late.
FALLBACK_PRICE = Price(15.0, 75.0)
# No single call reports more tokens than this; a larger count is a server error.
MAX_SANE_TOKENS = 10_000_000
_KEYS = ("input", "output", "cache_read", "cache_write", "cache_write_1h")
_warned: set[str] = set()


def _rate(value: Any) -> bool:
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value >= 0
    )


def _parse_table(text: str, source: str) -> dict[str, Price]:
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"price table {source} is not valid JSON: {err}") from None
    if not isinstance(raw, dict):
        raise ValueError(f"price table {source} must be a JSON object of model id -> prices")
    table = {}
    for model, entry in raw.items():
        ok = (
            isinstance(entry, dict)
            and set(entry) <= set(_KEYS)
            and all(_rate(entry.get(k)) for k in ("input", "output"))
            and all(_rate(entry[k]) for k in _KEYS[2:] if k in entry)
        )
        if not ok:
            raise ValueError(
                f'price table {source}: {model!r} must be {{"input": USD, "output": USD}} per million '
                f"tokens (optionally cache_read, cache_write, cache_write_1h), non-negative numbers; got {entry!r}"
            )
        table[model] = Price(**{k: float(v) for k, v in entry.items()})
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
    return table.get(model) or table.get(alias(model))


def billed_price(model: str, prices: Mapping[str, Price] | None = None) -> Price:
    """The price to charge: the table's, or :data:`FALLBACK_PRICE` with a one-time warning."""
    price = price_of(model, prices)
    if price is None:
        price = FALLBACK_PRICE
        if model not in _warned:
            _warned.add(model)
            warnings.warn(
                f"no price for model {model!r}: charging the fallback ${FALLBACK_PRICE.input:g}/"
                f"${FALLBACK_PRICE.output:g} per million input/output tokens so that the spend cap still "
                f"holds; set {ENV_VAR} to price it (0 for a free local model)",
                UserWarning,
                stacklevel=2,
            )
    return price


def cost_usd(
    model: str,
    input_tokens: int,
    output_tokens: int,
    prices: Mapping[str, Price] | None = None,
    *,
    cache_read_tokens: int = 0,
    cache_write_tokens: int = 0,
    cache_write_1h_tokens: int = 0,
) -> float:
    """USD for one call. ``input_tokens`` are those billed at the plain input rate (not read from or
    written to the cache); reasoning tokens are part of ``output_tokens``, as the APIs bill them."""
    p = billed_price(model, prices)
    return (
        input_tokens * p.input
        + cache_read_tokens * p.read
        + cache_write_tokens * p.write
        + cache_write_1h_tokens * p.write_1h
        + output_tokens * p.output
    ) / 1e6


def checked_counts(counts: Mapping[str, Any]) -> tuple[dict[str, int], str | None]:
    """The counts as ints (None -> 0), or the first problem: each must be a finite integer in
    [0, MAX_SANE_TOKENS]. Booleans and floats with a fraction are refused."""
    clean = {}
    for name, value in counts.items():
        if value is None:
            value = 0
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SANE_TOKENS:
            return {}, f"usage.{name}={value!r} is not a token count"
        clean[name] = value
    return clean, None


def max_charge(model: str, prices: Mapping[str, Price] | None, max_output: int) -> float:
    """The most one call can cost: a full context at the 1-hour cache-write rate (the dearest input
    rate) plus ``max_output`` output tokens."""
    p = billed_price(model, prices)
    return (capabilities(model).context * max(p.input, p.write_1h) + max_output * p.output) / 1e6
