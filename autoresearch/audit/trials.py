"""Resumable batches of training runs: the one engine under noise, verify, prune.

A step describes its runs as :class:`Trial` s, each with a key unique within the step's log.
Results are appended to the log as they arrive (through the journal, so concurrent workers never
interleave lines); a re-run skips every key already logged as ok and retries the rest.

For a family with a sealed test split every audit run is scored on both splits from one training
(``train.py --eval-split test``): a row keeps the search split's value as ``metric`` and
``feasible``, as every row always has, and the test split's under ``test``; :func:`at_split` reads
either. A row logged before the family had the split (no ``test``) is re-run.
"""

from __future__ import annotations

import functools
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.audit.progress import TrialProgress
from autoresearch.executors import Executor
from autoresearch.family import SEARCH, TEST, Family
from autoresearch.journal import Journal
from autoresearch.loop.processes import stop_orphaned_run
from autoresearch.loop.protocol import searched
from autoresearch.loop.runner import RunResult, load_result, logged_run, run_experiment


@dataclass(frozen=True)
class Trial:
    key: str  # e.g. "verify-c1-s11": the resumption key, also the run id and run directory name
    config: dict[str, Any]
    seed: int


def eval_split_of(family: Family) -> str:
    """What the audit's runs are scored on: both splits where the family has a sealed one."""
    return TEST if family.has_test_split else SEARCH


def at_split(row: dict[str, Any], split: str) -> tuple[float | None, bool | None]:
    """(metric, feasible) of a trial row on ``split``; (None, None) when the run has no such value."""
    if split == SEARCH:
        return row["metric"], row["feasible"]
    test = row.get(TEST) or {}
    return test.get("metric"), test.get("feasible")


def trial_row(family: Family, trial: Trial, result: RunResult, eval_split: str = SEARCH) -> dict[str, Any]:
    """The log line of one trial: what every audit step reads back."""
    record = result.record or {}
    metric, feasible, test = result.metric, (family.is_feasible(record) if result.ok else None), None
    if result.ok and eval_split == TEST:
        search = searched(record)  # checked by the runner
        test = {"metric": metric, "feasible": feasible}
        metric, feasible = float(search[family.metric]), family.is_feasible(search)
    return {
        "key": trial.key,
        "run_id": result.run_id,
        "seed": trial.seed,
        "status": result.status,
        "eval_split": eval_split,
        "metric": metric,
        "feasible": feasible,
        TEST: test,
        "best_train_loss": record.get("best_train_loss"),
        "reason": result.reason,
        "wall_seconds": result.wall_seconds,
        "returncode": result.returncode,
        "config": trial.config,
        "record": result.record,
    }


def run_trial(
    family: Family,
    root: Path,
    runs_log: Path,
    timeout: float,
    eval_split: str,
    trial: Trial,
    experiment: Callable[..., RunResult] = run_experiment,
) -> dict[str, Any]:
    """Run one trial in root/<key>; a finished earlier attempt of the same configuration and split
    whose log line was lost is reused, anything else left in the directory is replaced."""
    run_dir = root / trial.key
    earlier = load_result(run_dir)
    if (
        earlier is not None
        and earlier.ok
        and earlier.record.get("config") == trial.config
        and earlier.record.get("eval_split", SEARCH) == eval_split
    ):
        return trial_row(family, trial, earlier, eval_split)
    if run_dir.exists():  # a failed or interrupted attempt: its directory is used once
        stop_orphaned_run(run_dir)  # an orphan of a killed audit, wherever it moved: it must not write twice
        logged = logged_run(family, runs_log, trial.key, trial.config, trial.seed, eval_split)
        if logged is not None and logged.ok:  # it finished before it was stopped: its line is the result
            return trial_row(family, trial, logged, eval_split)
        shutil.rmtree(run_dir)
    result = experiment(
        family,
        trial.config,
        run_id=trial.key,
        seed=trial.seed,
        run_dir=run_dir,
        runs_log=runs_log,
        timeout=timeout,
        eval_split=eval_split,
    )
    return trial_row(family, trial, result, eval_split)


def run_trials(
    family: Family,
    trials: Sequence[Trial],
    executor: Executor,
    log_path: Path,
    root: Path,
    timeout: float,
    runs_log: Path | None = None,
    label: str | None = None,
    eval_split: str | None = None,
) -> list[dict[str, Any]]:
    """Rows for ``trials`` in order, running only those not already logged as ok (for that config
    and that split).

    Run directories go under ``root``; train.py appends its records to ``runs_log`` (default
    root/runs.jsonl). Progress, named ``label`` (default: the log's stem), goes to stderr. Runs
    are scored on ``eval_split``, by default both splits where the family has a sealed one
    (:func:`eval_split_of`).
    """
    keys = [t.key for t in trials]
    if len(set(keys)) != len(keys):
        raise ValueError("run_trials: trial keys must be unique")
    root.mkdir(parents=True, exist_ok=True)
    journal = Journal(log_path)
    wanted, eval_split = {t.key: t.config for t in trials}, eval_split or eval_split_of(family)
    # A row counts only for the configuration and split it ran: a key reused for another
    # configuration (e.g. a re-run after the promoted configuration changed) runs again.
    done = {
        row["key"]: row
        for row in journal.read()
        if row.get("status") == "ok"
        and row["key"] in wanted
        and row["config"] == wanted[row["key"]]
        and row.get("eval_split", SEARCH) == eval_split
    }
    todo = [t for t in trials if t.key not in done]
    runs_log = (runs_log or root / "runs.jsonl").resolve()
    fn = functools.partial(
        run_trial, family, root.resolve(), runs_log, timeout, eval_split, experiment=executor.run_experiment
    )
    with TrialProgress(label or log_path.stem, len(trials), len(trials) - len(todo)) as progress:

        def record(_: int, row: dict[str, Any]) -> None:
            journal.append(row)
            progress.advance(row)

        fresh = executor.map(fn, todo, on_result=record)
    done.update({row["key"]: row for row in fresh})
    return [done[key] for key in keys]
