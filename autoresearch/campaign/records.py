"""One proposals.jsonl record: what happened in one iteration of a campaign, typed.

On disk a record is one JSON object per line with every field below, unset ones null, in this
order, and ``schema``. Schema 2 (this one) writes ``early_stopped`` for a run stopped by the early
stopper and ``final_metric`` for the run's FINAL_METRIC object; schema 1 (campaigns written before,
no ``schema`` key) wrote ``pruned`` and ``record``. Both read into the same :class:`Record`, so
every committed campaign loads unchanged.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime, timezone
from enum import Enum
from typing import Any

from autoresearch.campaign.paths import CampaignError

SCHEMA = 2
BASELINE_PROPOSER = "baseline"


class Status(str, Enum):
    """What an iteration came to. A str, so that it is its own JSON value."""

    RAN = "ran"  # the run finished with a valid FINAL_METRIC
    FAILED = "failed"  # the run failed, crashed or ran out of time
    EARLY_STOPPED = "early_stopped"  # the early stopper ended the run (schema 1: "pruned")
    INVALID = "invalid"  # the proposal was refused; nothing ran
    STOP_ACCEPTED = "stop_accepted"  # the proposer asked to stop and the stop gate agreed
    STOP_REJECTED = "stop_rejected"  # the proposer asked to stop and the gate refused
    STOPPED = "stopped"  # a stopping trigger ended the campaign (the loop's own record)

    @property
    def started_a_run(self) -> bool:
        return self in RUN_STATUSES

    @property
    def ends_campaign(self) -> bool:
        return self in TERMINAL

    @property
    def counts_as_failure(self) -> bool:
        """Counted by the consecutive-failures trigger: nothing came of the iteration."""
        return self in (Status.FAILED, Status.INVALID, Status.STOP_REJECTED)


RUN_STATUSES = frozenset({Status.RAN, Status.FAILED, Status.EARLY_STOPPED})
TERMINAL = frozenset({Status.STOP_ACCEPTED, Status.STOPPED})
_LEGACY_STATUS = {"pruned": Status.EARLY_STOPPED}
_LEGACY_KEYS = {"record": "final_metric"}


def parse_status(value: Any) -> Status | None:
    """The Status a record's ``status`` value names (schema 1 or 2), or None."""
    try:
        return _LEGACY_STATUS.get(value) or Status(value)
    except (ValueError, TypeError):
        return None


def now() -> str:
    """A record's time stamp: UTC, to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


@dataclass(frozen=True)
class Record:
    """One iteration. ``final_metric`` is the run's FINAL_METRIC object (the train.py record);
    ``metric`` and ``feasible`` are read from it; ``verdict`` and ``best_so_far`` are computed once,
    when the record is written (autoresearch.campaign.store)."""

    iteration: int
    status: Status
    time: str | None = None
    proposer: str | None = None
    reason: str | None = None
    proposal: dict[str, Any] | None = None
    overrides: dict[str, Any] | None = None
    config: dict[str, Any] | None = None
    run_id: str | None = None
    seed: int | None = None
    metric: float | None = None
    feasible: bool | None = None
    final_metric: dict[str, Any] | None = None
    verdict: str | None = None
    # the noise the verdict was judged against (verdicts.judged_against): {sigma, k, measured_at}
    verdict_noise: dict[str, Any] | None = None
    best_so_far: float | None = None
    cost_usd: float | None = None
    input_tokens: int | None = None
    output_tokens: int | None = None
    cumulative_cost_usd: float | None = None
    elapsed_s: float | None = None
    trigger: str | None = None
    run_status: str | None = None
    wall_seconds: float | None = None
    returncode: int | None = None
    interrupted_run_ids: list[str] | None = None
    progress: list[dict[str, Any]] | None = None
    # A run that used up its training time budget and was scored as it stood (FINAL_METRIC's
    # ``budget_exhausted``): a result like any other, told to the proposer as cut short.
    budget_exhausted: bool | None = None
    schema: int = SCHEMA

    @property
    def ran(self) -> bool:
        return self.status is Status.RAN

    @property
    def hypothesis(self) -> str | None:
        return ((self.proposal or {}).get("annotation") or {}).get("hypothesis")

    def replace(self, **changes: Any) -> Record:
        return dataclasses.replace(self, **changes)

    def to_json(self) -> dict[str, Any]:
        """The on-disk object (schema 2): every field, in order, the status as its value."""
        data = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        data["status"] = self.status.value
        data["schema"] = SCHEMA
        return data

    @classmethod
    def from_json(cls, data: Any, where: str = "proposals.jsonl") -> Record:
        """A record from its on-disk object, schema 1 or 2; CampaignError naming what is wrong."""
        if not isinstance(data, dict):
            raise CampaignError(f"{where}: not a JSON object")
        fields = {_LEGACY_KEYS.get(key, key): value for key, value in data.items()}
        iteration = fields.get("iteration")
        if not isinstance(iteration, int) or isinstance(iteration, bool) or iteration < 1:
            raise CampaignError(f"{where}: no iteration number")
        status = parse_status(fields.get("status"))
        if status is None:
            raise CampaignError(f"{where}: iteration {iteration} has unknown status {fields.get('status')!r}")
        fields["status"] = status
        unknown = set(fields) - _FIELD_NAMES
        if unknown:
            raise CampaignError(f"{where}: iteration {iteration} has unknown fields {sorted(unknown)}")
        fields["schema"] = data.get("schema", 1)
        return cls(**fields)


_FIELD_NAMES = frozenset(field.name for field in dataclasses.fields(Record))
