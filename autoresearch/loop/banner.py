"""What ``autoresearch loop`` says before its first run and after its last: the start banner (the
run budget, the caps, the workers and a bound on the campaign's length, so nobody learns an hour
in that a run takes 13 minutes) and, when no run was feasible, which run came closest and by how
much it missed."""

from __future__ import annotations

import math

from autoresearch.campaign import CampaignMeta, CampaignState
from autoresearch.family import Family
from autoresearch.loop.orchestrator import LoopSettings


def duration(seconds: float) -> str:
    """``0.5 s``, ``45 s``, ``12 min``, ``2 h 05 min``."""
    if seconds < 90:
        return f"{seconds:.2g} s" if seconds < 10 else f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def start_banner(meta: CampaignMeta, family: Family, loop: LoopSettings) -> list[str]:
    """The lines printed before the first run: what a run may take, when the campaign stops, and at
    most how long it lasts (a bound: runs that finish early end it sooner)."""
    settings, budgets = meta.settings, loop.budgets
    protocol = f", protocol {settings['protocol']}" if settings.get("protocol") else ""
    workers = f"{loop.workers} worker{'s' if loop.workers != 1 else ''}"
    lines = [f"loop: family {family.name}{protocol}, proposer {meta.proposer}, {workers}"]
    limit = meta.run_timeout
    if meta.time_budget is not None:
        whose = " (the family's default)" if meta.time_budget == family.time_budget else ""
        lines.append(
            f"  each run: {duration(meta.time_budget)} of training{whose}, then up to "
            f"{duration(meta.eval_allowance)} to load, score and save; stopped at {duration(limit)}"
        )
    else:
        lines.append(f"  each run: no training budget; stopped at {duration(limit)} (--timeout-per-run)")
    caps = [f"{budgets.max_iters} iterations" if budgets.max_iters else None]
    if budgets.max_iters == 1:
        caps[0] = "1 iteration (the baseline only: every campaign's first iteration runs it)"
    if budgets.max_runs:
        caps.append(f"{budgets.max_runs} successful runs")
    if budgets.max_seconds:
        caps.append(f"{duration(budgets.max_seconds)} of wall clock")
    if budgets.max_cost_usd and meta.proposer in ("anthropic", "openai"):
        caps.append(f"${budgets.max_cost_usd:g} of LLM spend")
    caps.append(f"{budgets.max_failures} failed iterations in a row")
    caps.append(f"no gain beyond the seed noise over {budgets.plateau_window} runs (plateau)")
    lines.append("  stops at the first of: " + ", ".join(c for c in caps if c))
    runs = min(n for n in (budgets.max_iters, budgets.max_runs, math.inf) if n)
    bound = math.inf if runs == math.inf else math.ceil(runs / loop.workers) * limit
    if budgets.max_seconds:
        bound = min(bound, budgets.max_seconds + limit)  # the runs in flight at the cap finish
    if math.isfinite(bound):
        how = f"{runs} runs of at most {duration(limit)}, {loop.workers} at a time"
        lines.append(f"  campaign length: at most {duration(bound)} ({how}); --max-seconds caps it")
    return lines


def closest_miss(state: CampaignState) -> str:
    """Why no run was feasible, in one clause: the finished run nearest the gate by its graded
    constraints (the largest violation smallest), and what it missed by."""
    family = state.family
    graded = []
    for record in state.records:
        if not record.ran:
            continue
        constraints = family.constraints(record.final_metric)
        if constraints:
            over = {name: value for name, value in constraints.items() if value > 0}
            graded.append((max(over.values(), default=0.0), record, over))
    if not any(r.ran for r in state.records):
        return "no run finished"
    if not graded:
        return "no finished run met the family's feasibility gate"
    _, record, over = min(graded, key=lambda g: g[0])
    misses = ", ".join(
        f"{name} by {value:.3g}" for name, value in sorted(over.items(), key=lambda kv: -kv[1])
    )
    return f"the closest, {record.run_id}, missed {misses or 'the gate'} (each feasible at <= 0)"
