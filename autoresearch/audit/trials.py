"""Resumable batches of training runs: the one engine under noise, verify, prune.

A step describes its runs as :class:`Trial` s, each with a key unique within the step's log.
Results are appended to the log as :class:`TrialRow` s as they arrive (through the journal, so
concurrent workers never interleave lines); a re-run skips every key already logged as ok and
retries the rest.

For a family with a sealed test split every audit run is scored on both splits from one training
(``train.py --eval-split test``): a row holds the run's score on each. A row logged before the
family had the split is re-run.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.audit.inputs import AuditError, audit_split
from autoresearch.audit.progress import TrialProgress
from autoresearch.campaign.audit_log import StepLog, TrialRow
from autoresearch.execution.executors import Executor
from autoresearch.execution.processes import stop_orphaned_run
from autoresearch.execution.result import RunResult
from autoresearch.execution.runner import logged_run, saved_run
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.splits import Split


@dataclass(frozen=True)
class Trial:
    key: str  # e.g. "verify-c1-s11": the resumption key, also the run id and run directory name
    config: dict[str, Any]
    seed: int


def trial_row(family: Family, trial: Trial, result: RunResult, split: Split) -> TrialRow:
    """The log line of one trial: what every audit step reads back."""
    final_metric = result.final_metric or {}
    return TrialRow(
        key=trial.key,
        run_id=result.run_id,
        seed=trial.seed,
        status=result.status,
        split=split,
        scores=family.scored(final_metric) if result.ok else None,
        best_train_loss=final_metric.get("best_train_loss"),
        reason=result.reason,
        wall_seconds=result.wall_seconds,
        returncode=result.returncode,
        config=trial.config,
        final_metric=result.final_metric,
    )


def run_trial(executor: Executor, spec: RunSpec, trial: Trial) -> TrialRow:
    """Run one trial as ``spec`` (its run directory used once); a finished earlier attempt of the same
    configuration and split whose log line was lost is reused, anything else left in the directory
    is replaced."""
    family, run_dir = spec.family, spec.run_dir
    earlier = saved_run(spec)
    if (
        earlier is not None
        and earlier.ok
        and earlier.final_metric.get("config") == trial.config
        and earlier.final_metric.get("eval_split", Split.SEARCH.value) == spec.split.value
        and not family.off_split(earlier.final_metric)
    ):
        return trial_row(family, trial, earlier, spec.split)
    if run_dir.exists():  # a failed or interrupted attempt: its directory is used once
        stop_orphaned_run(run_dir)  # an orphan of a killed audit, wherever it moved: it must not write twice
        logged = logged_run(spec)
        if logged is not None and logged.ok and not family.off_split(logged.final_metric):
            # it finished before it was stopped: its line is the result
            return trial_row(family, trial, logged, spec.split)
        shutil.rmtree(run_dir)
    return trial_row(family, trial, executor.run(spec), spec.split)


def _logged(family: Family, trials: Sequence[Trial], log: StepLog, split: Split) -> dict[str, TrialRow]:
    """The rows of ``log`` that already answer ``trials``, by key. A row counts only for the
    configuration and split it ran, and only if it was scored on the data the family pins: a key
    reused for another configuration (e.g. a re-run after the promoted configuration changed), or a
    row scored on another build of a split, runs again."""
    wanted = {t.key: t.config for t in trials}
    return {
        row.key: row
        for row in log.read()
        if row.ok
        and row.key in wanted
        and row.config == wanted[row.key]
        and row.split is split
        and not family.off_split(row.final_metric)
    }


def refuse_off_split(family: Family, rows: Sequence[TrialRow]) -> None:
    """Raise AuditError when a finished run was scored on data other than the family pins: this
    machine's data are not the family's, and no gate may compare the two."""
    off = {row.key: why for row in rows if row.ok and (why := family.off_split(row.final_metric))}
    if off:
        key, why = next(iter(off.items()))
        raise AuditError(
            f"{len(off)} run(s) were scored on data other than family {family.name!r} pins ({key}: "
            f"{'; '.join(why)}); the data sets on this machine are not the family's: check them with "
            f"`python prepare.py --check` in {family.path}, then run the same command again"
        )


def run_trials(
    family: Family,
    trials: Sequence[Trial],
    executor: Executor,
    log_path: Path,
    root: Path,
    timeout: float,
    runs_log: Path | None = None,
    label: str | None = None,
    split: Split | None = None,
    time_budget: float | None = None,
) -> list[TrialRow]:
    """Rows for ``trials`` in order, running only those not already logged as ok (for that config
    and that split).

    Run directories go under ``root``; train.py appends its FINAL_METRIC lines to ``runs_log``
    (default root/runs.jsonl). Progress, named ``label`` (default: the log's stem), goes to stderr.
    Runs are scored on ``split``, by default both splits where the family has a sealed one
    (:func:`audit_split`), each granted ``time_budget`` training seconds when given.
    """
    keys = [t.key for t in trials]
    if len(set(keys)) != len(keys):
        raise ValueError("run_trials: trial keys must be unique")
    root.mkdir(parents=True, exist_ok=True)
    log, split = StepLog(log_path), split or audit_split(family)
    done = _logged(family, trials, log, split)
    todo = [t for t in trials if t.key not in done]
    runs_log, root = (runs_log or root / "runs.jsonl").resolve(), root.resolve()

    def spec(trial: Trial) -> RunSpec:
        return RunSpec(
            family,
            trial.config,
            trial.key,
            trial.seed,
            root / trial.key,
            runs_log,
            timeout,
            split,
            time_budget,
        )

    with TrialProgress(label or log_path.stem, len(trials), len(trials) - len(todo)) as progress:

        def logged(_: int, row: TrialRow) -> None:
            log.append(row)
            progress.advance(row)

        fresh = executor.map(lambda trial: run_trial(executor, spec(trial), trial), todo, on_result=logged)
    refuse_off_split(family, fresh)
    done.update({row.key: row for row in fresh})
    return [done[key] for key in keys]
