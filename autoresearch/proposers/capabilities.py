"""One table of what each LLM can do and costs: prices (cache rates included), forced tool choice,
effort, and output/context limits. It replaces the old prefix lists of model quirks.

A dated snapshot (``claude-sonnet-4-5-20250929``, ``gpt-5.5-2026-04-23``) takes its alias's row. An
unknown model gets :data:`UNKNOWN`: no forced tool choice (the system prompt demands the call), no
effort field, and a conservative price (see :mod:`autoresearch.proposers.pricing`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Price:
    """USD per million tokens. Cache rates default to the providers' multipliers of the input price:
    reads 0.1x; Anthropic writes 1.25x (5-minute TTL) and 2x (1-hour TTL); OpenAI writes cost nothing
    extra (its cache is automatic), which the OpenAI rows state with ``cache_write=input``."""

    input: float
    output: float
    cache_read: float | None = None
    cache_write: float | None = None
    cache_write_1h: float | None = None

    @property
    def read(self) -> float:
        return self.input * 0.1 if self.cache_read is None else self.cache_read

    @property
    def write(self) -> float:
        return self.input * 1.25 if self.cache_write is None else self.cache_write

    @property
    def write_1h(self) -> float:
        return self.input * 2.0 if self.cache_write_1h is None else self.cache_write_1h


@dataclass(frozen=True)
class Model:
    """price: list price; forced_tool: the API accepts a forced tool choice ("any"/"required");
    effort: the Messages API takes ``output_config.effort``; max_output / context: token limits."""

    price: Price | None
    forced_tool: bool = False
    effort: bool = False
    max_output: int = 64_000
    context: int = 200_000


def _claude(inp: float, out: float, *, forced: bool, effort: bool, context: int = 200_000) -> Model:
    return Model(Price(inp, out), forced_tool=forced, effort=effort, max_output=64_000, context=context)


def _gpt(inp: float, out: float, read: float, *, max_output: int = 128_000, context: int = 400_000) -> Model:
    return Model(
        Price(inp, out, cache_read=read, cache_write=inp, cache_write_1h=inp),
        True,
        False,
        max_output,
        context,
    )


# Prices: list prices for standard requests, November 2026 (platform.claude.com model pages,
# developers.openai.com pricing). Limits of models whose pages give none are the family's.
# Claude 5.x models think adaptively and refuse a forced tool choice with a 400.
MODELS: dict[str, Model] = {
    "claude-fable-5-1": _claude(10.0, 50.0, forced=False, effort=True),
    "claude-fable-5": _claude(10.0, 50.0, forced=False, effort=True),
    "claude-opus-5-5": _claude(4.0, 20.0, forced=False, effort=True),
    "claude-opus-5": _claude(5.0, 25.0, forced=False, effort=True),
    "claude-opus-4-8": _claude(5.0, 25.0, forced=True, effort=True),
    "claude-opus-4-7": _claude(5.0, 25.0, forced=True, effort=True),
    "claude-opus-4-6": _claude(5.0, 25.0, forced=True, effort=True),
    "claude-opus-4-5": _claude(5.0, 25.0, forced=True, effort=True),
    "claude-sonnet-5-5": _claude(2.0, 10.0, forced=False, effort=True),
    "claude-sonnet-5": _claude(2.0, 10.0, forced=False, effort=True),
    "claude-sonnet-4-6": _claude(3.0, 15.0, forced=True, effort=True),
    "claude-sonnet-4-5": _claude(3.0, 15.0, forced=True, effort=False),
    "claude-haiku-5-5": _claude(0.10, 0.50, forced=False, effort=True),  # prompts up to 100k tokens
    "claude-haiku-4-5": _claude(1.0, 5.0, forced=True, effort=False),
    "gpt-6.2-astra": _gpt(8.0, 40.0, 0.80),
    "gpt-6-astra": _gpt(10.0, 50.0, 1.0),
    "gpt-6.2-sol": _gpt(2.0, 10.0, 0.20),
    "gpt-6.1-sol": _gpt(2.0, 10.0, 0.20),
    "gpt-6-sol": _gpt(2.0, 10.0, 0.20),
    "gpt-6-luna": _gpt(0.10, 0.50, 0.01),
    "gpt-5.6-sol": _gpt(4.0, 20.0, 0.40),
    "gpt-5.6-terra": _gpt(2.0, 12.0, 0.20),
    "gpt-5.6-luna": _gpt(0.20, 1.20, 0.02),
    "gpt-5.5": _gpt(5.0, 30.0, 0.50),
    "gpt-5.4": _gpt(2.50, 15.0, 0.25),
    "gpt-4.1": _gpt(2.0, 8.0, 0.50, max_output=32_768, context=1_047_576),
    "gpt-4o": _gpt(2.50, 10.0, 1.25, max_output=16_384, context=128_000),
    "gpt-4o-mini": _gpt(0.15, 0.60, 0.075, max_output=16_384, context=128_000),
}

UNKNOWN = Model(price=None, forced_tool=False, effort=False, max_output=64_000, context=200_000)

_SNAPSHOT_SUFFIX = re.compile(r"-(\d{8}|\d{4}-\d{2}-\d{2})$")


def alias(model: str) -> str:
    """The model id without a dated-snapshot suffix."""
    return _SNAPSHOT_SUFFIX.sub("", model)


def capabilities(model: str) -> Model:
    """The row of ``model`` (or of its alias), :data:`UNKNOWN` when the table has none."""
    return MODELS.get(model) or MODELS.get(alias(model)) or UNKNOWN
