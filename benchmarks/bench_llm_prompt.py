"""Prompt size, prompt-cache hits and campaign cost of the LLM proposers, on a fake 50-iteration campaign.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_llm_prompt.py [--family docking] [--iterations 50]

Each proposer (the real anthropic / openai SDK) is driven for N turns over the family's real
program.md and registry with a history that grows by one synthetic run a turn (a 200-character
hypothesis, a random configuration, six auxiliary metrics). The network is an httpx2 MockTransport
that answers like the API, including its cache accounting (tools + system + user message, ~4
characters a token). Anthropic: a ``cache_control`` breakpoint writes the prefix ending there; a
later request reads the longest such prefix found at one of the 20 block boundaries before each of
its breakpoints, and writes the rest up to its last breakpoint. OpenAI: the cached prefix is the
longest common prefix with the previous request, in multiples of 128 tokens, at least 1024. The proposers then price the calls from that
usage as they would from the real API's; each reply reports 1000 output tokens. "Without caching"
prices the same tokens at the plain input rate. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path

import anthropic
import httpx2
import openai

from autoresearch.family import resolve_family
from autoresearch.loop.context import shown_registry
from autoresearch.proposers.anthropic_api import AnthropicProposer
from autoresearch.proposers.base import ProposerContext
from autoresearch.proposers.openai_api import OpenAIProposer
from autoresearch.proposers.pricing import billed_price
from autoresearch.proposers.tools import PROPOSE

CHARS_PER_TOKEN = 4
OUTPUT_TOKENS = 1000
REPORT_AT = (1, 10, 30, 50)


def _serialise(body: dict) -> tuple[list[str], list[bool]]:
    """The request as the prefix cache sees it: pieces in order, and which end at a breakpoint."""
    pieces, marks = [json.dumps(body["tools"])], [False]
    system = body.get("system")
    messages = body["messages"]
    if system is not None:
        pieces.append(system)
        marks.append(False)
    for message in messages:
        content = message["content"]
        blocks = [{"text": content}] if isinstance(content, str) else content
        for block in blocks:
            pieces.append(block["text"])
            marks.append("cache_control" in block)
    return pieces, marks


def _common(a: str, b: str) -> int:
    n = min(len(a), len(b))
    i = 0
    while i < n and a[i] == b[i]:
        i += 1
    return i


class CachingServer:
    """Answers every call with one propose_experiment call and API-like cache accounting."""

    def __init__(self, kind: str) -> None:
        self.kind, self.previous, self.log = kind, "", []
        self.written: set[str] = set()  # Anthropic: prefixes cached at earlier breakpoints

    def __call__(self, request: httpx2.Request) -> httpx2.Response:
        body = json.loads(request.content)
        pieces, marks = _serialise(body)
        text = "".join(pieces)
        total = len(text) // CHARS_PER_TOKEN
        if self.kind == "anthropic":
            ends = [sum(map(len, pieces[: i + 1])) for i in range(len(pieces))]
            breakpoints = [i for i, m in enumerate(marks) if m]
            hits = [
                ends[j]
                for i in breakpoints
                for j in range(max(0, i - 20), i + 1)
                if text[: ends[j]] in self.written
            ]
            read = max(hits, default=0) // CHARS_PER_TOKEN
            written = (ends[breakpoints[-1]] // CHARS_PER_TOKEN - read) if breakpoints else 0
            self.written.update(text[: ends[i]] for i in breakpoints)
            usage = {
                "input_tokens": total - read - written,
                "cache_read_input_tokens": read,
                "cache_creation_input_tokens": written,
                "output_tokens": OUTPUT_TOKENS,
            }
            reply = {
                "id": "msg",
                "type": "message",
                "role": "assistant",
                "model": body["model"],
                "content": [{"type": "tool_use", "id": "t", "name": PROPOSE, "input": {}}],
                "stop_reason": "tool_use",
                "stop_sequence": None,
                "usage": usage,
            }
        else:
            cached = _common(text, self.previous) // CHARS_PER_TOKEN
            read = 0 if cached < 1024 else cached // 128 * 128
            usage = {
                "prompt_tokens": total,
                "completion_tokens": OUTPUT_TOKENS,
                "prompt_tokens_details": {"cached_tokens": read},
            }
            message = {
                "role": "assistant",
                "content": None,
                "tool_calls": [
                    {"id": "c", "type": "function", "function": {"name": PROPOSE, "arguments": "{}"}}
                ],
            }
            reply = {
                "id": "c",
                "object": "chat.completion",
                "created": 0,
                "model": body["model"],
                "choices": [{"index": 0, "message": message, "finish_reason": "tool_calls"}],
                "usage": usage,
            }
        self.previous = text
        self.log.append((len(request.content), total, read))
        return httpx2.Response(200, json=reply)


def _run_record(rng: random.Random, iteration: int, registry: dict, baseline: dict) -> dict:
    space = registry["search_space"]
    config = dict(baseline)
    for name in rng.sample(sorted(space), k=2):
        spec = space[name]
        if spec["type"] == "categorical":
            config[name] = rng.choice(spec["choices"])
        elif spec["type"] == "bool":
            config[name] = rng.random() < 0.5
        elif spec["type"] == "int":
            config[name] = rng.randint(spec["low"], spec["high"] - 1)
        else:
            config[name] = rng.uniform(spec["low"], spec["high"])
    words = "raising the learning rate should shorten the plateau seen in the previous run because".split()
    return {
        "iteration": iteration,
        "run_id": f"it{iteration:04d}",
        "status": "ok",
        "hypothesis": " ".join(rng.choice(words) for _ in range(35))[:200],
        "overrides": {k: v for k, v in config.items() if v != baseline[k]},
        "config": config,
        registry["metric"]: rng.uniform(0.5, 7.0),
        "feasible": rng.random() < 0.8,
        "verdict": rng.choice(["improved", "not_better", "within_noise"]),
        "auxiliary": {f"aux_{i}": rng.uniform(0, 100) for i in range(6)},
    }


def campaign(kind: str, family_name: str, iterations: int) -> dict:
    family = resolve_family(family_name)
    registry = shown_registry(family.search_registry(), blind=False)
    server = CachingServer(kind)
    http = httpx2.Client(transport=httpx2.MockTransport(server))
    if kind == "anthropic":
        proposer = AnthropicProposer(
            registry, client=anthropic.Anthropic(api_key="x", max_retries=0, http_client=http)
        )
    else:
        proposer = OpenAIProposer(
            registry, client=openai.OpenAI(api_key="x", max_retries=0, http_client=http)
        )
    rng = random.Random(0)
    baseline = family.baseline_config
    history: list[dict] = []
    costs = []
    for i in range(1, iterations + 1):
        history.append(_run_record(rng, i, registry, baseline))
        context = ProposerContext(
            iteration=i + 1,
            warnings=(f"Budget: iterations {i}/{iterations}",),
            program=family.program,
            registry=registry,
            random_arm_summary=None,
            history=tuple(history),
            current_values=dict(baseline),
        )
        costs.append(proposer.propose(context).usage.cost_usd)
    price = billed_price(proposer.model, proposer.prices)
    uncached = sum(total * price.input + OUTPUT_TOKENS * price.output for _, total, _ in server.log) / 1e6
    return {"model": proposer.model, "log": server.log, "cached_cost": sum(costs), "uncached_cost": uncached}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--family", default="docking")
    parser.add_argument("--iterations", type=int, default=50)
    args = parser.parse_args(argv)
    print(
        f"LLM prompt on a fake {args.iterations}-iteration campaign of {args.family} "
        f"(~{CHARS_PER_TOKEN} chars/token, {OUTPUT_TOKENS} output tokens/call)\n"
    )
    print("| proposer (model) | iteration | request bytes | input tokens | cached tokens | cached |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    summaries = []
    for kind in ("anthropic", "openai"):
        result = campaign(kind, args.family, args.iterations)
        log = result["log"]
        for i in REPORT_AT:
            if i <= len(log):
                size, total, read = log[i - 1]
                print(
                    f"| {kind} ({result['model']}) | {i} | {size:,} | {total:,} | {read:,} | {read / total:.0%} |"
                )
        later = log[2:]
        fraction = sum(r for _, _, r in later) / sum(t for _, t, _ in later)
        summaries.append((kind, result, fraction))
    print(
        "\n| proposer (model) | cached share of input tokens, turns 3+ | campaign cost with caching | without |"
    )
    print("| --- | ---: | ---: | ---: |")
    for kind, result, fraction in summaries:
        print(
            f"| {kind} ({result['model']}) | {fraction:.1%} | ${result['cached_cost']:.3f} | "
            f"${result['uncached_cost']:.3f} |"
        )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
