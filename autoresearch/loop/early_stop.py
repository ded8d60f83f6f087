"""Early stopping of hopeless runs (``loop --early-stop``): Optuna's pruners judge the PROGRESS curves.

One in-memory study per campaign, one trial per run: each PROGRESS point of a run in flight is
``trial.report(value, step)``, and ``trial.should_prune()`` decides whether to stop it. Finished
runs are told as complete trials (pruned ones as pruned), so a run is compared with the curves of
the runs before it at the same step. On ``--resume`` the study is rebuilt from the records' curves.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from autoresearch.campaign import Record, Status
from autoresearch.direction import Direction

if TYPE_CHECKING:
    import optuna

# optuna is imported only when early stopping is on: it costs the CLI a second of start-up.
EARLY_STOP = ("none", "median", "asha")


def make_pruner(name: str) -> optuna.pruners.BasePruner:
    import optuna

    if name == "median":
        return optuna.pruners.MedianPruner()
    if name == "asha":
        return optuna.pruners.SuccessiveHalvingPruner()
    raise ValueError(f"--early-stop must be one of {', '.join(EARLY_STOP)}, got {name!r}")


def _curve(record: Record) -> dict[int, float]:
    return {point["step"]: point["value"] for point in record.progress or ()}


class EarlyStopper:
    """Thread-safe: runs in flight report from their own supervising threads."""

    def __init__(self, name: str, direction: Direction, records: list[Record] = ()):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.name = name
        self.study = optuna.create_study(direction=direction.study, pruner=make_pruner(name))
        self._lock = threading.Lock()
        self._trials: dict[str, optuna.Trial] = {}
        for record in records:
            self._add_finished(record)

    def _add_finished(self, record: Record) -> None:
        curve = _curve(record)
        if not curve or record.status not in (Status.RAN, Status.EARLY_STOPPED):
            return  # a failed run's curve says nothing about the metric it would have reached
        import optuna
        from optuna.trial import TrialState

        self.study.add_trial(
            optuna.trial.create_trial(
                state=TrialState.COMPLETE if record.ran else TrialState.PRUNED,
                value=record.metric if record.ran else None,
                intermediate_values=curve,
                params={},
                distributions={},
            )
        )

    def start(self, run_id: str) -> Callable[[int, float], bool]:
        """The ``on_report`` of one run: True when the pruner says to stop it."""
        with self._lock:
            trial = self._trials[run_id] = self.study.ask()

        def report(step: int, value: float) -> bool:
            with self._lock:
                trial.report(value, step)
                return trial.should_prune()

        return report

    def finish(self, record: Record) -> None:
        """Tell the study how a run ended (a run adopted on resume had no trial: it is added)."""
        from optuna.trial import TrialState

        with self._lock:
            trial = self._trials.pop(record.run_id, None)
            if trial is None:
                self._add_finished(record)
            elif record.ran:
                self.study.tell(trial, record.metric)
            else:
                stopped = record.status is Status.EARLY_STOPPED
                self.study.tell(trial, state=TrialState.PRUNED if stopped else TrialState.FAIL)
