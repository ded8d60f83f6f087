"""The one reader and writer of a campaign directory's files.

``Campaign(root)`` reads campaign.json (:class:`CampaignMeta`), proposals.jsonl (typed
:class:`Record` s, schema 1 or 2), the run intents under ``runs/`` and the campaign's copy of the
family registry. :class:`CampaignWriter` is the write path of the loop: it appends one record per
iteration and folds it into the :class:`CampaignState`, and it alone computes a run's verdict and
the best so far, stamps the time, the spend and the elapsed seconds. Nothing else in autoresearch
opens proposals.jsonl or sorts records by status.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from autoresearch.campaign.meta import CampaignMeta
from autoresearch.campaign.paths import CampaignError, CampaignPaths
from autoresearch.campaign.records import BASELINE_PROPOSER, Record, Status, now
from autoresearch.campaign.state import CampaignState
from autoresearch.execution.result import RunResult
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import (
    Journal,
    JournalError,
    read_json,
    read_jsonl,
    repair_torn_tail,
    write_json_atomic,
)
from autoresearch.verdicts import CONFIRMED, REGRESSED, WITHIN_NOISE, judged_against, run_verdict

INTENT = "intent.json"
INTERRUPTED = "interrupted.json"
RUNNING_BEST = "campaign_best"  # the campaign copy's own running best (schema 1 kept it as "best")


@dataclass(frozen=True)
class Intent:
    """An iteration whose run has started: its record-to-be, written to runs/<run_id>/intent.json
    before the run starts, so that a resume can finish the iteration whatever happened."""

    iteration: int
    proposer: str
    run_id: str
    seed: int
    config: dict[str, Any]
    overrides: dict[str, Any]
    proposal: dict[str, Any] | None = None
    cost_usd: float | None = None
    input_tokens: int | None = None
    output_tokens: int | None = None
    interrupted_run_ids: list[str] | None = None

    @property
    def hypothesis(self) -> str | None:
        return ((self.proposal or {}).get("annotation") or {}).get("hypothesis")

    def to_json(self) -> dict[str, Any]:
        return {field.name: getattr(self, field.name) for field in fields(self)}

    @classmethod
    def from_json(cls, data: Any, where: str) -> Intent:
        """An intent as written now, or a schema-1 one (a whole record-to-be, unset fields null)."""
        if not isinstance(data, dict) or not isinstance(data.get("run_id"), str):
            raise CampaignError(f"{where}: not a run intent")
        return cls(**{name: data.get(name) for name in _INTENT_FIELDS})


_INTENT_FIELDS = tuple(field.name for field in fields(Intent))


class Campaign:
    """A campaign directory (which need not exist yet)."""

    def __init__(self, root: str | Path):
        self.paths = CampaignPaths(Path(root))
        self._journal = Journal(self.paths.proposals)

    @property
    def root(self) -> Path:
        return self.paths.root

    def exists(self) -> bool:
        return self.paths.campaign_json.exists()

    # ----- campaign.json ------------------------------------------------------------------

    def meta(self) -> CampaignMeta:
        return CampaignMeta.read(self.root)

    # ----- proposals.jsonl ----------------------------------------------------------------

    def records(self) -> list[Record]:
        """Every record in the order written (a torn last line is skipped; a bad one raises)."""
        try:
            raw = self._journal.read()
        except JournalError as err:
            raise CampaignError(str(err)) from None
        return [Record.from_json(data, f"{self.paths.proposals}:{i}") for i, data in enumerate(raw, 1)]

    def state(self, family: Family) -> CampaignState:
        return CampaignState.from_records(family, self.records())

    def started(self) -> list[Record]:
        """The iterations whose experiment started (ran, failed or stopped early)."""
        return [r for r in self.records() if r.status.started_a_run]

    def logged_final_metrics(self) -> list[dict[str, Any]]:
        """runs.jsonl: the FINAL_METRIC objects the campaign's train.py runs appended."""
        return [line for line in read_jsonl(self.paths.runs_log) if isinstance(line, dict)]

    def append(self, record: Record) -> None:
        """Append one record, durably (autoresearch.journal)."""
        self._journal.append(record.to_json())

    def repair(self) -> None:
        """What a writer does before its first append: move a torn last line of proposals.jsonl and
        runs.jsonl (a crash mid-append) to ``.torn`` beside them. Reading a campaign never does."""
        self._journal.repair()
        repair_torn_tail(self.paths.runs_log)

    # ----- run intents --------------------------------------------------------------------

    def write_intent(self, intent: Intent) -> None:
        run_dir = self.paths.run_dir(intent.run_id)
        run_dir.mkdir(parents=True, exist_ok=True)  # a dir left empty by a crash before its intent is reused
        if (run_dir / INTENT).exists():
            raise CampaignError(f"{run_dir} already holds a run")
        write_json_atomic(run_dir / INTENT, intent.to_json())

    def intents(self) -> list[Intent]:
        """Every intent not marked interrupted, in run-id order (recorded or not)."""
        if not self.paths.runs_dir.is_dir():
            return []
        found = []
        for run_dir in sorted(self.paths.runs_dir.iterdir()):
            path = run_dir / INTENT
            if path.exists() and not (run_dir / INTERRUPTED).exists():
                found.append(Intent.from_json(read_json(path), str(path)))
        return found

    def in_flight(self, state: CampaignState) -> list[Intent]:
        """Intents of runs that started but whose iteration was never recorded."""
        return [intent for intent in self.intents() if intent.run_id not in state.run_ids]

    def run_spec(
        self, family: Family, intent: Intent, timeout: float, time_budget: float | None = None
    ) -> RunSpec:
        """The run of ``intent``, in its run directory, logging to the campaign's runs.jsonl."""
        paths = self.paths
        return RunSpec(
            family,
            intent.config,
            intent.run_id,
            intent.seed,
            paths.run_dir(intent.run_id),
            paths.runs_log,
            timeout,
            time_budget=time_budget,
        )

    def mark_interrupted(self, run_id: str, why: str) -> None:
        write_json_atomic(self.paths.run_dir(run_id) / INTERRUPTED, {"time": now(), "reason": why})

    # ----- the campaign's copy of family.json -----------------------------------------------

    def registry(self) -> dict[str, Any] | None:
        return read_json(self.paths.family_json) if self.paths.family_json.exists() else None

    def write_registry(self, registry: dict[str, Any]) -> None:
        write_json_atomic(self.paths.family_json, registry)

    def running_best(self) -> dict[str, Any] | None:
        """The campaign copy's running best: {"metric", "run_id", "iteration", "config"}, or None."""
        registry = self.registry() or {}
        best = registry.get(RUNNING_BEST)
        legacy = registry.get("best")
        if best is None and isinstance(legacy, dict) and str(legacy.get("source", "")).startswith("loop:"):
            best = legacy
        return best


