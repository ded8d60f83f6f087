"""The agent loop of one campaign (paper Algorithm 1).

Each iteration: check the stopping triggers, ask the proposer (the first experiment is the
family's baseline, with no proposer call), validate and deduplicate the proposal, run it,
judge it, record it. Exactly one record per iteration goes to proposals.jsonl, whatever
happened; the loop state is a fold over those records (:mod:`autoresearch.campaign`), written
through one path (:class:`autoresearch.campaign.CampaignWriter`).

Runs in flight (``workers`` > 1, :mod:`autoresearch.loop.scheduler`): the main thread proposes,
validates and records; each run is supervised by a thread of its own (or a Ray task). An
iteration number is given when the proposal is made; its record is appended when its run ends,
so records are in completion order. The proposer sees the runs in flight
(``ProposerContext.running``) and dedup covers them. When a trigger fires, no new proposal is
made; the runs in flight finish and are recorded, then the stop record is written (with the
highest iteration number). With ``workers`` = 1 each run finishes before the next proposal.

Durability: before a run starts, its intent (the record-to-be) is written atomically to
``runs/<run_id>/intent.json``; after a crash at any moment ``--resume`` finishes every intent
without a record (:mod:`autoresearch.loop.recovery`).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from autoresearch.campaign import (
    BASELINE_PROPOSER,
    Campaign,
    CampaignError,
    CampaignState,
    CampaignWriter,
    Intent,
    Record,
    Status,
)
from autoresearch.campaign.store import RUNNING_BEST, running_best_entry
from autoresearch.execution.executors import Executor, LocalExecutor
from autoresearch.execution.result import RunResult
from autoresearch.execution.runner import run_prepare_check
from autoresearch.execution.spec import RunHooks
from autoresearch.family import Family
from autoresearch.loop import recovery
from autoresearch.loop.asking import Halt, ask
from autoresearch.loop.context import build_context, summarize_random_arm, training_budget_line
from autoresearch.loop.early_stop import EarlyStopper, curve_of
from autoresearch.loop.live import View
from autoresearch.loop.scheduler import Scheduler
from autoresearch.loop.stopping import Budgets, closest_trigger, first_trigger, stop_gate
from autoresearch.loop.warm_start import WarmStart
from autoresearch.proposers.base import Proposal, Proposer, RunOutcome
from autoresearch.space import ValidationError, canonical_key

BASELINE_HYPOTHESIS = "the family's baseline configuration (the shared first experiment of every campaign)"


@dataclass(frozen=True)
class LoopSettings:
    proposer_name: str
    budgets: Budgets = field(default_factory=Budgets)
    blind: bool = False
    timeout_per_run: float = 3600.0  # the hard limit of one run (with a time budget: budget + allowance)
    random_arm: Path | None = None
    workers: int = 1  # experiments in flight at once
    early_stop: str = "none"  # none, median, asha or hyperband (autoresearch.loop.early_stop)
    time_budget: float | None = None  # training seconds each run is granted (AUTORESEARCH_TIME_BUDGET)
    warm_start: WarmStart | None = None  # earlier campaigns' runs; an LLM proposer is shown their summary


@dataclass(frozen=True)
class Outcome:
    """How :meth:`Orchestrator.run` ended: ``status`` is stopped, stop_accepted, prepare_failed or
    already_finished (a resumed campaign that had ended and has nothing left to do)."""

    status: str
    trigger: str | None
    reason: str
    iterations: int
    n_runs_ok: int
    best: Record | None


def _jsonable(value: Any) -> Any:
    """A JSON-clean copy of untrusted proposer output; what JSON cannot hold is kept as its repr."""
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError):
        return repr(value)


def run_id_for(iteration: int, attempt: int = 1) -> str:
    return f"it{iteration:04d}" + (f"-r{attempt}" if attempt > 1 else "")


class Orchestrator:
    """One campaign's loop. ``executor`` runs each experiment (by default on this machine; a Ray
    executor runs it as a remote task), each supervised by a thread of this process when
    ``settings.workers`` > 1. ``on_record`` hears every record once written (e.g.
    autoresearch.optuna_journal.LiveFeed)."""

    def __init__(
        self,
        family: Family,
        proposer: Proposer,
        campaign_dir: str | Path,
        settings: LoopSettings,
        view: View | None = None,
        executor: Executor | None = None,
        on_record: Callable[[Record], None] | None = None,
    ):
        self.family = family
        self.proposer = proposer
        self.settings = settings
        self.view = view or View()
        self.executor = executor or LocalExecutor()
        self.on_record = on_record
        self.campaign = Campaign(campaign_dir)
        self.state = CampaignState(family)  # the fold of the records, once _open has read them
        self.writer = CampaignWriter(self.campaign, self.state, self.elapsed)
        self.scheduler = Scheduler(settings.workers, self._execute)
        self.registry: dict[str, Any] = {}  # the campaign's copy of family.json
        self.stopper: EarlyStopper | None = None
        self.random_summary: str | None = None
        self.warm_summary: str | None = None
        self._elapsed_base, self._started = 0.0, time.monotonic()

    # ----- set-up and resume -------------------------------------------------------------

    def _open(self) -> None:
        campaign = self.campaign
        campaign.paths.runs_dir.mkdir(parents=True, exist_ok=True)
        registry = campaign.registry()
        if registry is None:
            # The campaign's own copy: no sealed-split number, and its own running best.
            registry = self.family.search_registry()
            campaign.write_registry(registry)
        name = registry.get("name") if isinstance(registry, dict) else None
        if name != self.family.name:  # a one-line error, with its repair, not a traceback
            what = f"belongs to family {name!r}, not {self.family.name!r}" if name else "is no family.json"
            raise CampaignError(
                f"{campaign.paths.family_json} {what}; delete it: the loop rewrites it from the records"
            )
        self.registry = registry
        campaign.repair()
        self.state = campaign.state(self.family)
        self.writer = CampaignWriter(campaign, self.state, self.elapsed)
        for record in self.state.records:
            if record.status.started_a_run:
                self.proposer.tell(self._run_outcome(record))
        self._sync_best()
        if self.settings.early_stop != "none":
            self.stopper = EarlyStopper(self.settings.early_stop, self.family.direction, self.state.records)
        self._elapsed_base, self._started = self.state.elapsed_s, time.monotonic()
        arm = self.settings.random_arm
        self.random_summary = summarize_random_arm(arm, self.family) if arm else None
        warm = self.settings.warm_start
        self.warm_summary = warm.summary(self.family) if warm else None

    def elapsed(self) -> float:
        """Seconds the loop has been running, summed over this campaign's sessions."""
        return self._elapsed_base + time.monotonic() - self._started

    def _sync_best(self) -> None:
        entry = running_best_entry(self.state.best)
        if self.registry.get(RUNNING_BEST) != entry:
            self.registry = {**self.registry, RUNNING_BEST: entry}
            self.campaign.write_registry(self.registry)

    def _recover(self) -> list[Intent]:
        """Finish every in-flight iteration from its outcome; return the intents that must be re-run."""
        live, superseded = recovery.pending(self.campaign, self.state)
        for intent in superseded:
            recovery.retire(self.campaign, intent, "superseded by a later attempt or record of its iteration")
        reruns = []
        for intent in live:
            result = recovery.adopt(self.campaign, self.family, intent, self.settings.timeout_per_run)
            if result is None:
                reruns.append(intent)
            else:
                self._finish_run(intent, result)
        return reruns

    # ----- the loop ----------------------------------------------------------------------

    def run(self) -> Outcome:
        try:
            return self._run()
        finally:
            self.view.close()

    def _run(self) -> Outcome:
        self._open()
        state, budgets = self.state, self.settings.budgets
        if state.finished:
            trigger = first_trigger(state, budgets, self.elapsed())
            if state.last.status is Status.STOP_ACCEPTED or trigger is not None:
                return self._outcome("already_finished", state.last.trigger, state.last.reason)
        reruns = self._recover()
        problem = run_prepare_check(self.family.path)
        if problem is not None:
            for intent in reruns:
                self.campaign.mark_interrupted(
                    intent.run_id, "not re-run: prepare.py --check failed on resume"
                )
            self._stop("prepare_check", problem)
            return self._outcome("prepare_failed", "prepare_check", problem)
        try:
            for intent in reruns:
                self._rerun(intent)
            while True:
                for done in self.scheduler.finished():
                    self._finish_run(*done)
                trigger = first_trigger(state, budgets, self.elapsed())
                if trigger is not None:
                    self._drain()  # no new proposal; the runs in flight finish and are recorded first
                    trigger = first_trigger(state, budgets, self.elapsed()) or trigger
                    self._stop(trigger.name, trigger.message)
                    return self._outcome("stopped", trigger.name, trigger.message)
                if self.scheduler.in_flight and (self.scheduler.full or self._caps_taken()):
                    self._finish_run(*self.scheduler.collect(block=True))
                    continue
                before = state.last
                self._iteration()
                if state.last is not before and state.finished:  # a stop record of this session
                    last = state.last
                    return self._outcome(last.status.value, last.trigger, last.reason)
        except BaseException:
            self.scheduler.abort()  # Ctrl-C, SIGTERM or a bug: kill the runs in flight, then unwind
            raise

    def _caps_taken(self) -> bool:
        """Whether the runs in flight, counted as iterations and as successes, already fill
        max_iters or max_runs: then the loop waits for them instead of proposing more."""
        b, n = self.settings.budgets, len(self.scheduler.in_flight)
        return (b.max_iters is not None and self.state.iterations + n >= b.max_iters) or (
            b.max_runs is not None and self.state.n_runs_ok + n >= b.max_runs
        )

    def _next_iteration(self) -> int:
        in_flight = (intent.iteration for intent in self.scheduler.in_flight.values())
        return max([self.state.next_iteration - 1, *in_flight]) + 1

    def _stop(self, trigger: str, reason: str) -> None:
        self._drain()
        name = self.settings.proposer_name
        self._shown(self.writer.append_stop(self._next_iteration(), name, trigger, reason))

    def _outcome(self, status: str, trigger: str | None, reason: str) -> Outcome:
        s = self.state
        return Outcome(status, trigger, reason, s.iterations, s.n_runs_ok, s.best)

    def _running(self) -> tuple[dict[str, Any], ...]:
        """The experiments in flight, as the proposer is shown them."""
        return tuple(
            {
                "iteration": i.iteration,
                "run_id": i.run_id,
                "overrides": i.overrides,
                "config": i.config,
                "hypothesis": i.hypothesis,
            }
            for i in self.scheduler.in_flight.values()
        )

    def _ask(self, iteration: int) -> tuple[str, Proposal | None]:
        """(proposer name, proposal); the proposal is None when the campaign was stopped instead."""
        state = self.state
        if state.n_runs_attempted == 0 and not self.scheduler.in_flight:
            return BASELINE_PROPOSER, Proposal(kind="propose", annotation={"hypothesis": BASELINE_HYPOTHESIS})
        blind, budgets = self.settings.blind, self.settings.budgets
        context = build_context(
            state,
            registry=self.registry,
            blind=blind,
            extra_warnings=(
                f"Budget: {closest_trigger(state, budgets, self.elapsed(), blind)}",
                *training_budget_line(state, self.settings.time_budget),
            ),
            random_arm_summary=self.random_summary,
            warm_start_summary=self.warm_summary,
        )
        context = replace(context, iteration=iteration, running=self._running())
        seconds_left = None if budgets.max_seconds is None else budgets.max_seconds - self.elapsed()
        answer = ask(self.proposer, context, state, budgets, seconds_left)
        name = self.settings.proposer_name
        if isinstance(answer, Halt):
            self._stop(answer.trigger, answer.reason)
            return name, None
        return name, answer

    def _iteration(self) -> None:
        state = self.state
        iteration = self._next_iteration()
        self.view.iteration_started(iteration)
        proposer, proposal = self._ask(iteration)
        if proposal is None:
            return
        self.view.proposal(iteration, proposer, proposal)
        usage = proposal.usage
        asked = {
            "proposal": {
                "kind": _jsonable(proposal.kind),
                "overrides": _jsonable(proposal.overrides),
                "annotation": _jsonable(proposal.annotation),
                "error": _jsonable(proposal.error),
                "usage": {
                    "cache_read_tokens": usage.cache_read_tokens,
                    "cache_write_tokens": usage.cache_write_tokens,
                    "reasoning_tokens": usage.reasoning_tokens,
                    "problem": usage.problem,
                },
                "notes": _jsonable(proposal.notes),
            },
            "cost_usd": usage.cost_usd,
            "input_tokens": usage.input_tokens,
            "output_tokens": usage.output_tokens,
        }

        def refuse(status: Status, reason: str, **fields: Any) -> None:
            self._shown(self.writer.append_refusal(iteration, proposer, status, reason, **asked, **fields))

        if proposal.kind == "stop":
            annotation = proposal.annotation if isinstance(proposal.annotation, dict) else {}
            accepted, why = stop_gate(annotation, state, self.settings.budgets.stop_at_target)
            if accepted:
                self._drain()  # the stop record is the last: the runs in flight are recorded first
                refuse(Status.STOP_ACCEPTED, why, trigger="stop_research")
            else:
                refuse(Status.STOP_REJECTED, why)
            return
        if proposal.kind != "propose":
            refuse(
                Status.INVALID,
                proposal.error or f"the proposer returned a proposal of kind {proposal.kind!r}",
            )
            return
        try:
            overrides = self.family.space.validate(proposal.overrides)
        except ValidationError as err:
            refuse(Status.INVALID, str(err))
            return
        config = {**state.current_values(), **overrides}
        if not overrides and proposer != BASELINE_PROPOSER:
            why = "the override map is empty: it changes nothing"
        else:
            why = state.seen_at(overrides, config) or self._seen_in_flight(overrides, config)
        if why is not None:
            refuse(Status.INVALID, why, overrides=overrides, config=config)
            return
        intent = Intent(
            iteration=iteration,
            proposer=proposer,
            run_id=run_id_for(iteration),
            seed=self.family.default_seed,
            config=config,
            overrides=overrides,
            interrupted_run_ids=[],
            **asked,
        )
        self._start(intent)

    def _seen_in_flight(self, overrides: dict[str, Any], config: dict[str, Any]) -> str | None:
        """Why (overrides, config) repeats an experiment in flight, or None (dedup covers them too)."""
        for intent in self.scheduler.in_flight.values():
            if canonical_key(overrides) == canonical_key(intent.overrides):
                return f"this override map is running now, at iteration {intent.iteration}"
            if canonical_key(config) == canonical_key(intent.config):
                return f"the resulting configuration is running now, at iteration {intent.iteration}"
        return None

    def _start(self, intent: Intent, supersedes: Intent | None = None) -> None:
        self.campaign.write_intent(intent)
        if supersedes is not None:  # only once the new attempt is durable
            why = f"the loop died during this run; re-run as {intent.run_id}"
            self.campaign.mark_interrupted(supersedes.run_id, why)
        self.view.run_started(intent.run_id)
        self.scheduler.launch(intent)

    def _execute(self, intent: Intent) -> RunResult:
        run_id = intent.run_id
        hooks = RunHooks(
            on_progress=lambda elapsed: self.view.run_progress(elapsed, run_id),
            on_report=self.stopper.start(run_id) if self.stopper else None,
            cancel=self.scheduler.cancel,  # set as the loop unwinds: every run in flight is killed
        )
        settings = self.settings
        spec = self.campaign.run_spec(self.family, intent, settings.timeout_per_run, settings.time_budget)
        return self.executor.run(spec, hooks)

    def _drain(self) -> None:
        for done in self.scheduler.drain():
            self._finish_run(*done)

    def _rerun(self, intent: Intent) -> None:
        lost = [*(intent.interrupted_run_ids or []), intent.run_id]
        retry = replace(intent, run_id=run_id_for(intent.iteration, len(lost) + 1), interrupted_run_ids=lost)
        self._start(retry, supersedes=intent)

    def _finish_run(self, intent: Intent, result: RunResult) -> None:
        record = self.writer.append_run(intent, result)
        self._shown(record)
        off = self.family.off_split(record.final_metric) if record.ran else []
        if off:  # its record says so too: the FINAL_METRIC object it keeps names the data it scored on
            print(
                f"[it {record.iteration}] warning: run {record.run_id} was scored on data other than family "
                f"{self.family.name!r} pins ({'; '.join(off)}); its numbers are not comparable with the "
                "family's: check the data with `python prepare.py --check` in the family directory",
                file=sys.stderr,
                flush=True,
            )
        if self.stopper is not None:
            self.stopper.finish(record)
        self.proposer.tell(self._run_outcome(record))
        self._sync_best()

    def _shown(self, record: Record) -> None:
        self.view.record(record, closest_trigger(self.state, self.settings.budgets, self.elapsed()))
        if self.on_record is not None:
            self.on_record(record)

    def _run_outcome(self, record: Record) -> RunOutcome:
        """What the proposer is told of a run record (a failed or stopped run has no metric), with what
        it cost and whether its training budget cut it short."""
        cost = {"seconds": record.wall_seconds, "budget_exhausted": bool(record.budget_exhausted)}
        if record.status is Status.EARLY_STOPPED:
            return RunOutcome(record.config, None, False, curve=curve_of(record), **cost)
        if not record.ran:
            return RunOutcome(record.config, None, False, **cost)
        constraints = self.family.constraints(record.final_metric)
        return RunOutcome(record.config, record.metric, bool(record.feasible), constraints, **cost)
