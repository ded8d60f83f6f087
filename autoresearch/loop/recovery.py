"""Finishing the iterations a dead loop left in flight (``loop --resume``).

Every intent without a record is finished: what is left of its run is killed (every process
carrying its run directory, wherever it moved: autoresearch.execution.tracking), then its outcome is
adopted from ``result.json`` (the runner's verdict, read as untrusted input since the run could
write it: autoresearch.execution.runner.saved_run) or from the run's line in runs.jsonl (train.py
finished, with the intent's config and seed), or it is recorded as timed out (still running past
its deadline, or killed there by its watchdog); otherwise it is re-run under a new run id
(``<run_id>-r2``, ...), listing the lost attempts in ``interrupted_run_ids``. No iteration and no
run id is recorded twice.
"""

from __future__ import annotations

from autoresearch.campaign import Campaign, CampaignState, Intent
from autoresearch.execution.processes import stop_orphaned_run
from autoresearch.execution.result import RunResult
from autoresearch.execution.runner import logged_run, saved_run
from autoresearch.family import Family


def adopt(campaign: Campaign, family: Family, intent: Intent, timeout: float) -> RunResult | None:
    """The outcome of an in-flight run whose supervisor died, if it finished or ran out of time
    (past its deadline at resume, or killed there by its watchdog); None otherwise."""
    spec = campaign.run_spec(family, intent, timeout)
    leftover = stop_orphaned_run(spec.run_dir)  # first: nothing of it may write beside a re-run
    result = saved_run(spec)
    if result is not None:
        return result
    logged = logged_run(spec)
    if logged is not None:
        return logged
    if leftover.overdue is not None:
        return RunResult("timeout", intent.run_id, None, leftover.overdue, None, None)
    return None


def pending(campaign: Campaign, state: CampaignState) -> tuple[list[Intent], list[Intent]]:
    """(live, superseded) intents of unrecorded iterations. Several intents of one iteration are
    pending only after a crash during a re-run: its latest attempt is the live one; any other, or
    one whose iteration is recorded, is superseded."""
    live: dict[int, Intent] = {}
    superseded = []
    for intent in campaign.in_flight(state):
        if intent.iteration in state.recorded:
            superseded.append(intent)
            continue
        other = live.get(intent.iteration)
        if other is not None:
            older, intent = sorted((other, intent), key=lambda i: len(i.interrupted_run_ids or ()))
            superseded.append(older)
        live[intent.iteration] = intent
    return [live[i] for i in sorted(live)], superseded


def retire(campaign: Campaign, intent: Intent, why: str) -> None:
    """Kill what is left of a superseded attempt and mark it, so that no resume looks at it again."""
    stop_orphaned_run(campaign.paths.run_dir(intent.run_id))
    campaign.mark_interrupted(intent.run_id, why)
