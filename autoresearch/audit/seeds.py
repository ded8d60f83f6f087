"""Fresh seeds: held out from every seed that produced or measured anything so far.

Deterministic on purpose (the smallest unused integers), so an audit re-run with the same
inputs plans the same seeds; each step stores its plan in audit.json before it runs.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from pathlib import Path
from typing import Any

from autoresearch.campaign import Campaign
from autoresearch.campaign.audit_log import read_audit


def fresh_seeds(used: Iterable[int], n: int) -> list[int]:
    """The ``n`` smallest non-negative integers not in ``used``."""
    if n < 1:
        raise ValueError(f"fresh_seeds: need n >= 1 seeds (got {n})")
    taken, seeds, candidate = set(used), [], 0
    while len(seeds) < n:
        if candidate not in taken:
            seeds.append(candidate)
        candidate += 1
    return seeds


def _seeds_in(value: Any) -> set[int]:
    # Every audit step stores its seeds under keys ending in "seeds" (seeds, probe_seeds, ...).
    found: set[int] = set()
    if isinstance(value, dict):
        for key, item in value.items():
            if key.endswith("seeds") and isinstance(item, list):
                found |= {s for s in item if isinstance(s, int)}
            else:
                found |= _seeds_in(item)
    elif isinstance(value, list):
        for item in value:
            found |= _seeds_in(item)
    return found


def used_seeds(
    default_seed: int,
    seed_noise: dict | None,
    campaign_dirs: Iterable[Path] = (),
    skip_step: str | Collection[str] = (),
) -> set[int]:
    """Every seed used so far: the family's default seed and noise seeds, and for each campaign
    directory the seeds of its proposals and runs and every seed its audit planned.

    ``skip_step`` (one step or several) leaves out those audit steps' own plans, so that
    re-planning a step reproduces it (a resumed step finds its runs) and a larger --seeds extends
    it; steps skipped together share one plan (the pruning rules that reuse each other's runs).
    """
    skip = {skip_step} if isinstance(skip_step, str) else set(skip_step)
    used = {default_seed} | _seeds_in(seed_noise or {})
    for campaign in campaign_dirs:
        store = Campaign(campaign)
        used |= {r.seed for r in store.records() if isinstance(r.seed, int)}
        used |= {r["seed"] for r in store.logged_final_metrics() if isinstance(r.get("seed"), int)}
        audit = read_audit(campaign)
        used |= _seeds_in({step: part for step, part in audit.items() if step not in skip})
    return used
