"""The agent loop of one campaign (paper Algorithm 1).

Each iteration: check the stopping triggers, ask the proposer (the first experiment is the
family's baseline, with no proposer call), validate and deduplicate the proposal, run it,
judge it, record it. Exactly one record per iteration goes to proposals.jsonl, whatever
happened; the loop state is a fold over those records (:mod:`autoresearch.loop.campaign`).

Runs in flight (``workers`` > 1): the main thread proposes, validates and records; each run is
supervised by a thread of its own (or a Ray task) and reports back through a queue. An iteration
number is given when the proposal is made; its record is appended when its run ends, so records
are in completion order. The proposer sees the runs in flight (``ProposerContext.running``) and
dedup covers them. When a trigger fires, no new proposal is made; the runs in flight finish and
are recorded, then the stop record is written (with the highest iteration number). With
``workers`` = 1 each run finishes before the next proposal, as before.

Durability: before a run starts, the iteration's record-to-be is written atomically to
``runs/<run_id>/intent.json``. After a crash at any moment, ``--resume`` finds every intent
without a proposals record and finishes that iteration: it kills what is left of the run
(every process carrying its run directory, wherever it moved: autoresearch.loop.tracking), then
adopts its outcome from ``result.json`` (the runner's verdict) or from the run's line in
runs.jsonl (train.py finished, with the intent's config and seed), or records it as timed out
(still running past its deadline, or killed there by its watchdog), or else marks the run dir
interrupted and re-runs the same configuration under a new run id (``<run_id>-r2``, ...),
listing the lost attempts in ``interrupted_run_ids``. No iteration and no run id is recorded twice.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from autoresearch.executors import Executor
from autoresearch.family import Family, search_view
from autoresearch.journal import Journal, read_json, repair_torn_tail, write_json_atomic
from autoresearch.loop.campaign import (
    BASELINE_PROPOSER,
    RUN_STATUSES,
    CampaignError,
    CampaignPaths,
    CampaignState,
    new_record,
    now,
)
from autoresearch.loop.context import build_context, summarize_random_arm
from autoresearch.loop.early_stop import EarlyStopper
from autoresearch.loop.live import View
from autoresearch.loop.runner import (
    RunResult,
    load_result,
    logged_run,
    run_experiment,
    run_prepare_check,
    stop_orphaned_run,
)
from autoresearch.loop.stopping import Budgets, closest_trigger, first_trigger, spend_trigger, stop_gate
from autoresearch.loop.verdicts import run_verdict
from autoresearch.proposers.base import FatalAPIError, Proposal, Proposer, RunOutcome, projected_cost
from autoresearch.proposers.retry import RetryBudgetSpent, call_with_retries
from autoresearch.space import ValidationError, canonical_key

BASELINE_HYPOTHESIS = "the family's baseline configuration (the shared first experiment of every campaign)"


@dataclass(frozen=True)
class LoopSettings:
    proposer_name: str
    budgets: Budgets = field(default_factory=Budgets)
    blind: bool = False
    timeout_per_run: float = 3600.0
    random_arm: Path | None = None
    workers: int = 1  # experiments in flight at once
    early_stop: str = "none"  # none, median or asha (autoresearch.loop.early_stop)
    executor: Executor | None = None  # None: runs supervised by threads of this process


@dataclass(frozen=True)
class Outcome:
    """How :meth:`Orchestrator.run` ended: ``status`` is stopped, stop_accepted, prepare_failed or
    already_finished (a resumed campaign that had ended and has nothing left to do)."""

    status: str
    trigger: str | None
    reason: str
    iterations: int
    n_runs_ok: int
    best: dict[str, Any] | None


def _jsonable(value: Any) -> Any:
    """A JSON-clean copy of untrusted proposer output; what JSON cannot hold is kept as its repr."""
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError):
        return repr(value)


def run_id_for(iteration: int, attempt: int = 1) -> str:
    return f"it{iteration:04d}" + (f"-r{attempt}" if attempt > 1 else "")


class Orchestrator:
    def __init__(
        self,
        family: Family,
        proposer: Proposer,
        campaign_dir: str | Path,
        settings: LoopSettings,
        view: View | None = None,
    ):
        self.family = family
        self.proposer = proposer
        self.paths = CampaignPaths(Path(campaign_dir))
        self.settings = settings
        self.view = view or View()

    # ----- set-up and resume -------------------------------------------------------------

    def _open(self) -> None:
        paths = self.paths
        paths.runs_dir.mkdir(parents=True, exist_ok=True)
        if paths.family_json.exists():
            self.registry = read_json(paths.family_json)
            name = self.registry.get("name") if isinstance(self.registry, dict) else None
            if name != self.family.name:  # a one-line error, with its repair, not a traceback
                what = (
                    f"belongs to family {name!r}, not {self.family.name!r}" if name else "is no family.json"
                )
                raise CampaignError(
                    f"{paths.family_json} {what}; delete it: the loop rewrites it from the records"
                )
        else:
            # The campaign's own copy: its best is this campaign's running best, not the family's.
            self.registry = search_view(self.family.registry)
            write_json_atomic(paths.family_json, self.registry)
        self.journal = Journal(paths.proposals)
        repair_torn_tail(paths.runs_log)
        self.state = CampaignState.from_records(self.family, self.journal.read())
        for record in self.state.records:
            if record["status"] in RUN_STATUSES:
                self.proposer.tell(self._run_outcome(record))
        self._sync_best()
        self._in_flight: dict[str, dict[str, Any]] = {}  # run_id -> intent, in launch order
        self._done: queue.Queue[tuple[dict[str, Any], RunResult | BaseException]] = queue.Queue()
        self._threads: list[threading.Thread] = []
        self._cancel = threading.Event()  # set when the loop unwinds: every run in flight is killed
        self.stopper = None
        if self.settings.early_stop != "none":
            self.stopper = EarlyStopper(self.settings.early_stop, self.family.direction, self.state.records)
        self._elapsed_base, self._started = self.state.elapsed_s, time.monotonic()
        arm = self.settings.random_arm
        self.random_summary = summarize_random_arm(arm, self.family) if arm else None

    def elapsed(self) -> float:
        """Seconds the loop has been running, summed over this campaign's sessions."""
        return self._elapsed_base + time.monotonic() - self._started

    def _sync_best(self) -> None:
        best = self.state.best
        entry = None
        if best is not None:
            entry = {
                "config": best["config"],
                "metric": best["metric"],
                "std": None,
                "n": 1,
                "source": f"loop:{best['run_id']}",
                "run_id": best["run_id"],
                "iteration": best["iteration"],
            }
        if self.registry.get("best") != entry:
            self.registry = {**self.registry, "best": entry}
            write_json_atomic(self.paths.family_json, self.registry)

    def _pending_intents(self) -> list[dict[str, Any]]:
        """Intents of runs that started but whose iteration was never recorded."""
        pending = []
        for run_dir in sorted(self.paths.runs_dir.iterdir()):
            if (run_dir / "intent.json").exists() and not (run_dir / "interrupted.json").exists():
                intent = read_json(run_dir / "intent.json")
                if intent["run_id"] not in self.state.run_ids:
                    pending.append(intent)
        return pending

    def _adopt(self, intent: dict[str, Any]) -> RunResult | None:
        """The outcome of an in-flight run whose supervisor died, if it finished or ran out of time
        (past its deadline at resume, or killed there by its watchdog); None otherwise."""
        run_id = intent["run_id"]
        run_dir = self.paths.run_dir(run_id)
        leftover = stop_orphaned_run(run_dir)  # first: nothing of it may write beside a re-run
        result = load_result(run_dir)
        if result is not None:
            return result
        logged = logged_run(self.family, self.paths.runs_log, run_id, intent["config"], intent["seed"])
        if logged is not None:
            return logged
        if leftover.overdue is not None:
            return RunResult("timeout", run_id, None, leftover.overdue, None, None)
        return None

    def _mark_interrupted(self, intent: dict[str, Any], why: str) -> None:
        write_json_atomic(
            self.paths.run_dir(intent["run_id"]) / "interrupted.json", {"time": now(), "reason": why}
        )

    def _recover(self) -> list[dict[str, Any]]:
        """Finish every in-flight iteration from its outcome; return the intents that must be re-run.

        Several intents of one iteration are pending only after a crash during a re-run: its
        latest attempt is the live one; any other, or one whose iteration is recorded, is superseded.
        """
        live: dict[int, dict[str, Any]] = {}
        superseded = []
        for intent in self._pending_intents():
            if intent["iteration"] in self.state.recorded:
                superseded.append(intent)
                continue
            other = live.get(intent["iteration"])
            if other is not None:
                older, intent = sorted((other, intent), key=lambda i: len(i["interrupted_run_ids"]))
                superseded.append(older)
            live[intent["iteration"]] = intent
        for intent in superseded:
            stop_orphaned_run(self.paths.run_dir(intent["run_id"]))
            self._mark_interrupted(intent, "superseded by a later attempt or record of its iteration")
        reruns = []
        for iteration in sorted(live):
            result = self._adopt(live[iteration])
            if result is None:
                reruns.append(live[iteration])
            else:
                self._finish_run(live[iteration], result)
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
            if state.last["status"] == "stop_accepted" or trigger is not None:
                return self._outcome("already_finished", state.last["trigger"], state.last["reason"])
        reruns = self._recover()
        problem = run_prepare_check(self.family)
        if problem is not None:
            for intent in reruns:
                self._mark_interrupted(intent, "not re-run: prepare.py --check failed on resume")
            self._stop("prepare_check", problem)
            return self._outcome("prepare_failed", "prepare_check", problem)
        try:
            for intent in reruns:
                self._rerun(intent)
            while True:
                self._collect_finished()
                trigger = first_trigger(state, budgets, self.elapsed())
                if trigger is not None:
                    self._drain()  # no new proposal; the runs in flight finish and are recorded first
                    trigger = first_trigger(state, budgets, self.elapsed()) or trigger
                    self._stop(trigger.name, trigger.message)
                    return self._outcome("stopped", trigger.name, trigger.message)
                if self._in_flight and (len(self._in_flight) >= self.settings.workers or self._caps_taken()):
                    self._collect(block=True)
                    continue
                before = state.last
                self._iteration()
                if state.last is not before and state.finished:  # a stop record of this session
                    return self._outcome(state.last["status"], state.last["trigger"], state.last["reason"])
        except BaseException:
            self._cancel.set()  # Ctrl-C, SIGTERM or a bug: kill the runs in flight, then unwind
            for thread in self._threads:
                thread.join()
            raise

    def _caps_taken(self) -> bool:
        """Whether the runs in flight, counted as iterations and as successes, already fill
        max_iters or max_runs: then the loop waits for them instead of proposing more."""
        b, n = self.settings.budgets, len(self._in_flight)
        return (b.max_iters is not None and self.state.iterations + n >= b.max_iters) or (
            b.max_runs is not None and self.state.n_runs_ok + n >= b.max_runs
        )

    def _next_iteration(self) -> int:
        return max([self.state.next_iteration - 1, *(i["iteration"] for i in self._in_flight.values())]) + 1

    def _stop(self, trigger: str, reason: str) -> None:
        self._drain()
        name = self.settings.proposer_name
        self._commit(
            self._record(self._next_iteration(), name, status="stopped", trigger=trigger, reason=reason)
        )

    def _outcome(self, status: str, trigger: str | None, reason: str) -> Outcome:
        s = self.state
        return Outcome(status, trigger, reason, s.iterations, s.n_runs_ok, s.best)

    def _running(self) -> tuple[dict[str, Any], ...]:
        """The experiments in flight, as the proposer is shown them."""
        return tuple(
            {
                "iteration": i["iteration"],
                "run_id": i["run_id"],
                "overrides": i["overrides"],
                "config": i["config"],
                "hypothesis": ((i["proposal"] or {}).get("annotation") or {}).get("hypothesis"),
            }
            for i in self._in_flight.values()
        )

    def _ask(self, iteration: int) -> tuple[str, Proposal | None]:
        """(proposer name, proposal); the proposal is None when the campaign was stopped instead
        (the next call would pass the spend cap, or the API refused the key or the spend)."""
        state = self.state
        if state.n_runs_attempted == 0 and not self._in_flight:
            return BASELINE_PROPOSER, Proposal(kind="propose", annotation={"hypothesis": BASELINE_HYPOTHESIS})
        blind = self.settings.blind
        budget = closest_trigger(state, self.settings.budgets, self.elapsed(), blind)
        context = build_context(
            state,
            registry=self.registry,
            blind=blind,
            extra_warnings=(f"Budget: {budget}",),
            random_arm_summary=self.random_summary,
        )
        context = replace(context, iteration=iteration, running=self._running())
        name = self.settings.proposer_name
        budgets = self.settings.budgets
        trigger = spend_trigger(state, budgets, projected_cost(self.proposer, context))
        if trigger is not None:
            self._stop(trigger.name, trigger.message)
            return name, None
        seconds_left = None if budgets.max_seconds is None else budgets.max_seconds - self.elapsed()
        try:
            # transport faults are retried here, within the wall-clock budget, and noted, not failed
            proposal = call_with_retries(lambda: self.proposer.propose(context), seconds_left=seconds_left)
        except FatalAPIError as err:  # no retry heals a bad key or a spent account
            self._stop(f"api_{err.kind}", str(err))
            return name, None
        except RetryBudgetSpent as err:
            self._stop("wall_clock", str(err))
            return name, None
        except Exception as err:  # a proposer bug or API outage is an invalid iteration, not a crash
            return name, Proposal(kind="invalid", error=f"the proposer raised {type(err).__name__}: {err}")
        if not isinstance(proposal, Proposal):
            return name, Proposal(
                kind="invalid", error=f"the proposer returned {type(proposal).__name__}, not a Proposal"
            )
        return name, proposal

    def _iteration(self) -> None:
        state = self.state
        iteration = self._next_iteration()
        self.view.iteration_started(iteration)
        proposer, proposal = self._ask(iteration)
        if proposal is None:
            return
        self.view.proposal(iteration, proposer, proposal)
        usage = proposal.usage
        base = {
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
            "cost_usd": proposal.usage.cost_usd,
            "input_tokens": proposal.usage.input_tokens,
            "output_tokens": proposal.usage.output_tokens,
        }

        def record(status: str, reason: str, **fields: Any) -> None:
            self._commit(self._record(iteration, proposer, status=status, reason=reason, **base, **fields))

        if proposal.kind == "stop":
            annotation = proposal.annotation if isinstance(proposal.annotation, dict) else {}
            accepted, why = stop_gate(annotation, state)
            if accepted:
                self._drain()  # the stop record is the last: the runs in flight are recorded first
                record("stop_accepted", why, trigger="stop_research")
            else:
                record("stop_rejected", why)
            return
        if proposal.kind != "propose":
            record("invalid", proposal.error or f"the proposer returned a proposal of kind {proposal.kind!r}")
            return
        try:
            overrides = self.family.space.validate(proposal.overrides)
        except ValidationError as err:
            record("invalid", str(err))
            return
        config = {**state.current_values(), **overrides}
        if not overrides and proposer != BASELINE_PROPOSER:
            why = "the override map is empty: it changes nothing"
        else:
            why = state.seen_at(overrides, config) or self._seen_in_flight(overrides, config)
        if why is not None:
            record("invalid", why, overrides=overrides, config=config)
            return
        intent = self._record(
            iteration,
            proposer,
            overrides=overrides,
            config=config,
            run_id=run_id_for(iteration),
            seed=self.family.default_seed,
            interrupted_run_ids=[],
            **base,
        )
        self._start(intent)

    def _seen_in_flight(self, overrides: dict[str, Any], config: dict[str, Any]) -> str | None:
        """Why (overrides, config) repeats an experiment in flight, or None (dedup covers them too)."""
        for intent in self._in_flight.values():
            if canonical_key(overrides) == canonical_key(intent["overrides"]):
                return f"this override map is running now, at iteration {intent['iteration']}"
            if canonical_key(config) == canonical_key(intent["config"]):
                return f"the resulting configuration is running now, at iteration {intent['iteration']}"
        return None

    def _start(self, intent: dict[str, Any], supersedes: dict[str, Any] | None = None) -> None:
        run_dir = self.paths.run_dir(intent["run_id"])
        run_dir.mkdir(parents=True, exist_ok=True)  # a dir left empty by a crash before its intent is reused
        if (run_dir / "intent.json").exists():
            raise CampaignError(f"{run_dir} already holds a run")
        write_json_atomic(run_dir / "intent.json", intent)
        if supersedes is not None:  # only once the new attempt is durable
            self._mark_interrupted(supersedes, f"the loop died during this run; re-run as {intent['run_id']}")
        self.view.run_started(intent["run_id"])
        self._launch(intent)

    def _launch(self, intent: dict[str, Any]) -> None:
        """Put the run in flight: in this thread with one worker, else on a thread of its own."""
        self._in_flight[intent["run_id"]] = intent
        if self.settings.workers == 1:
            self._done.put((intent, self._execute(intent)))
            return
        self._threads = [t for t in self._threads if t.is_alive()]
        thread = threading.Thread(target=self._supervise, args=(intent,), name=intent["run_id"], daemon=True)
        self._threads.append(thread)
        thread.start()

    def _supervise(self, intent: dict[str, Any]) -> None:
        try:
            outcome: RunResult | BaseException = self._execute(intent)
        except BaseException as err:  # re-raised in the main thread
            outcome = err
        self._done.put((intent, outcome))

    def _execute(self, intent: dict[str, Any]) -> RunResult:
        run_id = intent["run_id"]
        task = {
            "family": self.family,
            "config": intent["config"],
            "run_id": run_id,
            "seed": intent["seed"],
            "run_dir": self.paths.run_dir(run_id),
            "runs_log": self.paths.runs_log,
            "timeout": self.settings.timeout_per_run,
        }
        executor = self.settings.executor
        if executor is not None and executor.name == "ray":
            return executor.map(_run_task, [task], cancel=self._cancel)[0]  # cancelled as the loop unwinds
        return run_experiment(
            **task,
            on_progress=lambda elapsed: self.view.run_progress(elapsed, run_id),
            on_report=self.stopper.start(run_id) if self.stopper else None,
            cancel=self._cancel,
        )

    def _collect(self, block: bool) -> None:
        """Record one finished run; raises queue.Empty when none has finished and not ``block``."""
        while True:
            try:
                intent, outcome = self._done.get(timeout=0.2) if block else self._done.get_nowait()
                break
            except queue.Empty:
                if not block:
                    raise
        del self._in_flight[intent["run_id"]]
        if isinstance(outcome, BaseException):
            raise outcome
        self._finish_run(intent, outcome)

    def _collect_finished(self) -> None:
        try:
            while True:
                self._collect(block=False)
        except queue.Empty:
            pass

    def _drain(self) -> None:
        while self._in_flight:
            self._collect(block=True)

    def _rerun(self, intent: dict[str, Any]) -> None:
        lost = [*intent["interrupted_run_ids"], intent["run_id"]]
        retry = {
            **intent,
            "run_id": run_id_for(intent["iteration"], len(lost) + 1),
            "interrupted_run_ids": lost,
        }
        self._start(retry, supersedes=intent)

    def _finish_run(self, intent: dict[str, Any], result: RunResult) -> None:
        state, family = self.state, self.family
        fields: dict[str, Any] = {
            "run_status": result.status,
            "wall_seconds": result.wall_seconds,
            "returncode": result.returncode,
            "run_id": result.run_id,
        }
        if result.progress:
            fields["progress"] = result.progress
        if result.ok:
            feasible = family.is_feasible(result.record)
            judged = run_verdict(
                result.metric,
                feasible=feasible,
                is_baseline=intent["proposer"] == BASELINE_PROPOSER,
                prior_best=state.best_metric,
                direction=family.direction,
                sigma=family.sigma,
            )
            fields.update(
                status="ran", metric=result.metric, feasible=feasible, record=result.record, verdict=judged
            )
        elif result.status == "early_stopped":  # never a result: no metric, never best, not a failure
            fields.update(status="pruned", reason=result.reason)
        else:
            fields.update(status="failed", reason=result.reason)
        record = {**intent, **fields}
        record["best_so_far"] = state.best_after(record["metric"], record["feasible"])
        self._commit(record)
        if self.stopper is not None:
            self.stopper.finish(record)
        self.proposer.tell(self._run_outcome(record))
        self._sync_best()

    def _run_outcome(self, record: dict[str, Any]) -> RunOutcome:
        """What the proposer is told of a run record (a failed or stopped run has no metric)."""
        if record["status"] != "ran":
            return RunOutcome(record["config"], None, False)
        constraints = self.family.constraints(record["record"])
        return RunOutcome(record["config"], record["metric"], bool(record["feasible"]), constraints)

    def _record(self, iteration: int, proposer: str, **fields: Any) -> dict[str, Any]:
        return new_record(
            iteration=iteration, proposer=proposer, best_so_far=self.state.best_metric, **fields
        )

    def _commit(self, record: dict[str, Any]) -> None:
        """Append one iteration's record (durably) and fold it into the state."""
        state = self.state
        record["time"] = now()
        record["cost_usd"] = record["cost_usd"] or 0.0
        record["input_tokens"] = record["input_tokens"] or 0
        record["output_tokens"] = record["output_tokens"] or 0
        record["cumulative_cost_usd"] = state.cost_usd + record["cost_usd"]
        record["elapsed_s"] = round(self.elapsed(), 3)
        self.journal.append(record)
        state.apply(record)
        self.view.record(record, closest_trigger(state, self.settings.budgets, self.elapsed()))


def _run_task(task: dict[str, Any]) -> RunResult:
    """One run as a plain function of picklable arguments (a Ray task)."""
    return run_experiment(**task)
