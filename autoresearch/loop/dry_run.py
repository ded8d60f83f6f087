"""``loop --dry-run``: the first request an LLM proposer would send, and the campaign's estimated cost."""

from __future__ import annotations

import json
import sys
from typing import TextIO

from autoresearch.campaign import CampaignMeta, CampaignState
from autoresearch.extras import require
from autoresearch.family import resolve_family
from autoresearch.loop.context import build_context, shown_registry
from autoresearch.loop.stopping import Budgets, closest_trigger
from autoresearch.proposers import make_proposer
from autoresearch.proposers.llm_options import TYPICAL_OUTPUT_TOKENS, campaign_estimate, llm_kwargs


def dry_run(meta: CampaignMeta, out: TextIO | None = None) -> int:
    """Print the first request the proposer would send and the estimated cost of the campaign."""
    out = out or sys.stdout
    settings, name = meta.settings, meta.proposer
    if name not in ("anthropic", "openai"):
        raise ValueError(f"--dry-run shows an LLM's request; the {name!r} proposer sends none")
    sdk = require(name, "llm", f"--proposer {name}")  # the SDK builds the request it would send
    family = resolve_family(meta.family).under_protocol(settings.get("protocol"))
    blind = settings["blind"]
    client = (
        sdk.Anthropic(api_key="dry-run")
        if name == "anthropic"
        else sdk.OpenAI(api_key="dry-run", base_url=settings["base_url"])
    )
    proposer = make_proposer(
        name,
        shown_registry(family.search_registry(), blind),
        seed=settings["seed"],
        model=settings["model"],
        base_url=settings["base_url"],
        client=client,
        **llm_kwargs(name, settings),
    )
    state = CampaignState.from_records(family, [])
    budgets = Budgets(max_iters=settings["max_iters"], max_cost_usd=settings["max_cost_usd"])
    context = build_context(
        state,
        registry=family.search_registry(),
        blind=blind,
        extra_warnings=(f"Budget: {closest_trigger(state, budgets, 0.0, blind)}",),
    )
    body = proposer.request(context)
    iterations = settings["max_iters"] or 50
    cost = campaign_estimate(proposer, context, iterations)
    print(json.dumps(body, indent=2), file=out)
    print(
        f"\n# dry run: {name} {proposer.model}; the request above is the first (before the baseline's run, "
        f"which the real first call also shows); {len(json.dumps(body))} characters",
        file=out,
    )
    print(
        f"# estimated cost of {iterations} iterations: ${cost['typical_cached']:.2f} with prompt caching, "
        f"${cost['typical_uncached']:.2f} without ({TYPICAL_OUTPUT_TOKENS} output tokens a call); at most "
        f"${cost['worst']:.2f} (max_tokens={proposer.max_tokens} every call, no cache hit); "
        f"spend cap ${settings['max_cost_usd']:g}",
        file=out,
    )
    return 0