def running_best_entry(best: Record | None) -> dict[str, Any] | None:
    """What the campaign copy of family.json holds as the running best."""
    if best is None:
        return None
    return {"config": best.config, "metric": best.metric, "run_id": best.run_id, "iteration": best.iteration}


class CampaignWriter:
    """The loop's write path: one record per iteration, appended and folded into ``state``.

    ``elapsed()`` gives the loop's seconds over all its sessions, stamped on every record.
    """

    def __init__(self, campaign: Campaign, state: CampaignState, elapsed: Callable[[], float]):
        self.campaign, self.state, self.elapsed = campaign, state, elapsed

    def append_run(self, intent: Intent, result: RunResult) -> Record:
        """The record of a finished run: its outcome, the per-run verdict and the best so far."""
        state, family = self.state, self.state.family
        fields = {
            "run_status": result.status,
            "wall_seconds": result.wall_seconds,
            "returncode": result.returncode,
            "run_id": result.run_id,
            "progress": result.progress or None,
        }
        if result.ok:
            feasible = family.is_feasible(result.final_metric)
            verdict = run_verdict(
                result.metric,
                feasible=feasible,
                is_baseline=intent.proposer == BASELINE_PROPOSER,
                prior_best=state.best_metric,
                direction=family.direction,
                sigma=family.sigma,
            )
            cut = result.final_metric.get("budget_exhausted")
            judged = verdict in (CONFIRMED, REGRESSED, WITHIN_NOISE)  # a comparison in noise units
            fields.update(
                status=Status.RAN,
                metric=result.metric,
                feasible=feasible,
                final_metric=result.final_metric,
                verdict=verdict,
                verdict_noise=judged_against(family.seed_noise, state.best_metric) if judged else None,
                best_so_far=state.best_after(result.metric, feasible),
                budget_exhausted=cut if isinstance(cut, bool) else None,
            )
        elif result.status == "early_stopped":  # never a result: no metric, never best, not a failure
            fields.update(status=Status.EARLY_STOPPED, reason=result.reason, best_so_far=state.best_metric)
        else:
            fields.update(status=Status.FAILED, reason=result.reason, best_so_far=state.best_metric)
        return self._commit(Record(**{**intent.to_json(), **fields}))

    def append_refusal(
        self, iteration: int, proposer: str, status: Status, reason: str, **fields: Any
    ) -> Record:
        """The record of an iteration that ran nothing: an invalid proposal or a stop request."""
        record = Record(
            iteration, status, proposer=proposer, reason=reason, best_so_far=self.state.best_metric, **fields
        )
        return self._commit(record)

    def append_stop(self, iteration: int, proposer: str, trigger: str, reason: str) -> Record:
        """The loop's own last record: a stopping trigger fired."""
        return self.append_refusal(iteration, proposer, Status.STOPPED, reason, trigger=trigger)

    def _commit(self, record: Record) -> Record:
        state = self.state
        cost = record.cost_usd or 0.0
        record = record.replace(
            time=now(),
            cost_usd=cost,
            input_tokens=record.input_tokens or 0,
            output_tokens=record.output_tokens or 0,
            cumulative_cost_usd=state.cost_usd + cost,
            elapsed_s=round(self.elapsed(), 3),
        )
        self.campaign.append(record)
        state.apply(record)
        return record
