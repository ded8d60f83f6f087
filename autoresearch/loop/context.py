"""The ProposerContext built from a campaign's state each turn (paper Sec. 3.3); in blind mode it is
stripped of every answer-bearing number. How an LLM sees it laid out: proposers/prompting.py."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from autoresearch.campaign import Campaign, CampaignState, Status
from autoresearch.family import Family, search_view
from autoresearch.proposers.base import ProposerContext

# The registry fields a blind proposer may see: the problem's invariant facts and its search
# space. Target, baseline, best and seed noise (and any field the contract does not define) are
# withheld, so no number hints at what is good.
BLIND_REGISTRY_KEYS = (
    "name",
    "metric",
    "direction",
    "feasibility_field",
    "limits",
    "default_seed",
    "axes",
    "search_space",
)
TOP_K = 5


def shown_registry(registry: dict[str, Any], blind: bool) -> dict[str, Any]:
    """What a proposer is shown of a registry: never a sealed-split number; in blind mode only the
    invariant facts."""
    view = search_view(registry)
    if not blind:
        return view
    return {k: view[k] for k in BLIND_REGISTRY_KEYS if k in view}


def summarize_random_arm(campaign_dir: Path, family: Family) -> str:
    """A compact text summary of a random-search campaign of the same family."""
    arm = Campaign(campaign_dir)
    if not arm.paths.proposals.exists():
        raise FileNotFoundError(f"{arm.paths.proposals}: not found; is {campaign_dir} a campaign directory?")
    if arm.exists() and arm.meta().family_name != family.name:
        raise ValueError(
            f"{campaign_dir} is a campaign of family {arm.meta().family_name!r}, not {family.name!r}"
        )
    records = arm.records()
    ran = [r for r in records if r.ran]
    failed = sum(r.status is Status.FAILED for r in records)
    metric, direction = family.metric, family.direction
    lines = [f"Random-search arm ({arm.root.name}): {len(ran)} successful runs, {failed} failed."]
    ranked = sorted(ran, key=lambda r: (not r.feasible, -direction * r.metric))
    for r in ranked[:TOP_K]:
        flag = "" if r.feasible else " (infeasible)"
        lines.append(f"  {metric}={r.metric:.6g}{flag} at iteration {r.iteration}: {json.dumps(r.config)}")
    return "\n".join(lines)


def training_budget_line(state: CampaignState, time_budget: float | None) -> tuple[str, ...]:
    """The turn's line on the training budget (``loop --time-budget``): how long a run may train and
    which runs used it all up, scored as they stood (their training was cut short); () without one."""
    if time_budget is None:
        return ()
    cut = [r.iteration for r in state.records if r.ran and r.budget_exhausted]
    ran = sum(r.ran for r in state.records)
    text = (
        f"Training budget: each run trains for at most {time_budget:g} s and is then scored as it stands; "
        f"{len(cut)} of {ran} finished runs used it up"
    )
    return (text + (f" (iterations {', '.join(map(str, cut))})" if cut else "") + ".",)


def build_context(
    state: CampaignState,
    *,
    registry: dict[str, Any],
    blind: bool,
    extra_warnings: tuple[str, ...] = (),
    random_arm_summary: str | None = None,
    warm_start_summary: str | None = None,
) -> ProposerContext:
    family = state.family
    history = state.history_blind if blind else state.history_full
    return ProposerContext(
        iteration=state.next_iteration,
        warnings=state.warnings() + extra_warnings,
        program=family.program_blind if blind else family.program,
        registry=shown_registry(registry, blind),
        random_arm_summary=random_arm_summary,
        warm_start_summary=warm_start_summary,
        history=tuple(copy.deepcopy(history)),
        current_values=state.current_values(),
        blind=blind,
    )
