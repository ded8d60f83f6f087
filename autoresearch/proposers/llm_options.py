"""The LLM proposers' command-line flags and the cost estimate ``loop --dry-run`` prints.

The defaults keep a 50-iteration campaign cheap: Claude at ``--effort low`` (thinking dominates the
output cost at the API's default high effort) with at most 8192 output tokens a call, prompt caching
on, and the OpenAI models at their default reasoning with the same output cap.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

# Settings kept in campaign.json (None: the proposer's default); flags given on --resume override them.
LLM_DEFAULTS: dict[str, Any] = {
    "max_tokens": None,
    "effort": None,
    "thinking": None,
    "llm_timeout": None,
    "reasoning_effort": None,
    "profile": None,
    "cache_ttl": None,
}
# setting -> (constructor keyword, proposers that take it)
_KWARGS = {
    "max_tokens": ("max_tokens", ("anthropic", "openai")),
    "llm_timeout": ("timeout", ("anthropic", "openai")),
    "effort": ("effort", ("anthropic",)),
    "thinking": ("thinking", ("anthropic",)),
    "cache_ttl": ("cache_ttl", ("anthropic",)),
    "reasoning_effort": ("reasoning_effort", ("openai",)),
    "profile": ("profile", ("openai",)),
}
TYPICAL_OUTPUT_TOKENS = 1000  # a tool call with its annotation and some low-effort thinking
CHARS_PER_TOKEN = 4.0  # for the estimate; the projection before each call uses a safer 3


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def add_llm_arguments(parser: argparse.ArgumentParser) -> None:
    """The LLM flags of ``autoresearch loop`` (docs/llm-proposers.md)."""
    g = parser.add_argument_group("LLM proposers")
    g.add_argument(
        "--max-tokens", type=_positive_int, help="output cap per call, thinking included (default 8192)"
    )
    g.add_argument(
        "--effort", choices=("low", "medium", "high", "xhigh", "max"), help="Claude effort (default low)"
    )
    g.add_argument(
        "--thinking", choices=("adaptive", "disabled"), help="Claude thinking (default: the model's)"
    )
    g.add_argument(
        "--llm-timeout", type=_positive_float, help="seconds to wait for a reply's bytes (default 600)"
    )
    g.add_argument(
        "--reasoning-effort",
        choices=("none", "minimal", "low", "medium", "high", "xhigh"),
        help="OpenAI reasoning effort (default: the model's; not sent to local servers)",
    )
    g.add_argument(
        "--profile",
        choices=("auto", "cloud", "local"),
        help="openai: 'local' for vLLM/Ollama (default auto: local with --base-url)",
    )
    g.add_argument(
        "--cache-ttl", choices=("auto", "5m", "1h", "off"), help="Claude prompt-cache TTL (default auto)"
    )
    g.add_argument(
        "--dry-run",
        action="store_true",
        help="print the first request and the campaign's estimated cost; call nothing (no key needed)",
    )


def llm_kwargs(proposer: str, settings: dict[str, Any]) -> dict[str, Any]:
    """The constructor keywords of ``proposer`` that ``settings`` sets; a flag for the other LLM
    proposer is an error (a key-free proposer takes none)."""
    kwargs = {}
    for setting, (keyword, takers) in _KWARGS.items():
        if settings.get(setting) is None:
            continue
        if proposer not in takers:
            flag = "--" + setting.replace("_", "-")
            raise ValueError(f"{flag} applies to the {' and '.join(takers)} proposer(s), not to {proposer!r}")
        kwargs[keyword] = settings[setting]
    return kwargs


def campaign_estimate(proposer: Any, context: Any, iterations: int) -> dict[str, float]:
    """Estimated USD of ``iterations`` calls: the history grows by one run per call; with caching,
    all but the newest run and the tail are cache reads (Anthropic: the newest run is a 5-minute
    write); ``typical`` assumes TYPICAL_OUTPUT_TOKENS per call, ``worst`` max_tokens and no cache hit."""
    from autoresearch.proposers.pricing import billed_price
    from autoresearch.proposers.prompting import render_prompt, run_line

    prompt = render_prompt(context)
    body = proposer.request(context)
    system = body.get("system") or body["messages"][0]["content"]
    fixed = len(json.dumps(body["tools"])) + len(system) + len(prompt.stable)
    per_run = len(run_line(_typical_run(context), context.current_values)) + 1
    tail = len(prompt.tail)
    price = billed_price(proposer.model, proposer.prices)
    write_rate = price.write if proposer.name == "anthropic" else price.input
    cached = uncached = worst = 0.0
    for i in range(1, iterations + 1):
        prefix = (fixed + (i - 1) * per_run) / CHARS_PER_TOKEN
        new = (per_run + tail) / CHARS_PER_TOKEN
        out = min(TYPICAL_OUTPUT_TOKENS, proposer.max_tokens) * price.output
        first = prefix * (write_rate if i == 1 else price.read)
        cached += (
            first + per_run / CHARS_PER_TOKEN * write_rate + tail / CHARS_PER_TOKEN * price.input + out
        ) / 1e6
        uncached += ((prefix + new) * price.input + out) / 1e6
        worst += ((prefix + new) * max(price.input, write_rate) + proposer.max_tokens * price.output) / 1e6
    return {"typical_cached": cached, "typical_uncached": uncached, "worst": worst}


def _typical_run(context: Any) -> dict[str, Any]:
    metric = context.registry.get("metric", "metric")
    return {
        "iteration": 2,
        "run_id": "it0002",
        "status": "ok",
        "hypothesis": "x" * 300,
        "config": {**context.current_values, **dict.fromkeys(list(context.current_values)[:2], 0.123456)},
        metric: 1.23456,
        "feasible": True,
        "verdict": "improved",
        "auxiliary": {"wall_seconds": 12.3456, "train_loss": 0.123456},
    }
