"""The loop state: a pure fold over a campaign's records.

The live loop applies each record it writes through :meth:`CampaignState.apply`, and ``--resume``
rebuilds the identical state by applying the records read back from disk. Nothing else is kept in
memory that the trail cannot restore. Records are in the order they were written, which with
``loop --workers K`` is the order runs finished, not iteration order.
"""

from __future__ import annotations

from typing import Any

from autoresearch.campaign.paths import CampaignError
from autoresearch.campaign.records import BASELINE_PROPOSER, Record, Status
from autoresearch.family import Family
from autoresearch.space import canonical_key
from autoresearch.splits import Score
from autoresearch.verdicts import best_feasible, is_better, reaches_target


def count_iterations(records: list[Record]) -> int:
    """Iterations the loop has run: every record but the loop's own stop records, so that a campaign
    resumed with a larger --max-iters runs up to that many."""
    return sum(record.status is not Status.STOPPED for record in records)


class CampaignState:
    """Counters, best, seen configurations, spend and history after the records applied so far."""

    def __init__(self, family: Family):
        self.family = family
        self.records: list[Record] = []
        self.n_runs_ok = 0
        self.n_experiments = 0  # successful runs the proposer chose (the baseline excluded)
        self.n_runs_attempted = 0
        self.consecutive_failures = 0
        self.cost_usd = 0.0
        self.input_tokens = 0
        self.output_tokens = 0
        self.elapsed_s = 0.0
        self.best: Record | None = None  # the best feasible run so far
        self.scores: list[Score] = []  # of the successful runs, in the order recorded
        self.seen_configs: dict[str, int] = {}  # canonical config -> iteration that ran it
        self.seen_overrides: dict[str, int] = {}
        self.axes_exercised: set[str] = set()
        self.run_ids: set[str] = set()
        self.recorded: set[int] = set()  # iteration numbers with a record
        self.history_full: list[dict[str, Any]] = []
        self.history_blind: list[dict[str, Any]] = []

    @classmethod
    def from_records(cls, family: Family, records: list[Record]) -> CampaignState:
        state = cls(family)
        for record in records:
            state.apply(record)
        return state

    @property
    def iterations(self) -> int:
        return count_iterations(self.records)

    @property
    def next_iteration(self) -> int:
        """The number after every recorded one (runs in flight may hold some numbers past it)."""
        return max(self.recorded, default=0) + 1

    @property
    def last(self) -> Record | None:
        return self.records[-1] if self.records else None

    @property
    def finished(self) -> bool:
        return self.last is not None and self.last.status.ends_campaign

    @property
    def best_metric(self) -> float | None:
        return self.best.metric if self.best else None

    @property
    def target_met(self) -> bool:
        return reaches_target(self.best_metric, self.family.target, self.family.direction)

    def current_values(self) -> dict[str, Any]:
        """The configuration the next overrides apply to: the best so far, else the baseline."""
        return dict(self.best.config) if self.best else self.family.baseline_config

    def best_after(self, metric: float | None, feasible: bool | None) -> float | None:
        if metric is not None and feasible and is_better(metric, self.best_metric, self.family.direction):
            return metric
        return self.best_metric

    def seen_at(self, overrides: dict[str, Any], config: dict[str, Any]) -> str | None:
        """Why (overrides, config) repeats an evaluated point (paper Eq. dedup), or None."""
        if canonical_key(overrides) in self.seen_overrides:
            return f"this override map was already run at iteration {self.seen_overrides[canonical_key(overrides)]}"
        if canonical_key(config) in self.seen_configs:
            return f"the resulting configuration was already run at iteration {self.seen_configs[canonical_key(config)]}"
        return None

    def warnings(self) -> tuple[str, ...]:
        """What the proposer must hear about the last iteration."""
        last = self.last
        if last is None:
            return ()
        i, reason = last.iteration, last.reason
        if last.status is Status.INVALID:
            return (f"Iteration {i}: your proposal was refused and nothing ran: {reason}",)
        if last.status is Status.STOP_REJECTED:
            return (f"Iteration {i}: your stop request was rejected: {reason}",)
        if last.status is Status.FAILED:
            return (f"Iteration {i}: run {last.run_id} failed: {reason}",)
        if last.status is Status.EARLY_STOPPED:
            return (f"Iteration {i}: run {last.run_id} was stopped early: {reason}",)
        return ()

    def apply(self, record: Record) -> None:
        if record.iteration in self.recorded:
            raise CampaignError(f"proposals.jsonl: iteration {record.iteration} is recorded twice")
        self.records.append(record)
        self.recorded.add(record.iteration)
        self.cost_usd += record.cost_usd or 0.0
        self.input_tokens += record.input_tokens or 0
        self.output_tokens += record.output_tokens or 0
        self.elapsed_s = record.elapsed_s or self.elapsed_s
        if record.status.counts_as_failure:
            self.consecutive_failures += 1
        if record.status.started_a_run:
            self._apply_run(record)

    def _apply_run(self, record: Record) -> None:
        config, overrides = record.config, record.overrides
        self.n_runs_attempted += 1
        self.run_ids.add(record.run_id)
        self.seen_configs.setdefault(canonical_key(config), record.iteration)
        self.seen_overrides.setdefault(canonical_key(overrides), record.iteration)
        metric_name = self.family.metric
        item = {
            "iteration": record.iteration,
            "run_id": record.run_id,
            "status": record.run_status
            if record.run_status is not None
            else ("ok" if record.ran else "failed"),
            "hypothesis": record.hypothesis,
            "overrides": overrides,
            "config": config,
            metric_name: record.metric,
        }
        if record.wall_seconds is not None:  # what the run cost: the proposer weighs it against the gain
            item["seconds"] = round(record.wall_seconds, 1)
        if record.budget_exhausted:
            item["budget_exhausted"] = True  # cut at its time budget and scored as it stood
        if record.progress:
            item["progress"] = record.progress
        if not record.ran:  # failed, or stopped early: neither counts as a result nor as a failure
            item["reason"] = record.reason
        else:
            metric, feasible = record.metric, bool(record.feasible)
            self.n_runs_ok += 1
            self.consecutive_failures = 0
            self.scores.append(Score(metric, feasible))
            if record.proposer != BASELINE_PROPOSER:
                self.n_experiments += 1
                baseline = self.family.baseline_config
                self.axes_exercised |= self.family.space.axes_of(
                    {k for k in config if config[k] != baseline[k]}
                )
            self.best = best_feasible([self.best, record], self.family.direction)
            aux = {
                k: v
                for k, v in (record.final_metric or {}).items()
                if k not in ("run_id", "config", "splits", metric_name)  # splits: the search split, on top
            }
            item.update(feasible=feasible, verdict=record.verdict, auxiliary=aux)
        self.history_full.append(item)
        self.history_blind.append({"config": config, metric_name: record.metric})
