"""One call to the proposer: the spend gate before it, transport faults retried within the wall-clock
budget, and what cannot be retried turned into a reason to stop or an invalid iteration."""

from __future__ import annotations

from dataclasses import dataclass

from autoresearch.campaign import CampaignState
from autoresearch.loop.stopping import Budgets, spend_trigger
from autoresearch.proposers.base import FatalAPIError, Proposal, Proposer, ProposerContext, projected_cost
from autoresearch.proposers.retry import RetryBudgetSpent, call_with_retries


@dataclass(frozen=True)
class Halt:
    """The campaign stops instead of asking: the trigger to record, and why."""

    trigger: str
    reason: str


def ask(
    proposer: Proposer,
    context: ProposerContext,
    state: CampaignState,
    budgets: Budgets,
    seconds_left: float | None,
) -> Proposal | Halt:
    """The proposer's answer, or a Halt when the next call would pass the spend cap, the API refused
    the key or the spend, or the retries spent the wall-clock budget. A proposer that raises or
    returns something else gives an invalid proposal: an iteration, not a crash."""
    trigger = spend_trigger(state, budgets, projected_cost(proposer, context))
    if trigger is not None:
        return Halt(trigger.name, trigger.message)
    try:
        # transport faults are retried here, within the wall-clock budget, and noted, not failed
        proposal = call_with_retries(lambda: proposer.propose(context), seconds_left=seconds_left)
    except FatalAPIError as err:  # no retry heals a bad key or a spent account
        return Halt(f"api_{err.kind}", str(err))
    except RetryBudgetSpent as err:
        return Halt("wall_clock", str(err))
    except Exception as err:  # a proposer bug or an API outage is an invalid iteration, not a crash
        return Proposal(kind="invalid", error=f"the proposer raised {type(err).__name__}: {err}")
    if not isinstance(proposal, Proposal):
        return Proposal(
            kind="invalid", error=f"the proposer returned {type(proposal).__name__}, not a Proposal"
        )
    return proposal
