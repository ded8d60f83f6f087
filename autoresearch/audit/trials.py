"""Resumable batches of training runs: the one engine under noise, verify, prune.

A step describes its runs as :class:`Trial` s, each with a key unique within the step's log.
Results are appended to the log as they arrive (through the journal, so concurrent workers never
interleave lines); a re-run skips every key already logged as ok and retries the rest.
"""

from __future__ import annotations

import functools
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.audit.progress import TrialProgress
from autoresearch.executors import Executor
from autoresearch.family import Family
from autoresearch.journal import Journal
from autoresearch.loop.runner import RunResult, load_result, run_experiment, stop_orphaned_run


@dataclass(frozen=True)
class Trial:
    key: str  # e.g. "verify-c1-s11": the resumption key, also the run id and run directory name
    config: dict[str, Any]
    seed: int


def trial_row(family: Family, trial: Trial, result: RunResult) -> dict[str, Any]:
    """The log line of one trial: what every audit step reads back."""
    record = result.record or {}
    return {
        "key": trial.key,
        "run_id": result.run_id,
        "seed": trial.seed,
        "status": result.status,
        "metric": result.metric,
        "feasible": family.is_feasible(record) if result.ok else None,
        "best_train_loss": record.get("best_train_loss"),
        "reason": result.reason,
        "wall_seconds": result.wall_seconds,
        "returncode": result.returncode,
        "config": trial.config,
        "record": result.record,
    }


def run_trial(family: Family, root: Path, runs_log: Path, timeout: float, trial: Trial) -> dict[str, Any]:
    """Run one trial in root/<key>; a finished earlier attempt of the same configuration whose log
    line was lost is reused, anything else left in the directory is replaced."""
    run_dir = root / trial.key
    earlier = load_result(run_dir)
    if earlier is not None and earlier.ok and earlier.record.get("config") == trial.config:
        return trial_row(family, trial, earlier)
    if run_dir.exists():  # a failed or interrupted attempt: its directory is used once
        stop_orphaned_run(run_dir)
        shutil.rmtree(run_dir)
    result = run_experiment(
        family,
        trial.config,
        run_id=trial.key,
        seed=trial.seed,
        run_dir=run_dir,
        runs_log=runs_log,
        timeout=timeout,
    )
    return trial_row(family, trial, result)


def run_trials(
    family: Family,
    trials: Sequence[Trial],
    executor: Executor,
    log_path: Path,
    root: Path,
    timeout: float,
    runs_log: Path | None = None,
    label: str | None = None,
) -> list[dict[str, Any]]:
    """Rows for ``trials`` in order, running only those not already logged as ok (for that config).

    Run directories go under ``root``; train.py appends its records to ``runs_log`` (default
    root/runs.jsonl). Progress, named ``label`` (default: the log's stem), goes to stderr.
    """
    keys = [t.key for t in trials]
    if len(set(keys)) != len(keys):
        raise ValueError("run_trials: trial keys must be unique")
    root.mkdir(parents=True, exist_ok=True)
    journal = Journal(log_path)
    wanted = {t.key: t.config for t in trials}
    # A row counts only for the configuration it ran: a key reused for another configuration
    # (e.g. a re-run after the promoted configuration changed) runs again.
    done = {
        row["key"]: row
        for row in journal.read()
        if row.get("status") == "ok" and row["key"] in wanted and row["config"] == wanted[row["key"]]
    }
    todo = [t for t in trials if t.key not in done]
    runs_log = (runs_log or root / "runs.jsonl").resolve()
    fn = functools.partial(run_trial, family, root.resolve(), runs_log, timeout)
    with TrialProgress(label or log_path.stem, len(trials), len(trials) - len(todo)) as progress:

        def record(_: int, row: dict[str, Any]) -> None:
            journal.append(row)
            progress.advance(row)

        fresh = executor.map(fn, todo, on_result=record)
    done.update({row["key"]: row for row in fresh})
    return [done[key] for key in keys]
