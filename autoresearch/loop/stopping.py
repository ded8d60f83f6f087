"""When a campaign ends (paper Eq. stop) and when the proposer may end it (the stop gate).

Triggers are checked before every iteration, on the state the previous iteration left, in
the paper's fixed precedence; the first active one ends the campaign.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from autoresearch.campaign import CampaignState
from autoresearch.verdicts import plateau

GATE_MIN_EXPERIMENTS = 6
GATE_MIN_AXES = 4
# Statuses that claim success; they are accepted only when the target is actually met.
POSITIVE_STATUSES = frozenset(
    {"success", "successful", "succeeded", "solved", "achieved", "target_met", "target_reached", "met_target"}
)


@dataclass(frozen=True)
class Budgets:
    """Caps of Eq. stop; None means no cap."""

    max_seconds: float | None = None
    max_runs: int | None = None
    max_iters: int | None = None
    max_failures: int = 3
    max_cost_usd: float | None = None
    plateau_window: int = 6
    plateau_kappa: float = 1.0
    # The paper's rule (loop --stop-at-target): reaching the family's target ends the campaign. Off (the
    # default), the target is a report line and the budget is used whole: a target met once, on one
    # seed of the search split, is no reason to stop searching (docs/autoresearch-loop.md).
    stop_at_target: bool = False


@dataclass(frozen=True)
class Trigger:
    name: str
    message: str


def _plateau_active(state: CampaignState, budgets: Budgets) -> bool:
    family = state.family
    return plateau(
        state.scores, family.direction, budgets.plateau_window, budgets.plateau_kappa, family.sigma
    )


def first_trigger(state: CampaignState, budgets: Budgets, elapsed_s: float) -> Trigger | None:
    """The first active trigger of Eq. stop in precedence order, or None."""
    b = budgets
    if b.max_seconds is not None and elapsed_s > b.max_seconds:
        return Trigger("wall_clock", f"wall-clock budget spent ({elapsed_s:.0f} s > {b.max_seconds:g} s)")
    if b.max_runs is not None and state.n_runs_ok >= b.max_runs:
        return Trigger("max_runs", f"{state.n_runs_ok} successful runs reached the cap of {b.max_runs}")
    if b.stop_at_target and state.target_met:
        return Trigger(
            "target_reached",
            f"best {state.best_metric:g} reached the target {state.family.target:g} (run {state.best.run_id})",
        )
    if b.max_iters is not None and state.iterations >= b.max_iters:
        return Trigger("max_iters", f"{state.iterations} iterations reached the cap of {b.max_iters}")
    if state.consecutive_failures >= b.max_failures:
        return Trigger(
            "max_failures", f"{state.consecutive_failures} consecutive failed or invalid iterations"
        )
    if b.max_cost_usd is not None and state.cost_usd > b.max_cost_usd:
        return Trigger("max_cost", f"LLM spend ${state.cost_usd:.4f} exceeded the cap of ${b.max_cost_usd:g}")
    if _plateau_active(state, b):
        return Trigger(
            "plateau",
            f"none of the last {b.plateau_window} successful runs beat the best before them "
            f"by {b.plateau_kappa:g} noise unit(s)",
        )
    return None


def spend_trigger(state: CampaignState, budgets: Budgets, next_call_usd: float) -> Trigger | None:
    """``max_cost`` before a call: when the spend so far plus the next call's projected cost (an
    upper bound from the proposer) would pass the cap, the call is not made."""
    cap = budgets.max_cost_usd
    if cap is None or state.cost_usd + next_call_usd <= cap:
        return None
    return Trigger(
        "max_cost",
        f"LLM spend ${state.cost_usd:.4f} plus the next call's projected ${next_call_usd:.4f} would exceed "
        f"the cap of ${cap:g}",
    )


def closest_trigger(state: CampaignState, budgets: Budgets, elapsed_s: float, blind: bool = False) -> str:
    """A one-line summary of the budget nearest to ending the campaign; ``blind`` leaves out the
    distance to the target (it would reveal the target)."""
    b = budgets
    usage = []  # (fraction used, text)
    if b.max_seconds:
        usage.append((elapsed_s / b.max_seconds, f"time {elapsed_s:.0f}/{b.max_seconds:g} s"))
    if b.max_runs:
        usage.append((state.n_runs_ok / b.max_runs, f"{state.n_runs_ok} of {b.max_runs} runs done"))
    if b.max_iters:
        usage.append((state.iterations / b.max_iters, f"{state.iterations} of {b.max_iters} iterations done"))
    usage.append(
        (
            state.consecutive_failures / b.max_failures,
            f"{state.consecutive_failures} of {b.max_failures} failures in a row",
        )
    )
    if b.max_cost_usd:
        usage.append((state.cost_usd / b.max_cost_usd, f"spend ${state.cost_usd:.2f}/${b.max_cost_usd:g}"))
    _, text = max(usage, key=lambda u: u[0])
    family = state.family
    if state.best is not None and family.target is not None and not blind:
        gap = family.direction * (family.target - state.best_metric)  # > 0: the best is short of it
        text += f" | {gap:.3g} short of the target {family.target:g}" if gap > 0 else " | target reached"
    if _plateau_active(state, b):
        text += " | plateau"
    return text


def stop_gate(
    annotation: dict[str, Any], state: CampaignState, stop_at_target: bool = True
) -> tuple[bool, str]:
    """(accepted, reason) for the proposer's stop request.

    Accepted when the target is met (under the paper's rule, ``stop_at_target``), or after at least
    six completed experiments (the baseline excluded) over at least four distinct axes (axes of
    parameters that differ from the baseline in a completed run, measured from the runs, not from
    the proposer's claims). A status claiming success without the target met is always rejected.
    """
    status = str(annotation.get("status", "")).strip().lower().replace("-", "_").replace(" ", "_")
    if state.target_met and stop_at_target:
        return True, f"target met: best {state.best_metric:g} vs target {state.family.target:g}"
    if status in POSITIVE_STATUSES and not state.target_met:
        # No target value in the reason: it is fed back to the proposer, which may be blind.
        claim = "no target is declared" if state.family.target is None else "the target is not met"
        return False, f"status {annotation.get('status')!r} claims success but {claim}"
    n, axes = state.n_experiments, sorted(state.axes_exercised)
    if n >= GATE_MIN_EXPERIMENTS and len(axes) >= GATE_MIN_AXES:
        return True, f"{n} completed experiments over {len(axes)} axes ({', '.join(axes)})"
    needs = f"at least {GATE_MIN_EXPERIMENTS} experiments over at least {GATE_MIN_AXES} axes"
    if not stop_at_target:  # the target is a report line: reaching it ends nothing
        return False, f"only {n} experiment(s) completed over {len(axes)} axis/axes; a stop needs {needs}"
    return False, (
        f"the target is not met and only {n} experiment(s) completed over {len(axes)} axis/axes; a stop needs "
        f"the target met, or {needs}"
    )
